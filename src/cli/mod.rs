//! The command-line subcommands `smooth` and `report`.
//!
//! Exit codes: 0 success, 1 any other failure (e.g. the output cannot be
//! written), 2 usage or parameter error, 3 input unreadable or malformed,
//! 4 smoothing failed. Messages go to stderr and name the file, and the
//! line for parse errors.

mod params;
mod progress;
mod summary;

use anyhow::{Context, anyhow};
use meshsmooth_core::Params;
use meshsmooth_core::io::{Format, ReadLimits};
use meshsmooth_core::job::{Input, JobError};
use meshsmooth_core::report::{MeshStatistics, SCHEMA_VERSION, StageMeasures};
use std::io::{IsTerminal, Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

pub use params::ParamFlags;
use params::WeldFlags;

/// Arguments of `meshsmooth smooth`.
#[derive(Debug, clap::Args)]
pub struct SmoothArgs {
    /// Input mesh file, or `-` for stdin.
    input: PathBuf,
    /// Output mesh file, or `-` for stdout.
    #[arg(short, long)]
    output: PathBuf,
    /// Write the quality report (JSON) to this file, or `-` for stdout.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Load parameters from a JSON file (the HTTP API's `params` object);
    /// the flags below override it.
    #[arg(long, value_name = "FILE.json")]
    params: Option<PathBuf>,
    #[command(flatten)]
    flags: ParamFlags,
    /// Worker threads (default: all cores).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=1024))]
    threads: Option<u16>,
    /// Output format (default: from the output file's extension, else the
    /// input's format).
    #[arg(long, value_name = "FORMAT")]
    format: Option<Format>,
    /// Input format (default: from the input file's extension, else guessed
    /// from its content).
    #[arg(long, value_name = "FORMAT")]
    input_format: Option<Format>,
    /// No progress bar and no summary.
    #[arg(short, long)]
    quiet: bool,
}

/// Arguments of `meshsmooth report`.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Input mesh file, or `-` for stdin.
    input: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Input format (default: from the file's extension, else guessed from
    /// its content).
    #[arg(long, value_name = "FORMAT")]
    input_format: Option<Format>,
    #[command(flatten)]
    weld: WeldFlags,
}

/// A failure with the exit code it maps to.
struct Failure {
    code: u8,
    error: anyhow::Error,
}

impl Failure {
    fn usage(error: anyhow::Error) -> Self {
        Failure { code: 2, error }
    }
    fn input(error: anyhow::Error) -> Self {
        Failure { code: 3, error }
    }
    fn smoothing(error: anyhow::Error) -> Self {
        Failure { code: 4, error }
    }
    fn other(error: anyhow::Error) -> Self {
        Failure { code: 1, error }
    }
}

fn exit(result: Result<(), Failure>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("meshsmooth: error: {:#}", f.error);
            ExitCode::from(f.code)
        }
    }
}

/// Runs `meshsmooth smooth`.
pub fn smooth(args: SmoothArgs) -> ExitCode {
    exit(run_smooth(args))
}

/// Runs `meshsmooth report`.
pub fn report(args: ReportArgs) -> ExitCode {
    exit(run_report(args))
}

fn is_stdio(path: &Path) -> bool {
    path.as_os_str() == "-"
}

fn display(path: &Path) -> String {
    if is_stdio(path) {
        "<stdin>".to_owned()
    } else {
        path.display().to_string()
    }
}

/// Reads and parses the input for a job with `params` (limits, welding);
/// every failure is an input error (exit 3).
fn read_input(path: &Path, format: Option<Format>, params: &Params) -> Result<Input, Failure> {
    let name = display(path);
    let bytes = if is_stdio(path) {
        let mut bytes = Vec::new();
        std::io::stdin()
            .lock()
            .read_to_end(&mut bytes)
            .context("cannot read stdin")
            .map_err(Failure::input)?;
        bytes
    } else {
        std::fs::read(path)
            .with_context(|| format!("cannot read {name}"))
            .map_err(Failure::input)?
    };
    let format = format
        .or_else(|| path.to_str().and_then(Format::from_file_name))
        .or_else(|| Format::sniff(&bytes))
        .ok_or_else(|| {
            Failure::input(anyhow!(
                "cannot tell the format of {name}; name it with --input-format"
            ))
        })?;
    Input::read(&bytes, format, params, ReadLimits::default())
        .with_context(|| format!("cannot read {name}"))
        .map_err(Failure::input)
}

/// Writes `bytes` to `path` (`-` for stdout).
fn write_output(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if is_stdio(path) {
        let mut out = std::io::stdout().lock();
        out.write_all(bytes)
            .and_then(|()| out.flush())
            .context("cannot write to stdout")
    } else {
        std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
    }
}

fn load_params(args: &SmoothArgs) -> Result<Params, Failure> {
    let mut params = match &args.params {
        None => Params::default(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the parameter file {}", path.display()))
                .map_err(Failure::usage)?;
            serde_json::from_str(&text)
                .with_context(|| format!("invalid parameter file {}", path.display()))
                .map_err(Failure::usage)?
        }
    };
    args.flags.apply(&mut params);
    params
        .validate()
        .context("invalid parameters")
        .map_err(Failure::usage)?;
    Ok(params)
}

fn run_smooth(args: SmoothArgs) -> Result<(), Failure> {
    if is_stdio(&args.output) && args.report.as_deref().is_some_and(is_stdio) {
        return Err(Failure::usage(anyhow!(
            "the output and the report cannot both go to stdout"
        )));
    }
    let params = load_params(&args)?;
    let input = read_input(&args.input, args.input_format, &params)?;
    let out_format = args
        .format
        .or_else(|| {
            (!is_stdio(&args.output))
                .then(|| args.output.to_str().and_then(Format::from_file_name))
                .flatten()
        })
        .unwrap_or(input.format());

    let show = !args.quiet && std::io::stderr().is_terminal();
    let bar = progress::Bar::new(show);
    let cancel = AtomicBool::new(false);
    let started = Instant::now();
    let result = on_threads(args.threads, || {
        input.smooth(&params, out_format, &bar, &cancel)
    })?;
    bar.finish();
    let output = result.map_err(|e| match e {
        JobError::Write(e) => {
            Failure::other(anyhow::Error::new(e).context("cannot encode the smoothed mesh"))
        }
        e => Failure::smoothing(
            anyhow::Error::new(e).context(format!("smoothing {} failed", display(&args.input))),
        ),
    })?;
    let elapsed = started.elapsed();

    write_output(&args.output, &output.bytes).map_err(Failure::other)?;
    if params.vertex_results
        && !args.quiet
        && matches!(out_format, Format::Obj | Format::Stl | Format::Off)
    {
        eprintln!(
            "meshsmooth: note: {out_format} cannot hold per-vertex results; --vertex-results \
             has no effect (write glTF or PLY)"
        );
    }

    let report = output.report;
    if let Some(path) = &args.report {
        let mut json = serde_json::to_vec_pretty(&report)
            .context("cannot encode the report")
            .map_err(Failure::other)?;
        json.push(b'\n');
        write_output(path, &json).map_err(Failure::other)?;
    }
    if !args.quiet {
        let mut err = std::io::stderr().lock();
        let _ = summary::smoothed(&mut err, input.mesh(), &report, elapsed);
    }
    Ok(())
}

/// Runs `f` on a dedicated pool of `threads` workers, or on the global
/// pool when `None`.
fn on_threads<T: Send>(threads: Option<u16>, f: impl FnOnce() -> T + Send) -> Result<T, Failure> {
    match threads {
        None => Ok(f()),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(usize::from(n))
                .thread_name(|i| format!("meshsmooth-{i}"))
                .build()
                .context("cannot start the worker threads")
                .map_err(Failure::other)?;
            Ok(pool.install(f))
        }
    }
}

/// What `meshsmooth report --json` prints: the input measures of a
/// smoothing report, without smoothing.
#[derive(serde::Serialize)]
struct MeshReport {
    /// Same as the smoothing report's `schema_version`.
    schema_version: &'static str,
    /// Size and topology.
    mesh: MeshStatistics,
    /// Curvature variation, angles, edges, twisted quads and volume of the
    /// mesh as it is: the smoothing report's `input` stage.
    measures: StageMeasures,
    /// SHA-256 of the input file.
    input_sha256: String,
}

fn run_report(args: ReportArgs) -> Result<(), Failure> {
    let mut params = Params::default();
    args.weld.apply(&mut params);
    params
        .validate()
        .context("invalid parameters")
        .map_err(Failure::usage)?;
    let input = read_input(&args.input, args.input_format, &params)?;
    // The smoothing report's input stage, curvature variation included.
    let measured = input.measure(&params);
    let report = MeshReport {
        schema_version: SCHEMA_VERSION,
        mesh: measured.mesh,
        measures: measured
            .stages
            .input
            .context("the input was not measured")
            .map_err(Failure::other)?,
        input_sha256: input.sha256().to_owned(),
    };
    let mut out = std::io::stdout().lock();
    let written = if args.json {
        serde_json::to_writer_pretty(&mut out, &report)
            .map_err(std::io::Error::from)
            .and_then(|()| writeln!(out))
    } else {
        summary::measured(&mut out, &report.mesh, &report.measures)
    };
    written
        .and_then(|()| out.flush())
        .context("cannot write to stdout")
        .map_err(Failure::other)
}
