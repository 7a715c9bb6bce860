//! Prints, for the segmentation-like shapes (thin shells, thin tubes,
//! tangent spheres, folded sheets) and the analytic shapes of the engine
//! targets, the default pipeline's figures at 8 seeded grid placements
//! (sub-voxel offset and rotation): RMS distance to the true surface of the
//! input and the output, the worst placement against the median, and the
//! defects and volume change of the worst.
//!
//! `cargo run --release -p meshsmooth-core --example placements [-- JSON-PARAMS [SHAPES]]`
//! (SHAPES: comma-separated short names of
//! [`shapes::placement_families`], e.g. `sphere,tube1.5`).

use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, NoProgress, Params, run};
use std::sync::atomic::AtomicBool;

const PLACEMENTS: u64 = 8;

fn main() {
    let params: Params = match std::env::args().nth(1) {
        Some(j) => serde_json::from_str(&j).expect("params JSON"),
        None => Params::default(),
    };
    println!(
        "{:<26} {:>6} {:>7} {:>7} {:>7} {:>6} {:>5} {:>5} {:>6} {:>7} {:>8}",
        "shape (8 placements)",
        "verts",
        "rms in",
        "median",
        "worst",
        "w/med",
        "inv",
        "twst",
        "min°",
        "vol%",
        "held"
    );
    let only = std::env::args().nth(2);
    for (short, name, shape) in shapes::placement_families() {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|n| n == short))
        {
            continue;
        }
        let shape = &*shape;
        for mc in [false, true] {
            let mut rows = Vec::new();
            for seed in 0..PLACEMENTS {
                let shape = shapes::placed(shape, seed);
                let mask = shapes::voxel_mask(&shape);
                let mesh = if mc {
                    shapes::marching_cubes_mesh(&mask)
                } else {
                    shapes::voxel_boundary_mesh(&mask)
                };
                rows.push(measure(&shape, &mesh, &params));
            }
            let mut rms: Vec<f64> = rows.iter().map(|r| r.rms_out).collect();
            rms.sort_by(f64::total_cmp);
            let median = 0.5 * (rms[3] + rms[4]);
            let worst = rows
                .iter()
                .max_by(|a, b| a.rms_out.total_cmp(&b.rms_out))
                .expect("8 rows");
            let sum = |f: fn(&Row) -> u64| rows.iter().map(f).sum::<u64>();
            println!(
                "{:<26} {:>6} {:>7.4} {:>7.4} {:>7.4} {:>6.2} {:>5} {:>5} {:>6.1} {:>+7.2} {:>8}",
                format!("{} {name}", if mc { "mc" } else { "vox" }),
                worst.vertices,
                rows.iter().map(|r| r.rms_in).sum::<f64>() / rows.len() as f64,
                median,
                worst.rms_out,
                worst.rms_out / median,
                sum(|r| r.inverted),
                sum(|r| r.twisted),
                rows.iter().map(|r| r.min_angle).fold(180.0, f64::min),
                100.0
                    * rows
                        .iter()
                        .map(|r| r.volume)
                        .fold(0.0, |m: f64, v| if v.abs() > m.abs() { v } else { m }),
                sum(|r| r.held),
            );
        }
    }
}

struct Row {
    vertices: usize,
    rms_in: f64,
    rms_out: f64,
    inverted: u64,
    twisted: u64,
    min_angle: f64,
    volume: f64,
    held: u64,
}

fn measure(shape: &dyn Shape, mesh: &Mesh, params: &Params) -> Row {
    let out = run(mesh, params, &NoProgress, &AtomicBool::new(false)).expect("smooths");
    let fin = out.report.stages.final_stage.as_ref().expect("final stage");
    Row {
        vertices: mesh.num_vertices(),
        rms_in: shapes::rms_distance(shape, mesh.positions()),
        rms_out: shapes::rms_distance(shape, &out.positions),
        inverted: fin.inverted_faces,
        twisted: fin.twisted_quads,
        min_angle: fin.triangle_angles.min_deg.unwrap_or(180.0),
        volume: fin.volume.and_then(|v| v.relative_change).unwrap_or(0.0),
        held: out
            .report
            .wang_yu
            .as_ref()
            .and_then(|w| w.fidelity_held_back)
            .unwrap_or(0),
    }
}
