//! Speed and memory of the full default pipeline on voxel spheres of about
//! 72k, 228k and 1M vertices (r = 62, 110, 231), per stage.
//!
//! `cargo bench -p meshsmooth-core --bench pipeline` (each size runs in its
//! own process so its peak memory, VmHWM, is its own). Prints figures; asserts
//! nothing. `-- 110` runs one radius in this process.

use meshsmooth_core::{NoProgress, Params, run, shapes};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn one(radius: f64) {
    let t = Instant::now();
    let (sphere, mesh) = shapes::voxel_sphere(radius);
    let gen_ms = t.elapsed().as_secs_f64() * 1e3;
    let before = peak_rss_bytes().unwrap_or(0);
    let t = Instant::now();
    let out = run(
        &mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .expect("run");
    let wall = t.elapsed().as_secs_f64();
    let n = mesh.num_vertices();
    let peak = peak_rss_bytes().unwrap_or(0);
    let stages: Vec<String> = out
        .report
        .timings
        .iter()
        .map(|s| format!("{} {:.0}", s.stage, s.ms))
        .collect();
    println!(
        "r={radius:<4} vertices {n:>8}  wall {wall:>6.3} s  ({:.2} us/vertex)  rms {:.4}  peak RSS {:.0} MB = {:.0} B/vertex (mesh generation {gen_ms:.0} ms, RSS before run {:.0} MB)",
        wall * 1e6 / n as f64,
        shapes::rms_distance(&sphere, &out.positions),
        peak as f64 / 1e6,
        peak as f64 / n as f64,
        before as f64 / 1e6,
    );
    println!("        stages (ms): {}", stages.join(", "));
    if let Some(w) = &out.report.wang_yu {
        let f = &w.adaptive_fits;
        println!(
            "        adaptive fits per vertex: {:.2}",
            (f.cubic + f.quadric + f.plane + f.fixed) as f64 / n as f64
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    if let Some(r) = args.first().and_then(|a| a.parse::<f64>().ok()) {
        one(r);
        return;
    }
    println!("threads: {}", rayon::current_num_threads());
    let exe = std::env::current_exe().expect("own path");
    for r in ["62", "110", "231"] {
        let status = Command::new(&exe).arg(r).status().expect("spawn");
        assert!(status.success());
    }
}
