//! The analytic families at their seeded placements as mesh files, and the
//! RMS distance of any smoother's output to the true surface: what
//! `eval/compare_shapes.py` runs meshsmooth and its peers on.
//!
//! `cargo run --release -p meshsmooth-core --example shape_meshes -- list`
//! prints the families' short names, in order;
//! `... -- dump DIR`
//! writes `DIR/{shape}_{seed}_{vox,mc}.obj` for every family of
//! [`shapes::placement_families`] and seeds 0 to 7 (voxel quads and
//! marching cubes of the same mask);
//! `... -- rms SHAPE SEED FILE.obj` prints the RMS distance, in voxels, of
//! the OBJ's vertices (in file order) to that placed shape; `... -- bias
//! SHAPE SEED FILE.obj` their mean signed distance (positive outside).

use glam::DVec3;
use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, io};
use std::path::Path;
use std::process::ExitCode;

const PLACEMENTS: u64 = 8;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.iter().map(String::as_str).collect::<Vec<_>>()[..] {
        ["list"] => {
            for (short, _, _) in shapes::placement_families() {
                println!("{short}");
            }
            Ok(())
        }
        ["dump", dir] => dump(Path::new(dir)),
        ["rms", shape, seed, file] => distances(shape, seed, Path::new(file), false),
        ["bias", shape, seed, file] => distances(shape, seed, Path::new(file), true),
        _ => Err("usage: shape_meshes list | dump DIR | rms|bias SHAPE SEED FILE.obj".into()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("shape_meshes: {e}");
            ExitCode::FAILURE
        }
    }
}

fn dump(dir: &Path) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    for (short, _, shape) in shapes::placement_families() {
        for seed in 0..PLACEMENTS {
            let mask = shapes::voxel_mask(&shapes::placed(&*shape, seed));
            for (kind, mesh) in [
                ("vox", shapes::voxel_boundary_mesh(&mask)),
                ("mc", shapes::marching_cubes_mesh(&mask)),
            ] {
                let path = dir.join(format!("{short}_{seed}_{kind}.obj"));
                std::fs::write(&path, obj(&mesh))
                    .map_err(|e| format!("{}: {e}", path.display()))?;
            }
        }
    }
    Ok(())
}

fn obj(mesh: &Mesh) -> String {
    let mut out = String::new();
    for p in mesh.positions() {
        out += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for face in mesh.faces() {
        out += "f";
        for v in face {
            out += &format!(" {}", v + 1);
        }
        out += "\n";
    }
    out
}

/// The RMS distance of `file`'s vertices to the placed shape, or with
/// `signed` their mean signed distance (positive outside): whether a
/// smoother leaves the shape too thick or too thin.
fn distances(short: &str, seed: &str, file: &Path, signed: bool) -> Result<(), String> {
    let seed: u64 = seed.parse().map_err(|_| format!("bad seed {seed}"))?;
    let (_, _, shape) = shapes::placement_families()
        .into_iter()
        .find(|(s, _, _)| *s == short)
        .ok_or_else(|| format!("no shape {short}"))?;
    let bytes = std::fs::read(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let doc =
        io::read(&bytes, io::Format::Obj, &io::ReadLimits::default()).map_err(|e| e.to_string())?;
    let positions: &[DVec3] = doc.mesh.positions();
    let placed = shapes::placed(&*shape, seed);
    if signed {
        let sum: f64 = positions
            .iter()
            .map(|&p| {
                placed
                    .distance(p)
                    .copysign(if placed.inside(p) { -1.0 } else { 1.0 })
            })
            .sum();
        println!("{}", sum / positions.len().max(1) as f64);
    } else {
        println!("{}", shapes::rms_distance(&placed, positions));
    }
    Ok(())
}
