//! Settings of `meshsmooth serve`: every one a flag and a `MESHSMOOTH_*`
//! environment variable, with embedded defaults (no config file).

use meshsmooth_core::io::ReadLimits;
use std::net::SocketAddr;
use std::num::NonZeroUsize;
use std::time::Duration;

/// Arguments of `meshsmooth serve`. Sizes accept `KiB`/`MiB`/`GiB` (and
/// `KB`/`MB`/`GB`) suffixes; durations accept `ms`, `s`, `m` and `h`
/// suffixes (a bare number is seconds).
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address and port to listen on (port 0 picks a free port; the bound
    /// address is printed on the first line of stdout).
    #[arg(long, env = "MESHSMOOTH_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,

    /// Jobs smoothed at the same time, each on its own worker thread.
    /// Default: the number of available cores.
    #[arg(long, env = "MESHSMOOTH_WORKERS")]
    pub workers: Option<NonZeroUsize>,

    /// Jobs that may wait for a worker; when the queue is full, uploads are
    /// refused with 503 and `Retry-After`. At most this many plus the
    /// worker count uploads are received at once.
    #[arg(long, env = "MESHSMOOTH_QUEUE_CAPACITY", default_value_t = 16)]
    pub queue_capacity: usize,

    /// Longest a job may run before it is stopped and failed.
    #[arg(long, env = "MESHSMOOTH_JOB_TIME_LIMIT", default_value = "10m", value_parser = parse_duration)]
    pub job_time_limit: Duration,

    /// How long a finished job (and its result) is kept.
    #[arg(long, env = "MESHSMOOTH_RESULT_TTL", default_value = "1h", value_parser = parse_duration)]
    pub result_ttl: Duration,

    /// Memory for finished results; beyond it the oldest results are
    /// evicted first (their job then answers 410 for the mesh and report).
    #[arg(long, env = "MESHSMOOTH_RESULT_MEMORY", default_value = "2GiB", value_parser = parse_size)]
    pub result_memory: u64,

    /// Largest accepted upload (request body), in bytes.
    #[arg(long, env = "MESHSMOOTH_MAX_UPLOAD_BYTES", default_value = "512MiB", value_parser = parse_size)]
    pub max_upload_bytes: u64,

    /// Most vertices accepted in one mesh.
    #[arg(long, env = "MESHSMOOTH_MAX_VERTICES", default_value_t = ReadLimits::default().max_vertices)]
    pub max_vertices: usize,

    /// Most faces accepted in one mesh.
    #[arg(long, env = "MESHSMOOTH_MAX_FACES", default_value_t = ReadLimits::default().max_faces)]
    pub max_faces: usize,

    /// Largest accepted `params` multipart part (or `params` query value).
    #[arg(long, env = "MESHSMOOTH_MAX_PARAMS_BYTES", default_value = "64KiB", value_parser = parse_size)]
    pub max_params_bytes: u64,

    /// Longest an upload may take to arrive, from the end of the headers to
    /// the last body byte (guards against slow-loris uploads).
    #[arg(long, env = "MESHSMOOTH_UPLOAD_TIMEOUT", default_value = "5m", value_parser = parse_duration)]
    pub upload_timeout: Duration,

    /// Longest a client may take to send the request headers.
    #[arg(long, env = "MESHSMOOTH_HEADER_TIMEOUT", default_value = "30s", value_parser = parse_duration)]
    pub header_timeout: Duration,

    /// Time limit of every route except uploads, the one-call
    /// `/v1/smooth` and the event stream.
    #[arg(long, env = "MESHSMOOTH_REQUEST_TIMEOUT", default_value = "30s", value_parser = parse_duration)]
    pub request_timeout: Duration,

    /// On SIGTERM/SIGINT: how long running jobs and open requests may take
    /// to finish before they are cancelled and the process exits.
    #[arg(long, env = "MESHSMOOTH_SHUTDOWN_TIMEOUT", default_value = "30s", value_parser = parse_duration)]
    pub shutdown_timeout: Duration,

    /// Origins allowed to call the API from a browser (CORS), comma
    /// separated, or `*` for any. Default: none (no CORS headers).
    #[arg(long, env = "MESHSMOOTH_CORS_ORIGINS", value_delimiter = ',')]
    pub cors_origins: Vec<String>,

    /// Log format on stderr.
    #[arg(long, env = "MESHSMOOTH_LOG_FORMAT", value_enum, default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,

    /// Log filter, in `tracing` env-filter syntax (e.g. `info`,
    /// `meshsmooth=debug,tower_http=warn`).
    #[arg(long, env = "MESHSMOOTH_LOG", default_value = "info")]
    pub log: String,

    /// Threads serving HTTP (the async runtime); smoothing never runs on
    /// them.
    #[arg(long, env = "MESHSMOOTH_HTTP_THREADS", default_value = "2")]
    pub http_threads: NonZeroUsize,

    /// Where jobs, the queue and results live: `memory` (this process; the
    /// default, no server needed) or `redis://HOST:PORT[/DB]`, a Redis
    /// shared by every replica, so any replica answers for any job and
    /// accepted jobs survive restarts.
    #[arg(long, env = "MESHSMOOTH_STORE", default_value = "memory")]
    pub store: String,

    /// With the Redis store: how long a running job stays claimed by its
    /// replica without a renewal (renewed every 200 ms). When a replica
    /// dies, another runs its jobs again after this long.
    #[arg(long, env = "MESHSMOOTH_LEASE", default_value = "15s", value_parser = parse_duration)]
    pub lease: Duration,

    /// With the Redis store: runs of one job (first run and reruns after
    /// its replica died) before it fails with `job_attempts_exhausted`.
    #[arg(long, env = "MESHSMOOTH_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,

    /// Honour the `x-meshsmooth-test-hook` request header (`panic`,
    /// `sleep=MS`). For the end-to-end tests only.
    #[arg(long, env = "MESHSMOOTH_ENABLE_TEST_HOOKS", hide = true)]
    pub enable_test_hooks: bool,
}

/// Log output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per line.
    Json,
}

impl ServeArgs {
    /// Worker count: the setting, or the number of available cores.
    pub fn worker_count(&self) -> usize {
        self.workers
            .or_else(|| std::thread::available_parallelism().ok())
            .map_or(1, NonZeroUsize::get)
    }

    /// Read limits for uploads.
    pub fn read_limits(&self) -> ReadLimits {
        ReadLimits {
            max_vertices: self.max_vertices,
            max_faces: self.max_faces,
        }
    }
}

/// Parses a byte size: a number with an optional `B`, `KB`, `KiB`, `MB`,
/// `MiB`, `GB`, `GiB`, `TB` or `TiB` suffix (case-insensitive).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let s = s.trim();
    let split = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(s.len());
    let (number, unit) = s.split_at(split);
    let factor: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "kb" => 1_000,
        "kib" | "k" => 1 << 10,
        "mb" => 1_000_000,
        "mib" | "m" => 1 << 20,
        "gb" => 1_000_000_000,
        "gib" | "g" => 1 << 30,
        "tb" => 1_000_000_000_000,
        "tib" | "t" => 1 << 40,
        other => {
            return Err(format!(
                "unknown size unit `{other}` (use B, KiB, MiB, GiB)"
            ));
        }
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{s}` is not a size (e.g. 512MiB)"))?;
    let bytes = value * factor as f64;
    if !bytes.is_finite() || bytes < 0.0 || bytes > u64::MAX as f64 {
        return Err(format!("`{s}` is out of range"));
    }
    Ok(bytes.round() as u64)
}

/// Parses a duration: a number with an optional `ms`, `s`, `m` or `h`
/// suffix; a bare number is seconds.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let split = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(s.len());
    let (number, unit) = s.split_at(split);
    let seconds_per_unit = match unit.trim() {
        "ms" => 0.001,
        "" | "s" => 1.0,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        other => return Err(format!("unknown duration unit `{other}` (use ms, s, m, h)")),
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{s}` is not a duration (e.g. 30s, 10m)"))?;
    Duration::try_from_secs_f64(value * seconds_per_unit)
        .map_err(|_| format!("`{s}` is out of range"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        serve: ServeArgs,
    }

    #[test]
    fn sizes_parse_with_units() {
        assert_eq!(parse_size("512MiB"), Ok(512 << 20));
        assert_eq!(parse_size("2GiB"), Ok(2 << 30));
        assert_eq!(parse_size("64kib"), Ok(64 << 10));
        assert_eq!(parse_size("1.5KB"), Ok(1500));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert!(parse_size("12 parsecs").is_err());
        assert!(parse_size("MiB").is_err());
        assert!(parse_size("").is_err());
    }

    #[test]
    fn durations_parse_with_units() {
        assert_eq!(parse_duration("30s"), Ok(Duration::from_secs(30)));
        assert_eq!(parse_duration("10m"), Ok(Duration::from_secs(600)));
        assert_eq!(parse_duration("1h"), Ok(Duration::from_secs(3600)));
        assert_eq!(parse_duration("250ms"), Ok(Duration::from_millis(250)));
        assert_eq!(parse_duration("2"), Ok(Duration::from_secs(2)));
        assert!(parse_duration("3 fortnights").is_err());
        assert!(parse_duration("-1s").is_err());
    }

    #[test]
    fn defaults_are_pinned() {
        let a = Cli::try_parse_from(["x"]).unwrap().serve;
        assert_eq!(a.listen, "127.0.0.1:8080".parse().unwrap());
        assert_eq!(a.workers, None);
        assert!(a.worker_count() >= 1);
        assert_eq!(a.queue_capacity, 16);
        assert_eq!(a.job_time_limit, Duration::from_secs(600));
        assert_eq!(a.result_ttl, Duration::from_secs(3600));
        assert_eq!(a.result_memory, 2 << 30);
        assert_eq!(a.max_upload_bytes, 512 << 20);
        assert_eq!(a.read_limits(), ReadLimits::default());
        assert_eq!(a.max_params_bytes, 64 << 10);
        assert_eq!(a.upload_timeout, Duration::from_secs(300));
        assert_eq!(a.header_timeout, Duration::from_secs(30));
        assert_eq!(a.request_timeout, Duration::from_secs(30));
        assert_eq!(a.shutdown_timeout, Duration::from_secs(30));
        assert!(a.cors_origins.is_empty());
        assert_eq!(a.log_format, LogFormat::Text);
        assert_eq!(a.log, "info");
        assert_eq!(a.http_threads.get(), 2);
        assert!(!a.enable_test_hooks);
        assert_eq!(a.store, "memory");
        assert_eq!(a.lease, Duration::from_secs(15));
        assert_eq!(a.max_attempts, 3);
    }

    #[test]
    fn flags_override_defaults() {
        let a = Cli::try_parse_from([
            "x",
            "--workers",
            "3",
            "--queue-capacity",
            "2",
            "--result-memory",
            "1MiB",
            "--cors-origins",
            "https://a.example,https://b.example",
            "--log-format",
            "json",
        ])
        .unwrap()
        .serve;
        assert_eq!(a.worker_count(), 3);
        assert_eq!(a.queue_capacity, 2);
        assert_eq!(a.result_memory, 1 << 20);
        assert_eq!(a.cors_origins, ["https://a.example", "https://b.example"]);
        assert_eq!(a.log_format, LogFormat::Json);
        assert!(Cli::try_parse_from(["x", "--workers", "0"]).is_err());
    }
}
