//! The analytic families at their seeded placements as mesh files, and the
//! RMS distance of any smoother's output to the true surface: what
//! `eval/compare_shapes.py` runs meshsmooth and its peers on.
//!
//! `cargo run --release -p meshsmooth-core --example shape_meshes -- list`
//! prints the families' short names, in order;
//! `... -- dump DIR [PLACEMENTS]`
//! writes `DIR/{shape}_{seed}_{vox,mc}.obj` for every family of
//! [`shapes::placement_families`] and seeds 0 to 7, or 0 to `PLACEMENTS - 1`
//! (voxel quads and marching cubes of the same mask);
//! `... -- rms SHAPE SEED FILE.obj` prints the RMS distance, in voxels, of
//! the OBJ's vertices (in file order) to that placed shape; `... -- bias
//! SHAPE SEED FILE.obj` their mean signed distance (positive outside);
//! `... -- signed SHAPE SEED FILE.obj` each vertex's signed distance, one
//! per line, for a look at where the error is.

use glam::DVec3;
use meshsmooth_core::shapes::{self, Shape};
use meshsmooth_core::{Mesh, io};
use std::path::Path;
use std::process::ExitCode;

/// The placements of a family the accuracy bars are judged on.
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
        ["dump", dir] => dump(Path::new(dir), PLACEMENTS),
        ["dump", dir, count] => match count.parse() {
            Ok(count) => dump(Path::new(dir), count),
            Err(_) => Err(format!("bad placement count {count}")),
        },
        ["rms", shape, seed, file] => distances(shape, seed, Path::new(file), Report::Rms),
        ["bias", shape, seed, file] => distances(shape, seed, Path::new(file), Report::Bias),
        ["signed", shape, seed, file] => distances(shape, seed, Path::new(file), Report::Signed),
        _ => {
            Err("usage: shape_meshes list | dump DIR [PLACEMENTS] | rms|bias|signed SHAPE SEED FILE.obj".into())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("shape_meshes: {e}");
            ExitCode::FAILURE
        }
    }
}

fn dump(dir: &Path, placements: u64) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    for (short, _, shape) in shapes::placement_families() {
        for seed in 0..placements {
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

/// What [`distances`] prints of the vertices' distances to the shape.
#[derive(Clone, Copy, PartialEq)]
enum Report {
    /// Their RMS.
    Rms,
    /// Their mean signed distance (positive outside): whether a smoother
    /// leaves the shape too thick or too thin.
    Bias,
    /// Each vertex's signed distance, in file order.
    Signed,
}

/// The distances of `file`'s vertices to the placed shape, as `report`
/// asks.
fn distances(short: &str, seed: &str, file: &Path, report: Report) -> Result<(), String> {
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
    let signed = |p: DVec3| {
        placed
            .distance(p)
            .copysign(if placed.inside(p) { -1.0 } else { 1.0 })
    };
    match report {
        Report::Rms => println!("{}", shapes::rms_distance(&placed, positions)),
        Report::Bias => {
            let sum: f64 = positions.iter().map(|&p| signed(p)).sum();
            println!("{}", sum / positions.len().max(1) as f64);
        }
        Report::Signed => {
            for &p in positions {
                println!("{}", signed(p));
            }
        }
    }
    Ok(())
}
