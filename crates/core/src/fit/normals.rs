//! Step 1: area-weighted vertex normals (algorithm notes section 1).
//!
//! `n_i = normalize(sum_{f in F_i} A_f)` where `A_f` is the polygon's vector
//! area ([`crate::mesh::vector_area`]), which already equals `area * normal`.

use crate::mesh::{Mesh, Topology, vector_area};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Unit area-weighted normal of every vertex, one entry per vertex;
/// `DVec3::ZERO` where the incident faces have no area (isolated or fully
/// degenerate vertices), which later steps treat as "do not move". Each
/// face's vector area is recomputed at each of its corners (a few flops)
/// rather than stored for all faces (24 bytes a face, at the run's peak).
pub fn vertex_normals(mesh: &Mesh, topo: &Topology, positions: &[DVec3]) -> Vec<DVec3> {
    (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| vertex_normal(mesh, topo, positions, v))
        .collect()
}

/// [`vertex_normals`] stored in single precision (12 bytes a vertex instead
/// of 24): what the fitting passes keep for every vertex, where a normal
/// picks a frame and decides which neighbours face the same way.
pub fn vertex_normals_f32(mesh: &Mesh, topo: &Topology, positions: &[DVec3]) -> Vec<Vec3> {
    (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| vertex_normal(mesh, topo, positions, v).as_vec3())
        .collect()
}

/// [`vertex_normals_f32`] from the faces' vector areas computed once each
/// ([`face_vector_areas_f32`], [`normal_from_areas`]): about half the
/// work, for 12 bytes a face held while the normals are summed (so not
/// where a run's memory peaks, in the adaptive passes).
pub fn vertex_normals_f32_by_faces(mesh: &Mesh, topo: &Topology, positions: &[DVec3]) -> Vec<Vec3> {
    let areas = face_vector_areas_f32(mesh, positions);
    (0..topo.num_vertices())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| normal_from_areas(topo, &areas, v).as_vec3())
        .collect()
}

/// Every face's vector area ([`vector_area`]) in single precision, one
/// entry per face: for passes that need every vertex's normal once, where
/// computing each face once instead of at each of its corners halves the
/// work ([`normal_from_areas`]). 12 bytes a face.
pub fn face_vector_areas_f32(mesh: &Mesh, positions: &[DVec3]) -> Vec<Vec3> {
    (0..mesh.num_faces())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| vector_area(mesh.face(f), positions).as_vec3())
        .collect()
}

/// Unit area-weighted normal of vertex `v` from its faces' vector `areas`
/// ([`face_vector_areas_f32`]), summed in double precision in the order of
/// [`vertex_normal`] (zero without area).
#[inline]
pub fn normal_from_areas(topo: &Topology, areas: &[Vec3], v: usize) -> DVec3 {
    let s: DVec3 = topo
        .vertex_faces(v)
        .iter()
        .map(|&f| areas[f as usize].as_dvec3())
        .sum();
    s.normalize_or_zero()
}

/// Unit area-weighted normal of vertex `v` (zero without area).
#[inline]
pub fn vertex_normal(mesh: &Mesh, topo: &Topology, positions: &[DVec3], v: usize) -> DVec3 {
    let s: DVec3 = topo
        .vertex_faces(v)
        .iter()
        .map(|&f| vector_area(mesh.face(f as usize), positions))
        .sum();
    s.normalize_or_zero()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pyramid_apex_normal_points_up() {
        let p = vec![
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(0.0, -1.0, 0.0),
        ];
        let m = Mesh::from_polygons(p, &[[0u32, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]).unwrap();
        let t = Topology::build(&m);
        let n = vertex_normals(&m, &t, m.positions());
        assert!((n[0] - DVec3::Z).length() < 1e-12);
        assert!((n[1].length() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn normals_from_face_areas_match_the_per_corner_sums() {
        // A bumped grid of quads with a pentagon and a triangle on top.
        let mut p: Vec<DVec3> = (0..36)
            .map(|i| {
                let (x, y) = ((i % 6) as f64, (i / 6) as f64);
                DVec3::new(x, y, 0.3 * (1.3 * x).sin() * (0.7 * y).cos())
            })
            .collect();
        p.push(DVec3::new(2.5, 6.5, 0.2));
        let mut faces: Vec<Vec<u32>> = Vec::new();
        for y in 0..5u32 {
            for x in 0..5u32 {
                let a = y * 6 + x;
                faces.push(vec![a, a + 1, a + 7, a + 6]);
            }
        }
        faces.push(vec![30, 31, 32, 36, 33].into_iter().rev().collect());
        faces.push(vec![33, 36, 34]);
        let m = Mesh::from_polygons(p, &faces).unwrap();
        let t = Topology::build(&m);
        let plain = vertex_normals_f32(&m, &t, m.positions());
        let by_faces = vertex_normals_f32_by_faces(&m, &t, m.positions());
        for (v, (a, b)) in plain.iter().zip(&by_faces).enumerate() {
            assert!((*a - *b).length() < 1e-6, "vertex {v}: {a} vs {b}");
            assert!((a.length() - 1.0).abs() < 1e-6);
        }
    }
}
