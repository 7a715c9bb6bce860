//! Constrained fairing of a voxel staircase (our addition to section 2.2):
//! the surface of least bending that stays close to the staircase and
//! inside every corner's dual voxel.
//!
//! A voxel mask says, for every corner of its boundary, only that the true
//! surface crosses the corner's dual voxel (the cube between the eight
//! voxel centres around it). Fits made to the staircase's corners are
//! biased where the staircase is regular: a terrace (a flat run of faces at
//! a sphere's pole, a gyrus's crown) puts many corners at one height, and
//! a least-squares surface follows them there, however the grid fell. The
//! fairing instead minimises the thin-plate energy of the umbrella operator
//! `L` (Kobbelt 1998; Desbrun et al. 1999 smooth with the same `L^2`),
//! with a weak pull toward the input corners,
//!
//!   E(x) = sum_v |L x_v|^2 + anchor * sum_v |x_v - x0_v|^2,
//!
//! over the positions inside each vertex's box: a terrace bends with the
//! curvature its rims give it, and the boxes keep what the mask says.
//! The energy is convex and the boxes are convex, so the minimiser is
//! unique; it is reached by accelerated projected gradient steps (FISTA,
//! Beck & Teboulle 2009), Jacobi-style, so the result does not depend on
//! the thread count.

use super::fidelity::Fidelity;
use crate::mesh::Topology;
use glam::DVec3;
use rayon::prelude::*;

/// Gradient step of the fairing: the energy's gradient `L^2 x + anchor x`
/// has a Lipschitz constant of at most `4 + anchor` (the uniform umbrella
/// operator's eigenvalues lie in `[-2, 0]`), and a step of at most its
/// inverse keeps the accelerated iteration monotone in the limit.
const STEP: f64 = 0.2;

/// What a fairing run does.
#[derive(Debug, Clone, Copy)]
pub struct FairingPlan<'a> {
    /// Which vertices move; the others hold the surface where they are.
    pub movable: &'a [bool],
    /// Accelerated gradient steps.
    pub iterations: u32,
    /// Weight of the pull toward the input positions, relative to the
    /// bending energy: with `anchor = s^-4` the fairing damps the
    /// staircase's wiggles shorter than about `2 pi s` edges and keeps
    /// longer ones.
    pub anchor: f64,
    /// The box each vertex stays in (the fidelity bound, possibly
    /// narrowed); applied to every iterate.
    pub bound: &'a Fidelity<'a>,
}

/// Fairs `positions` (one per vertex, moved in place) toward the minimiser
/// of the energy of the module docs, pulled toward `anchor_positions`,
/// within `plan.bound`. Deterministic and parallel per vertex.
pub fn fair(
    topo: &Topology,
    positions: &mut [DVec3],
    anchor_positions: &[DVec3],
    plan: &FairingPlan,
) {
    if plan.iterations == 0 {
        return;
    }
    let n = positions.len();
    let mut x = positions.to_vec();
    let mut y = positions.to_vec();
    let mut umbrella = vec![DVec3::ZERO; n];
    let mut t = 1.0f64;
    for _ in 0..plan.iterations {
        laplacian(topo, &y, &mut umbrella);
        // The gradient step at the extrapolated point `y`, into `positions`.
        positions
            .par_iter_mut()
            .enumerate()
            .with_min_len(4096)
            .for_each(|(v, p)| {
                if !plan.movable[v] {
                    return;
                }
                let bend = umbrella_at(topo, &umbrella, v);
                let pull = plan.anchor * (y[v] - anchor_positions[v]);
                *p = y[v] - STEP * (bend + pull);
            });
        plan.bound.apply_quietly(positions);
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        let momentum = (t - 1.0) / t_next;
        y.par_iter_mut()
            .zip(&x[..])
            .zip(&positions[..])
            .with_min_len(4096)
            .for_each(|((y, &old), &new)| *y = new + momentum * (new - old));
        x.copy_from_slice(positions);
        t = t_next;
    }
}

/// `out[v] = L x` at every vertex: the mean of its neighbours less itself
/// (zero for a vertex without neighbours).
fn laplacian(topo: &Topology, x: &[DVec3], out: &mut [DVec3]) {
    out.par_iter_mut()
        .enumerate()
        .with_min_len(4096)
        .for_each(|(v, o)| *o = umbrella_at(topo, x, v));
}

/// The umbrella vector of `x` at `v`.
#[inline]
fn umbrella_at(topo: &Topology, x: &[DVec3], v: usize) -> DVec3 {
    let nb = topo.neighbors(v);
    if nb.is_empty() {
        return DVec3::ZERO;
    }
    let sum = nb.iter().fold(DVec3::ZERO, |s, &j| s + x[j as usize]);
    sum / nb.len() as f64 - x[v]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;
    use crate::smoothing::fidelity::FidelityBound;

    #[test]
    fn fairing_a_voxel_sphere_brings_it_close_within_the_dual_voxels() {
        let (sphere, mesh) = shapes::voxel_sphere(8.0);
        let topo = Topology::build(&mesh);
        let input = mesh.positions();
        let bound = FidelityBound::new(&mesh, &topo, 0.5);
        let fidelity = Fidelity::new(Some(&bound), input);
        let movable = vec![true; mesh.num_vertices()];
        let plan = FairingPlan {
            movable: &movable,
            iterations: 80,
            anchor: 0.03,
            bound: &fidelity,
        };
        let mut p = input.to_vec();
        fair(&topo, &mut p, input, &plan);
        let (before, after) = (
            shapes::rms_distance(&sphere, input),
            shapes::rms_distance(&sphere, &p),
        );
        assert!(after < 0.3 * before, "{before} -> {after}");
        assert!(
            p.iter()
                .zip(input)
                .all(|(a, b)| (*a - *b).abs().max_element() <= 0.5 + 1e-9)
        );
        assert_eq!(fidelity.held_back(), 0, "the fairing records nothing");

        // Held vertices stay; no iterations, no change.
        let held = vec![false; mesh.num_vertices()];
        let mut q = input.to_vec();
        fair(
            &topo,
            &mut q,
            input,
            &FairingPlan {
                movable: &held,
                ..plan
            },
        );
        assert_eq!(q, input);
        fair(
            &topo,
            &mut q,
            input,
            &FairingPlan {
                iterations: 0,
                ..plan
            },
        );
        assert_eq!(q, input);
    }
}
