//! Staircase relaxation: a couple of damped umbrella steps between the
//! first and the second initial pass (our addition to section 2.2).
//!
//! On a voxel staircase the area-weighted normal of a corner vertex points
//! along a lattice diagonal, not along the surface the staircase samples,
//! and the vertices crowd at the steps' edges. The first quadric pass moves
//! each vertex along that normal only; a fit in a frame tilted that far
//! leaves the steps' corners where they were. Moving each vertex part of
//! the way to the mean of its neighbours spreads them over the surface
//! and turns the normals toward it, so the later fits see the surface, not
//! the steps. Every step keeps to the fidelity bound.
//!
//! Umbrella steps also shrink the surface they smooth: a full step moves a
//! vertex of a smooth curved patch inward by the normal part of its
//! umbrella vector, about its curvature times its squared edge length
//! (Taubin 1995). The volume restoration at the end puts back the mean of
//! that loss, but a gyrus's crown shrinks and a sulcus's fundus swells
//! where a plateau barely moves. [`compensate_shrinkage`] moves each vertex
//! back along its normal by a fraction of that local shrinkage.

use super::fidelity::Fidelity;
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::mesh::{Mesh, Topology, VertexKind};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// `steps` Jacobi steps `p += lambda (mean of neighbours - p)` on the
/// `movable` vertices of `positions` (one per vertex, moved in place),
/// each followed by `fidelity`. Boundary vertices stay whatever `movable`
/// says: the step is tangential too, and a boundary vertex may at most move
/// along its normal. A movable non-manifold vertex moves to the mean of
/// all its fans' neighbours. Like the fits, the mean leaves out neighbours
/// whose normal turns from the vertex's by a cosine below `min_cos` (the
/// far side of a thin sheet, the other face of a cube's edge).
/// Deterministic and parallel per vertex.
#[allow(clippy::too_many_arguments)]
pub fn relax_staircase(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    movable: &[bool],
    steps: u32,
    lambda: f64,
    min_cos: f64,
    fidelity: &Fidelity,
) {
    if steps == 0 {
        return;
    }
    let mut old = positions.to_vec();
    for _ in 0..steps {
        old.copy_from_slice(positions);
        let normals = vertex_normals_f32_by_faces(mesh, topo, &old);
        positions
            .par_iter_mut()
            .enumerate()
            .with_min_len(4096)
            .for_each(|(v, p)| {
                if !movable[v] || topo.kind(v) == VertexKind::Boundary {
                    return;
                }
                if let Some(mean) = facing_mean(topo, &normals, &old, v, min_cos) {
                    *p += lambda * (mean - *p);
                }
            });
        fidelity.apply(positions);
    }
}

/// The mean position of `v`'s neighbours whose normals turn from its own
/// by a cosine of at least `min_cos` (the umbrella operator's target); none
/// when no neighbour qualifies.
fn facing_mean(
    topo: &Topology,
    normals: &[Vec3],
    positions: &[DVec3],
    v: usize,
    min_cos: f64,
) -> Option<DVec3> {
    let n = normals[v].as_dvec3();
    let (sum, count) = topo
        .neighbors(v)
        .iter()
        .filter(|&&j| n.dot(normals[j as usize].as_dvec3()) >= min_cos)
        .fold((DVec3::ZERO, 0u32), |(s, c), &j| {
            (s + positions[j as usize], c + 1)
        });
    (count > 0).then(|| sum / f64::from(count))
}

/// Jacobi sweeps that average the normal parts of the umbrella vectors
/// before they are undone: the average over a few rings is the part of
/// the vector that follows the surface's curvature; what remains of the
/// staircase and the vertices' uneven spacing varies from one vertex to
/// the next and averages out.
pub const SHRINKAGE_RINGS: u32 = 6;

/// Moves each `movable` vertex of `positions` (one per vertex, moved in
/// place) outward along its normal by `fraction` of the normal part of its
/// umbrella vector (the mean of its neighbours less its position, over the
/// neighbours whose normals turn from its own by a cosine of at least
/// `min_cos`), averaged over [`SHRINKAGE_RINGS`] rings; then `fidelity`.
/// Boundary vertices stay: the vector of an open rim points into the
/// surface, not across it. Deterministic and parallel per vertex.
pub fn compensate_shrinkage(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    movable: &[bool],
    fraction: f64,
    min_cos: f64,
    fidelity: &Fidelity,
) {
    if fraction == 0.0 {
        return;
    }
    let normals = vertex_normals_f32_by_faces(mesh, topo, positions);
    let normal = |v: usize| normals[v].as_dvec3();
    let mut shrink: Vec<f64> = (0..positions.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|v| {
            facing_mean(topo, &normals, positions, v, min_cos)
                .map_or(0.0, |mean| normal(v).dot(mean - positions[v]))
        })
        .collect();
    let mut next = vec![0.0; shrink.len()];
    for _ in 0..SHRINKAGE_RINGS {
        next.par_iter_mut()
            .with_min_len(4096)
            .enumerate()
            .for_each(|(v, out)| {
                let nb = topo.neighbors(v);
                let sum: f64 = nb.iter().map(|&j| shrink[j as usize]).sum();
                *out = (shrink[v] + sum) / (nb.len() + 1) as f64;
            });
        std::mem::swap(&mut shrink, &mut next);
    }
    positions
        .par_iter_mut()
        .with_min_len(4096)
        .enumerate()
        .for_each(|(v, p)| {
            if movable[v] && topo.kind(v) != VertexKind::Boundary {
                *p -= fraction * shrink[v] * normal(v);
            }
        });
    fidelity.apply(positions);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn relaxing_a_staircase_brings_it_closer_to_the_surface_within_the_bound() {
        let (sphere, mesh) = shapes::voxel_sphere(8.0);
        let topo = Topology::build(&mesh);
        let movable = vec![true; mesh.num_vertices()];
        let input = mesh.positions();
        let bound = crate::smoothing::fidelity::FidelityBound::new(&mesh, &topo, 0.5);
        let fidelity = Fidelity::new(Some(&bound), input);
        let mut p = input.to_vec();
        relax_staircase(&mesh, &topo, &mut p, &movable, 2, 0.5, 0.5, &fidelity);
        let (before, after) = (
            shapes::rms_distance(&sphere, input),
            shapes::rms_distance(&sphere, &p),
        );
        assert!(after < 0.8 * before, "{before} -> {after}");
        assert!(
            p.iter()
                .zip(input)
                .all(|(a, b)| (*a - *b).abs().max_element() <= 0.5 + 1e-12)
        );
        // No steps, no change.
        let mut q = input.to_vec();
        relax_staircase(&mesh, &topo, &mut q, &movable, 0, 0.5, 0.5, &fidelity);
        assert_eq!(q, input);
    }

    #[test]
    fn compensating_the_shrinkage_moves_a_smoothed_sphere_back_out() {
        let (sphere, mesh) = shapes::mc_sphere(10.0);
        let topo = Topology::build(&mesh);
        let movable = vec![true; mesh.num_vertices()];
        let fidelity = Fidelity::new(None, mesh.positions());
        let mut p = mesh.positions().to_vec();
        relax_staircase(&mesh, &topo, &mut p, &movable, 2, 1.0, -1.0, &fidelity);
        let mean_radius =
            |p: &[DVec3]| p.iter().map(|q| q.distance(sphere.center)).sum::<f64>() / p.len() as f64;
        let relaxed = p.clone();
        let shrunk = sphere.radius - mean_radius(&relaxed);
        assert!(shrunk > 0.05, "two full umbrella steps shrink it: {shrunk}");

        compensate_shrinkage(&mesh, &topo, &mut p, &movable, 0.0, -1.0, &fidelity);
        assert_eq!(p, relaxed, "a zero fraction moves nothing");

        compensate_shrinkage(&mesh, &topo, &mut p, &movable, 1.0, -1.0, &fidelity);
        let left = sphere.radius - mean_radius(&p);
        // One full step's shrinkage of two comes back, less the part a
        // polygonal sphere's umbrella vector does not show.
        assert!(left > 0.0 && left < 0.75 * shrunk, "{shrunk} -> {left}");
        let outward = p
            .iter()
            .zip(&relaxed)
            .all(|(q, r)| (*q - *r).dot(*r - sphere.center) >= 0.0);
        assert!(outward, "every vertex of a sphere moves out");
        assert!(shapes::rms_distance(&sphere, &p) < shapes::rms_distance(&sphere, &relaxed));

        // Held vertices stay.
        let mut q = relaxed.clone();
        let held = vec![false; mesh.num_vertices()];
        compensate_shrinkage(&mesh, &topo, &mut q, &held, 1.0, -1.0, &fidelity);
        assert_eq!(q, relaxed);
    }
}
