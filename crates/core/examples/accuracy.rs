//! Prints the accuracy and mesh-quality figures of the default pipeline on
//! the analytic shapes of issue 3: voxel-boundary quad meshes and
//! marching-cubes triangle meshes of a sphere r=12 and r=40, a torus R=20
//! r=8 and an ellipsoid 30x20x12 (voxel units).
//!
//! `cargo run --release -p meshsmooth-core --example accuracy [-- JSON-PARAMS]`

use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, NoProgress, Params, run};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

fn main() {
    let params: Params = match std::env::args().nth(1) {
        Some(j) => serde_json::from_str(&j).expect("params JSON"),
        None => Params::default(),
    };
    let only = std::env::args().nth(2);
    println!(
        "{:<22} {:>7} {:>8} {:>8} {:>9} {:>7} {:>6} {:>4} {:>4} {:>5} {:>5} {:>8}",
        "mesh",
        "verts",
        "rms in",
        "rms out",
        "vol err%",
        "min°",
        "<20°",
        "twst",
        "inv",
        "<30°",
        "mean k",
        "ms"
    );
    type Make = Box<dyn Fn() -> (Box<dyn Shape>, Mesh)>;
    let cases: Vec<(&str, Make)> = vec![
        (
            "voxel sphere r=12",
            Box::new(|| box_it(shapes::voxel_sphere(12.0))),
        ),
        (
            "voxel torus 20/8",
            Box::new(|| box_it(shapes::voxel_torus(20.0, 8.0))),
        ),
        (
            "voxel ellipsoid",
            Box::new(|| box_it(shapes::voxel_ellipsoid(30.0, 20.0, 12.0))),
        ),
        (
            "voxel sphere r=40",
            Box::new(|| box_it(shapes::voxel_sphere(40.0))),
        ),
        (
            "mc sphere r=12",
            Box::new(|| box_it(shapes::mc_sphere(12.0))),
        ),
        (
            "mc torus 20/8",
            Box::new(|| box_it(shapes::mc_torus(20.0, 8.0))),
        ),
        (
            "mc ellipsoid",
            Box::new(|| box_it(shapes::mc_ellipsoid(30.0, 20.0, 12.0))),
        ),
        (
            "mc sphere r=40",
            Box::new(|| box_it(shapes::mc_sphere(40.0))),
        ),
    ];
    for (name, make) in cases {
        if only.as_ref().is_some_and(|o| !name.contains(o.as_str())) {
            continue;
        }
        let (shape, mesh) = make();
        let t = Instant::now();
        let out = run(&mesh, &params, &NoProgress, &AtomicBool::new(false)).expect("run");
        let el = t.elapsed().as_secs_f64() * 1e3;
        let vol = meshsmooth_core::mesh::signed_volume(&mesh, &out.positions);
        let f = out.report.stages.final_stage.as_ref().expect("final stage");
        let meank = out.report.wang_yu.as_ref().map_or(0.0, |w| {
            let h = &w.ring_size_histogram;
            let n: u64 = h.iter().sum();
            h.iter()
                .enumerate()
                .map(|(k, c)| k as f64 * *c as f64)
                .sum::<f64>()
                / n.max(1) as f64
        });
        println!(
            "{:<22} {:>7} {:>8.4} {:>8.4} {:>+9.3} {:>7.2} {:>6} {:>4} {:>4} {:>5} {:>5.1} {:>8.0}",
            name,
            mesh.num_vertices(),
            shapes::rms_distance(shape.as_ref(), mesh.positions()),
            shapes::rms_distance(shape.as_ref(), &out.positions),
            (vol / shape.volume() - 1.0) * 100.0,
            f.triangle_angles.min_deg.unwrap_or(0.0),
            f.triangle_angles.below_20,
            f.twisted_quads,
            f.inverted_faces,
            f.triangle_angles.below_30,
            meank,
            el
        );
    }
}

fn box_it<S: Shape + 'static>((s, m): (S, Mesh)) -> (Box<dyn Shape>, Mesh) {
    (Box::new(s), m)
}
