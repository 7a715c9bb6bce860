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

use super::fidelity::Fidelity;
use crate::fit::normals::vertex_normals_f32_by_faces;
use crate::mesh::{Mesh, Topology, VertexKind};
use glam::DVec3;
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
                let nb = topo.neighbors(v);
                if !movable[v] || nb.is_empty() || topo.kind(v) == VertexKind::Boundary {
                    return;
                }
                let n = normals[v].as_dvec3();
                let (sum, count) = nb
                    .iter()
                    .filter(|&&j| n.dot(normals[j as usize].as_dvec3()) >= min_cos)
                    .fold((DVec3::ZERO, 0u32), |(s, c), &j| {
                        (s + old[j as usize], c + 1)
                    });
                if count > 0 {
                    *p += lambda * (sum / f64::from(count) - *p);
                }
            });
        fidelity.apply(positions);
    }
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
}
