//! Documented behaviour at boundary and non-manifold vertices: with the
//! default `boundary: fixed` they do not move; with `normal_only` boundary
//! vertices move along their normal only; nothing explodes, nothing tears.

use glam::DVec3;
use meshsmooth_core::params::BoundaryRule;
use meshsmooth_core::shapes::{VoxelMask, voxel_boundary_mesh};
use meshsmooth_core::{Mesh, NoProgress, Params, Topology, VertexKind, run};
use std::sync::atomic::AtomicBool;

/// A bumpy open height field on a 24 x 24 quad grid.
fn bumpy_grid() -> Mesh {
    checkerboard(0.3)
}

/// A 24 x 24 quad grid with heights `+-amplitude` in a checkerboard.
fn checkerboard(amplitude: f64) -> Mesh {
    let n = 24u32;
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let z = if (i + j) % 2 == 0 {
                amplitude
            } else {
                -amplitude
            };
            p.push(DVec3::new(i as f64, j as f64, z));
        }
    }
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            f.push([a, a + 1, a + n + 2, a + n + 1]);
        }
    }
    Mesh::from_polygons(p, &f).unwrap()
}

fn smooth(mesh: &Mesh, params: &Params) -> Vec<DVec3> {
    run(mesh, params, &NoProgress, &AtomicBool::new(false))
        .unwrap()
        .positions
}

#[test]
fn fixed_boundary_stays_and_interior_flattens() {
    let m = bumpy_grid();
    let t = Topology::build(&m);
    let out = smooth(&m, &Params::default());
    let mut interior_rms = 0.0;
    let mut count = 0;
    for (v, (a, b)) in out.iter().zip(m.positions()).enumerate() {
        assert!(a.is_finite());
        match t.kind(v) {
            VertexKind::Boundary => assert_eq!(a, b, "boundary vertex {v} moved"),
            _ => {
                // Away from the fixed rim the checkerboard bumps flatten.
                let (x, y) = (b.x, b.y);
                if (4.0..=20.0).contains(&x) && (4.0..=20.0).contains(&y) {
                    interior_rms += a.z * a.z;
                    count += 1;
                }
            }
        }
    }
    let rms = (interior_rms / count as f64).sqrt();
    assert!(rms < 0.1, "interior bumps RMS {rms} (input 0.3)");
}

#[test]
fn normal_only_boundary_moves_along_the_normal() {
    let m = checkerboard(0.05);
    let t = Topology::build(&m);
    let params = Params {
        boundary: BoundaryRule::NormalOnly,
        ..Params::default()
    };
    let params = Params {
        quality: meshsmooth_core::params::QualityParams {
            enabled: false,
            ..Default::default()
        },
        ..params
    };
    let out = smooth(&m, &params);
    let mut moved = 0;
    for (v, (a, b)) in out.iter().zip(m.positions()).enumerate() {
        if t.kind(v) == VertexKind::Boundary && a != b {
            moved += 1;
            // Low bumps keep the normals near vertical: the rim moves (almost)
            // only in z, and by no more than the bumps' height.
            let d = *a - *b;
            assert!(d.length() < 0.2, "vertex {v} moved {d}");
            let tangential = d.x.abs() + d.y.abs();
            if t.vertex_faces(v).len() == 1 {
                // A corner's normal is its one face's, which tilts while the
                // 2-ring passes work on the checkerboard: it may drift
                // sideways, but by a few hundredths of an edge at most.
                assert!(tangential < 0.08, "corner {v} moved {d}");
            } else {
                assert!(tangential < 0.5 * d.z.abs() + 1e-9, "vertex {v} moved {d}");
            }
        }
    }
    assert!(moved > 0);
}

#[test]
fn voxels_touching_along_an_edge_keep_their_pinch() {
    // Two 5x5x5 blocks touching only along one edge: a non-manifold edge
    // shared by four faces.
    let mask = VoxelMask::from_fn(glam::IVec3::ZERO, [14, 14, 7], |i, j, k| {
        (1..6).contains(&k)
            && ((1..6).contains(&i) && (1..6).contains(&j)
                || (6..11).contains(&i) && (6..11).contains(&j))
    });
    let m = voxel_boundary_mesh(&mask);
    let t = Topology::build(&m);
    assert!(t.num_non_manifold_edges() > 0);
    let out = smooth(&m, &Params::default());
    // A smoothed block rounds its corners; nothing may move by half a block.
    let half_block = 2.5;
    for (v, (a, b)) in out.iter().zip(m.positions()).enumerate() {
        assert!(a.is_finite());
        assert!(
            a.distance(*b) < half_block,
            "vertex {v} ({:?}) jumped by {}",
            t.kind(v),
            a.distance(*b)
        );
        if t.kind(v) == VertexKind::NonManifold {
            assert_eq!(a, b, "non-manifold vertex {v} moved");
        }
    }
}
