//! Baseline: Taubin λ/μ smoothing (Taubin, "A signal processing approach to
//! fair surface design", SIGGRAPH 1995): each iteration is an umbrella step
//! with a positive `lambda` followed by one with a negative `mu`
//! (`|mu| > lambda`), a low-pass filter that shrinks far less than plain
//! Laplacian smoothing. Fixed vertices, Jacobi updates and determinism as in
//! [`super::laplacian`].

use super::laplacian::umbrella_step;
use crate::control::{Cancelled, check};
use crate::mesh::Topology;
use glam::DVec3;
use std::sync::atomic::AtomicBool;

/// `iterations` λ/μ step pairs from `positions` (one per vertex; `movable`
/// likewise). Returns the smoothed positions; checks `cancel` before every
/// pair.
pub fn taubin_smooth(
    topo: &Topology,
    movable: &[bool],
    positions: &[DVec3],
    iterations: u32,
    lambda: f64,
    mu: f64,
    cancel: &AtomicBool,
) -> Result<Vec<DVec3>, Cancelled> {
    let mut cur = positions.to_vec();
    let mut next = cur.clone();
    for _ in 0..iterations {
        check(cancel)?;
        umbrella_step(topo, movable, lambda, &cur, &mut next);
        umbrella_step(topo, movable, mu, &next, &mut cur);
    }
    Ok(cur)
}

/// Step of the voxel lattices' closing low-pass
/// ([`crate::Params::lattice_lowpass_steps`]): half an umbrella step, so a
/// pair damps the grid's two-voxel ripple (the umbrella operator's highest
/// frequencies) at once.
pub const LOWPASS_LAMBDA: f64 = 0.5;

/// The low-pass's negative step: Taubin's pass band `1/lambda + 1/mu` is
/// then about 0.11 of the umbrella operator's range, so waves longer than
/// about ten edges pass unchanged and the surface does not shrink.
pub const LOWPASS_MU: f64 = -0.53;

/// `iterations` λ/μ step pairs on `positions` in place, each pair followed
/// by `after_pair` (the fidelity bound's clamp, in the pipeline).
pub fn taubin_in_place(
    topo: &Topology,
    movable: &[bool],
    positions: &mut [DVec3],
    iterations: u32,
    (lambda, mu): (f64, f64),
    mut after_pair: impl FnMut(&mut [DVec3]),
) {
    if iterations == 0 {
        return;
    }
    let mut next = positions.to_vec();
    for _ in 0..iterations {
        umbrella_step(topo, movable, lambda, positions, &mut next);
        umbrella_step(topo, movable, mu, &next, positions);
        after_pair(positions);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::signed_volume;
    use crate::params::{BaselineParams, BoundaryRule};
    use crate::pipeline::movable_mask;
    use crate::shapes::{rms_distance, voxel_sphere};
    use crate::smoothing::laplacian::laplacian_smooth;

    #[test]
    fn taubin_smooths_and_shrinks_much_less_than_laplacian() {
        let (sphere, mesh) = voxel_sphere(12.0);
        let topo = Topology::build(&mesh);
        let movable = movable_mask(&topo, BoundaryRule::Fixed);
        let no = AtomicBool::new(false);
        let p = BaselineParams::default();
        let v0 = mesh.signed_volume();
        let before = rms_distance(&sphere, mesh.positions());
        let taubin = taubin_smooth(
            &topo,
            &movable,
            mesh.positions(),
            p.iterations,
            p.lambda,
            p.mu,
            &no,
        )
        .unwrap();
        let laplace = laplacian_smooth(
            &topo,
            &movable,
            mesh.positions(),
            p.iterations,
            p.lambda,
            &no,
        )
        .unwrap();
        assert!(rms_distance(&sphere, &taubin) < 0.5 * before);
        let loss_taubin = 1.0 - signed_volume(&mesh, &taubin) / v0;
        let loss_laplace = 1.0 - signed_volume(&mesh, &laplace) / v0;
        assert!(
            loss_taubin.abs() < 0.2 * loss_laplace,
            "volume loss: taubin {loss_taubin}, laplacian {loss_laplace}"
        );
        let yes = AtomicBool::new(true);
        assert_eq!(
            taubin_smooth(&topo, &movable, mesh.positions(), 1, 0.5, -0.53, &yes),
            Err(Cancelled)
        );
    }
}
