//! Documented behaviour at boundary and non-manifold vertices: with the
//! default `boundary: fixed` they do not move (but for the non-manifold
//! corners of a voxel lattice, relaxed within their dual voxels); with
//! `normal_only` boundary vertices move along their normal only; components
//! too small to fit stay; nothing explodes, nothing tears.

use glam::DVec3;
use meshsmooth_core::params::BoundaryRule;
use meshsmooth_core::shapes::{self, VoxelMask, voxel_boundary_mesh};
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
    let m = shapes::edge_touching_blocks();
    let t = Topology::build(&m);
    assert!(t.num_non_manifold_edges() > 0);
    let out = smooth(&m, &Params::default());
    let mut non_manifold_moved = 0;
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
        // The shared edge is a staircase edge like any other: the
        // relaxation moves its vertices too, but only within their dual
        // voxels, so the blocks still meet there.
        if t.kind(v) == VertexKind::NonManifold {
            let d = (*a - *b).abs().max_element();
            assert!(d <= 0.5 + 1e-9, "non-manifold vertex {v} moved {d}");
            non_manifold_moved += usize::from(d > 0.05);
        }
    }
    // The edge's ends are block corners: they round with the blocks.
    assert!(non_manifold_moved >= 2, "{non_manifold_moved}");
}

#[test]
fn a_component_too_small_to_fit_stays_where_it_is() {
    // A voxel block and, apart from it, a tetrahedron: no vertex of the
    // tetrahedron has the points a quadric fit needs, and a plane through
    // its other three corners would fold it.
    let mask = VoxelMask::from_fn(glam::IVec3::ZERO, [8, 8, 8], |i, j, k| {
        (1..6).contains(&i) && (1..6).contains(&j) && (1..6).contains(&k)
    });
    let block = voxel_boundary_mesh(&mask);
    let mut p = block.positions().to_vec();
    let mut f: Vec<Vec<u32>> = (0..block.num_faces())
        .map(|i| block.face(i).to_vec())
        .collect();
    let o = p.len() as u32;
    p.extend([
        DVec3::new(20.0, 0.0, 0.0),
        DVec3::new(21.0, 0.0, 0.0),
        DVec3::new(20.3, 1.0, 0.0),
        DVec3::new(20.4, 0.4, 0.9),
    ]);
    f.extend([
        vec![o, o + 2, o + 1],
        vec![o, o + 1, o + 3],
        vec![o + 1, o + 2, o + 3],
        vec![o + 2, o, o + 3],
    ]);
    let mesh = Mesh::from_polygons(p, &f).unwrap();
    for params in [
        Params::default(),
        Params {
            max_displacement: None,
            ..Params::default()
        },
    ] {
        let out = smooth(&mesh, &params);
        assert_eq!(&out[o as usize..], &mesh.positions()[o as usize..]);
        // The block itself is smoothed.
        assert!(
            out[..o as usize]
                .iter()
                .zip(mesh.positions())
                .any(|(a, b)| a != b)
        );
    }
}
