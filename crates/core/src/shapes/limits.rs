//! Meshes that test the bound on work per upload: a fan around one vertex,
//! one huge polygon, and many closed solids whose vertices or faces stay
//! just under the upload limits (`pipeline::MAX_VALENCE`,
//! `pipeline::MAX_FACE_CORNERS`). Unit circles, solids four units apart
//! along x.

use crate::mesh::Mesh;
use glam::DVec3;

/// `n` points on a unit circle around `centre`, `z` above it, the first at
/// angle 0, counter-clockwise seen from +z.
fn circle(centre: DVec3, n: usize, z: f64) -> impl Iterator<Item = DVec3> {
    (0..n).map(move |i| {
        let (sin, cos) = (std::f64::consts::TAU * i as f64 / n as f64).sin_cos();
        centre + DVec3::new(cos, sin, z)
    })
}

/// Vertex 0 shared by `n` triangles around a wavy rim (vertices 1 ..= `n`).
pub fn fan(n: usize) -> Mesh {
    let mut p = vec![DVec3::ZERO];
    p.extend((0..n).map(|i| {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        DVec3::new(a.cos(), a.sin(), 0.1 * (7.0 * a).sin())
    }));
    let faces: Vec<[u32; 3]> = (0..n as u32)
        .map(|i| [0, i + 1, (i + 1) % n as u32 + 1])
        .collect();
    Mesh::from_polygons(p, &faces).expect("fan")
}

/// One polygon of `n` corners on a unit circle.
pub fn big_face(n: usize) -> Mesh {
    let p: Vec<DVec3> = circle(DVec3::ZERO, n, 0.0).collect();
    Mesh::from_polygons(p, &[(0..n as u32).collect::<Vec<u32>>()]).expect("big face")
}

/// `count` closed double cones. Each has tips at z = 1 and z = -1 (its
/// first two vertices, each with `rim` edges) and a rim of `rim` vertices
/// at z = 0, four edges each; every face is a sliver once the rim is longer
/// than a few dozen vertices.
pub fn double_cones(count: usize, rim: usize) -> Mesh {
    let (mut p, mut faces) = (Vec::new(), Vec::new());
    let n = rim as u32;
    for c in 0..count {
        let centre = DVec3::new(4.0 * c as f64, 0.0, 0.0);
        let base = p.len() as u32;
        p.push(centre + DVec3::Z);
        p.push(centre - DVec3::Z);
        p.extend(circle(centre, rim, 0.0));
        for i in 0..n {
            let (a, b) = (base + 2 + i, base + 2 + (i + 1) % n);
            faces.push([base, a, b]);
            faces.push([base + 1, b, a]);
        }
    }
    Mesh::from_polygons(p, &faces).expect("double cones")
}

/// `count` closed prisms. Each has a bottom cap (its first `corners`
/// vertices, at z = 0) and a top cap (the next `corners`, at z = 1), each
/// one polygon, and a quad per side; a prism's first face is its bottom
/// cap.
pub fn prisms(count: usize, corners: usize) -> Mesh {
    let (mut p, mut faces): (Vec<DVec3>, Vec<Vec<u32>>) = (Vec::new(), Vec::new());
    let n = corners as u32;
    for c in 0..count {
        let centre = DVec3::new(4.0 * c as f64, 0.0, 0.0);
        let base = p.len() as u32;
        p.extend(circle(centre, corners, 0.0));
        p.extend(circle(centre, corners, 1.0));
        faces.push((0..n).rev().map(|i| base + i).collect());
        faces.push((0..n).map(|i| base + n + i).collect());
        for i in 0..n {
            let j = (i + 1) % n;
            faces.push(vec![base + i, base + j, base + n + j, base + n + i]);
        }
    }
    Mesh::from_polygons(p, &faces).expect("prisms")
}
