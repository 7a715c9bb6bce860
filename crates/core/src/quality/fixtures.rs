//! Hand-built meshes for the quality tests.

use crate::mesh::Mesh;
use crate::shapes::{CENTER_OFFSET, voxel_sphere};
use glam::DVec3;

/// Index of grid vertex `(i, j)` in [`grid`]`(n)`.
pub fn at(n: u32, i: u32, j: u32) -> usize {
    (j * (n + 1) + i) as usize
}

/// An `n` x `n` grid of unit quads in the plane z = 0, normals +z.
pub fn grid(n: u32) -> Mesh {
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            p.push(DVec3::new(i as f64, j as f64, 0.0));
        }
    }
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            f.push([a, a + 1, a + n + 2, a + n + 1]);
        }
    }
    Mesh::from_polygons(p, &f).expect("valid grid")
}

/// Two hexagonal fans sharing their centre, vertex 0 at `centre` (a
/// non-manifold vertex, where two sheets meet): one of unit radius in the
/// plane z = 0 around the origin, one of radius 2.8 in the plane x = 0
/// around (0, 3, 0). Rim vertices 1-6 and 7-12, at 0, 60, ..., 300
/// degrees; the rims are boundaries. With the centre near the first fan's
/// rim between its vertices at 60 and 120 degrees, that face is a sliver,
/// and the centre's neighbours' mean (0, 1.5, 0) lies beyond that rim.
pub fn two_fans(centre: DVec3) -> Mesh {
    let mut positions = vec![centre];
    let mut faces = Vec::new();
    for fan in 0..2u32 {
        let first = positions.len() as u32;
        for k in 0..6 {
            let (sin, cos) = (60.0 * k as f64).to_radians().sin_cos();
            positions.push(if fan == 0 {
                DVec3::new(cos, sin, 0.0)
            } else {
                DVec3::new(0.0, 3.0 + 2.8 * cos, 2.8 * sin)
            });
        }
        for k in 0..6 {
            faces.push(vec![0, first + k, first + (k + 1) % 6]);
        }
    }
    Mesh::from_polygons(positions, &faces).expect("two fans")
}

/// A voxel-like staircase, open, normals up: `steps` terraces of `width`
/// unit quads along x, each one voxel above the last, joined by unit
/// risers facing -x, `depth` quads along y. Returns the mesh and the
/// staircase flattened onto its mean plane by orthogonal projection (what
/// smoothing does to it), the risers becoming slivers.
pub fn flattened_staircase(steps: u32, width: u32, depth: u32) -> (Mesh, Vec<DVec3>, Plane) {
    let mut p = Vec::new();
    let mut faces = Vec::new();
    let row = depth + 1;
    // Columns of vertices along x: each step has `width` terrace columns
    // then a riser column pair.
    let mut columns: Vec<(f64, f64)> = Vec::new(); // (x, z)
    for k in 0..steps {
        // The riser's top column starts terrace k (its bottom column ended
        // terrace k - 1).
        let first = if k == 0 { 0 } else { k * width };
        columns.push((first as f64, k as f64));
        for i in 1..=width {
            columns.push(((k * width + i) as f64, k as f64));
        }
    }
    for &(x, z) in &columns {
        for j in 0..=depth {
            p.push(DVec3::new(x, j as f64, z));
        }
    }
    for c in 0..columns.len() as u32 - 1 {
        for j in 0..depth {
            let a = c * row + j;
            let b = (c + 1) * row + j;
            // Counter-clockwise seen from above (+z) for terraces and from
            // -x for risers.
            faces.push([a, b, b + 1, a + 1]);
        }
    }
    let mesh = Mesh::from_polygons(p, &faces).expect("valid staircase");
    let slope = 1.0 / width as f64;
    let normal = DVec3::new(-slope, 0.0, 1.0).normalize();
    // Terrace k spans x in [k w, (k + 1) w] at z = k: mean z = x / w - 1/2.
    let origin = DVec3::new(0.0, 0.0, -0.5);
    let plane = Plane { origin, normal };
    let flat = mesh
        .positions()
        .iter()
        .map(|&q| q - plane.signed_distance(q) * normal)
        .collect();
    (mesh, flat, plane)
}

/// A plane through `origin` with unit `normal`.
#[derive(Debug, Clone, Copy)]
pub struct Plane {
    pub origin: DVec3,
    pub normal: DVec3,
}

impl Plane {
    pub fn signed_distance(&self, q: DVec3) -> f64 {
        (q - self.origin).dot(self.normal)
    }
}

/// The voxel sphere of `radius` with every vertex pushed radially onto the
/// true sphere: the flattened-staircase slivers (and some inverted faces)
/// that smoothing leaves, at their worst. Returns the mesh (input
/// positions) and the projected positions.
pub fn radially_projected_sphere(radius: f64) -> (Mesh, Vec<DVec3>) {
    let (_, mesh) = voxel_sphere(radius);
    let projected = mesh
        .positions()
        .iter()
        .map(|&q| CENTER_OFFSET + (q - CENTER_OFFSET).normalize() * radius)
        .collect();
    (mesh, projected)
}

/// Smallest split-triangle angle of `faces` (all when `None`), degrees,
/// computed with `acos` independently of the code under test.
pub fn min_split_angle(mesh: &Mesh, positions: &[DVec3], faces: Option<&[usize]>) -> f64 {
    let all: Vec<usize> = (0..mesh.num_faces()).collect();
    let mut m = 180.0f64;
    for &f in faces.unwrap_or(&all) {
        let face = mesh.face(f);
        let o = positions[face[0] as usize];
        for j in 1..face.len() - 1 {
            let (a, b) = (positions[face[j] as usize], positions[face[j + 1] as usize]);
            for (x, y, z) in [(o, a, b), (a, b, o), (b, o, a)] {
                m = m.min((y - x).angle_between(z - x).to_degrees());
            }
        }
    }
    m
}

/// A patch of a real mesh as a fix met it (`testdata/`): each `v` line
/// holds a vertex's input position, then its position when the fix began;
/// each `f` line a face's corners (0-based). Returns the mesh (at the input
/// positions), the input positions and the fix's starting positions.
pub fn patch(text: &str) -> (Mesh, Vec<DVec3>, Vec<DVec3>) {
    let (mut input, mut start, mut faces) = (Vec::new(), Vec::new(), Vec::new());
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                let x: Vec<f64> = words.map(|w| w.parse().expect("a number")).collect();
                input.push(DVec3::new(x[0], x[1], x[2]));
                start.push(DVec3::new(x[3], x[4], x[5]));
            }
            Some("f") => faces.push(
                words
                    .map(|w| w.parse().expect("a vertex index"))
                    .collect::<Vec<u32>>(),
            ),
            _ => {}
        }
    }
    let mesh = Mesh::from_polygons(input.clone(), &faces).expect("a valid patch");
    (mesh, input, start)
}
