//! Speed and memory of the full default pipeline on voxel spheres of about
//! 72k, 228k and 1M vertices (r = 62, 110, 231), per stage.
//!
//! `cargo bench -p meshsmooth-core --bench pipeline` (each size runs in its
//! own process so its peak memory, VmHWM, is its own). Prints figures; asserts
//! nothing. `-- 110` runs one radius in this process; `-- 110 5` runs it 5
//! times and ends with the median and fastest wall time and the median CPU
//! time (user + system, all threads): on a shared machine single runs vary
//! by 10% or more, so compare medians of runs taken in turn.
//!
//! `-- FILE.obj 5` (any format the service reads) times the pipeline on a
//! mesh file and on the r = 110 sphere in turn, 5 runs each, and ends with
//! the two medians per vertex and their ratio: how much more a real mesh
//! costs per vertex than the smooth sphere (reading the file not counted).
//!
//! `-- limits` times the shapes that test the promise that work is bounded
//! by the upload's size: a fan of 200 times [`MAX_VALENCE`] triangles and a
//! polygon of 100 times [`MAX_FACE_CORNERS`] corners (both refused), 300
//! double cones whose two tips have just under [`MAX_VALENCE`] edges each,
//! and 300 prisms capped by polygons of just under [`MAX_FACE_CORNERS`]
//! corners (both smoothed), each with its wall time and stages.

use meshsmooth_core::io::{Format, ReadLimits, read};
use meshsmooth_core::mesh::Mesh;
use meshsmooth_core::pipeline::{MAX_FACE_CORNERS, MAX_VALENCE};
use meshsmooth_core::report::QualityReport;
use meshsmooth_core::{NoProgress, Params, SmoothError, SmoothOutput, run, shapes};
use std::path::Path;
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU time of this process so far (user + system, all threads), in
/// seconds, from `/proc/self/stat` (in clock ticks of 1/100 s).
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are the
    // 14th and 15th fields of the whole line.
    let rest = &stat[stat.rfind(')')? + 2..];
    let mut fields = rest.split_whitespace().skip(11);
    let utime: f64 = fields.next()?.parse().ok()?;
    let stime: f64 = fields.next()?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// A report's stage timings, in milliseconds, as `name ms, ...`.
fn stage_times(report: &QualityReport) -> String {
    let stages: Vec<String> = report
        .timings
        .iter()
        .map(|s| format!("{} {:.0}", s.stage, s.ms))
        .collect();
    stages.join(", ")
}

/// One timed run at `radius`: prints its figures, returns (wall, CPU)
/// seconds. Peak memory is printed for a process's first run only (later
/// runs' peaks include what the earlier ones left to the allocator).
fn one(radius: f64, first: bool) -> (f64, f64) {
    let t = Instant::now();
    let (sphere, mesh) = shapes::voxel_sphere(radius);
    let gen_ms = t.elapsed().as_secs_f64() * 1e3;
    let before = peak_rss_bytes().unwrap_or(0);
    let cpu_before = cpu_seconds().unwrap_or(0.0);
    let t = Instant::now();
    let out = run(
        &mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .expect("run");
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_seconds().unwrap_or(0.0) - cpu_before;
    let n = mesh.num_vertices();
    let peak = peak_rss_bytes().unwrap_or(0);
    let memory = if first {
        format!(
            "peak RSS {:.0} MB = {:.0} B/vertex (mesh generation {gen_ms:.0} ms, RSS before run {:.0} MB)",
            peak as f64 / 1e6,
            peak as f64 / n as f64,
            before as f64 / 1e6,
        )
    } else {
        "peak RSS: first run only".to_string()
    };
    println!(
        "r={radius:<4} vertices {n:>8}  wall {wall:>6.3} s  ({:.2} us/vertex, CPU {cpu:.2} s)  rms {:.4}  {memory}",
        wall * 1e6 / n as f64,
        shapes::rms_distance(&sphere, &out.positions),
    );
    println!("        stages (ms): {}", stage_times(&out.report));
    if let Some(w) = &out.report.wang_yu {
        let f = &w.adaptive_fits;
        println!(
            "        adaptive fits per vertex: {:.2}",
            (f.cubic + f.quadric + f.plane + f.fixed) as f64 / n as f64
        );
    }
    (wall, cpu)
}

/// The default pipeline on `mesh`, and its wall seconds.
fn timed_run(mesh: &Mesh) -> (Result<SmoothOutput, SmoothError>, f64) {
    let t = Instant::now();
    let out = run(
        mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    );
    (out, t.elapsed().as_secs_f64())
}

/// One timed run on `mesh` (named `name`): prints its stages, returns the
/// wall seconds.
fn one_file(name: &str, mesh: &Mesh) -> f64 {
    let (out, wall) = timed_run(mesh);
    let out = out.expect("run");
    let n = mesh.num_vertices();
    println!(
        "{name}  vertices {n:>8}  wall {wall:>6.3} s  ({:.2} us/vertex)  stages (ms): {}",
        wall * 1e6 / n as f64,
        stage_times(&out.report)
    );
    wall
}

/// The mesh file at `path`, read as the service reads an upload of its
/// extension.
fn read_file(path: &Path) -> Mesh {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let format = Format::from_file_name(name)
        .unwrap_or_else(|| panic!("{}: not a mesh file extension", path.display()));
    let bytes = std::fs::read(path).expect("read the mesh file");
    read(&bytes, format, &ReadLimits::default())
        .expect("parse the mesh file")
        .mesh
}

/// `repeats` runs each of the file at `path` and the r = 110 sphere, in
/// turn; prints their medians per vertex and the file's over the sphere's.
fn file_against_sphere(path: &Path, repeats: usize) {
    let mesh = read_file(path);
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let (_, sphere) = shapes::voxel_sphere(110.0);
    let (mut file_us, mut sphere_us) = (Vec::new(), Vec::new());
    for _ in 0..repeats {
        file_us.push(one_file(name, &mesh) * 1e6 / mesh.num_vertices() as f64);
        sphere_us.push(one_file("sphere r=110", &sphere) * 1e6 / sphere.num_vertices() as f64);
    }
    let (f, s) = (median(file_us), median(sphere_us));
    println!(
        "{name}: {repeats} runs each, median {f:.2} us/vertex against the sphere's {s:.2}: {:.2}x",
        f / s
    );
}

/// Times the default pipeline on the shapes of `-- limits`.
fn limits() {
    let (fan_edges, face_corners) = (200 * MAX_VALENCE, 100 * MAX_FACE_CORNERS);
    let cases = [
        (
            format!("fan of {fan_edges} triangles"),
            shapes::fan(fan_edges),
        ),
        (
            format!("one face of {face_corners} corners"),
            shapes::big_face(face_corners),
        ),
        // Ten times the corners: refused in about ten times the time.
        (
            format!("one face of {} corners", 10 * face_corners),
            shapes::big_face(10 * face_corners),
        ),
        (
            format!("300 double cones, tips of {} edges", MAX_VALENCE - 2),
            shapes::double_cones(300, MAX_VALENCE - 2),
        ),
        (
            format!("300 prisms, caps of {} corners", MAX_FACE_CORNERS - 2),
            shapes::prisms(300, MAX_FACE_CORNERS - 2),
        ),
    ];
    for (name, mesh) in &cases {
        let (out, wall) = timed_run(mesh);
        let n = mesh.num_vertices();
        match out {
            Ok(out) => println!(
                "{name}: {n} vertices, smoothed in {wall:.3} s ({:.2} us/vertex); stages (ms): {}",
                wall * 1e6 / n as f64,
                stage_times(&out.report)
            ),
            Err(e) => println!("{name}: {n} vertices, refused in {wall:.3} s: {e}"),
        }
    }
}

/// The median of `x` (the upper one of an even count).
fn median(mut x: Vec<f64>) -> f64 {
    x.sort_by(f64::total_cmp);
    x[x.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    if let Some(r) = args.first().and_then(|a| a.parse::<f64>().ok()) {
        let repeats: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1).max(1);
        let runs: Vec<(f64, f64)> = (0..repeats).map(|i| one(r, i == 0)).collect();
        if repeats > 1 {
            let walls: Vec<f64> = runs.iter().map(|r| r.0).collect();
            let fastest = walls.iter().copied().fold(f64::INFINITY, f64::min);
            println!(
                "r={r}: {repeats} runs, wall median {:.3} s, fastest {fastest:.3} s, CPU median {:.2} s",
                median(walls),
                median(runs.iter().map(|r| r.1).collect()),
            );
        }
        return;
    }
    if args.first().is_some_and(|a| a == "limits") {
        limits();
        return;
    }
    if let Some(path) = args.first().map(Path::new).filter(|p| p.is_file()) {
        let repeats: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1).max(1);
        file_against_sphere(path, repeats);
        return;
    }
    println!("threads: {}", rayon::current_num_threads());
    let exe = std::env::current_exe().expect("own path");
    for r in ["62", "110", "231"] {
        let status = Command::new(&exe).arg(r).status().expect("spawn");
        assert!(status.success());
    }
}
