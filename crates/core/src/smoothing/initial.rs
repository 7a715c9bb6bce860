//! Initial smoothing (paper section 2.2): a few Jacobi passes of quadric
//! fits over the fixed 2-ring of every vertex.

use super::neighbourhood::Neighbourhoods;
use super::project::{FitStats, fit_pass, step_limits, weighted_pass};
use super::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use crate::pipeline::{Cancelled, check};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;

/// Runs `passes` passes over `hoods` starting from `positions` (updated in
/// place). Pass `p` fits anew when `refit(p)` holds, and always at the
/// first and the last pass; the others are [`weighted_pass`]es with the
/// weights of the latest fit. The last pass refits so the result lies on
/// fits made for it: on real meshes whose fits are poor (thin tubes,
/// non-manifold parts), passes on reused weights drift (the neuron of the
/// real-mesh sweep gains 15% in volume instead of 10% without it).
/// Returns the summed fit statistics. `model` and `min_cos` are
/// [`fit_pass`]'s.
#[allow(clippy::too_many_arguments)]
pub fn smooth_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    hoods: &Neighbourhoods,
    movable: &[bool],
    model: FitModel,
    min_cos: f64,
    passes: u32,
    refit: impl Fn(u32) -> bool,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<FitStats, Cancelled> {
    let mut moves = vec![Vec3::ZERO; positions.len()];
    let last = passes.saturating_sub(1);
    let refits = |p: u32| p == 0 || p == last || refit(p);
    // Weights are kept only when some pass reuses them.
    let mut weights = (0..passes)
        .any(|p| !refits(p))
        .then(|| hoods.zero_weights());
    let mut stats = FitStats::default();
    let limits = match &weights {
        Some(_) => step_limits(mesh, topo),
        None => Vec::new(),
    };
    for pass in 0..passes {
        check(cancel)?;
        let s = match &weights {
            Some(w) if !refits(pass) => weighted_pass(
                mesh, topo, positions, hoods, w, &limits, movable, &mut moves,
            ),
            _ => {
                let reused = pass + 1 < passes && !refits(pass + 1);
                fit_pass(
                    mesh,
                    topo,
                    positions,
                    hoods,
                    movable,
                    model,
                    min_cos,
                    &mut moves,
                    weights.as_mut().filter(|_| reused),
                )
            }
        };
        stats.accumulate(s);
        positions
            .par_iter_mut()
            .zip(&moves)
            .with_min_len(4096)
            .for_each(|(p, m)| *p += m.as_dvec3());
        on_pass(pass + 1);
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;
    use crate::smoothing::adaptive::is_refit_pass;
    use crate::smoothing::neighbourhood::push_thinned;

    #[test]
    fn reused_fits_track_fits_made_every_pass() {
        let (sphere, mesh) = shapes::voxel_sphere(8.0);
        let topo = Topology::build(&mesh);
        let hoods = Neighbourhoods::build(&topo, |v, w, out| {
            w.start(&topo, v);
            for _ in 0..5 {
                w.grow(&topo);
            }
            push_thinned(w, 56, 14, out);
        });
        let movable = vec![true; mesh.num_vertices()];
        // As in the pipeline: the staircase goes first, in passes that fit.
        let mut start = mesh.positions().to_vec();
        let two_ring = Neighbourhoods::two_ring(&topo, 56);
        let never = AtomicBool::new(false);
        smooth_passes(
            &mesh,
            &topo,
            &mut start,
            &two_ring,
            &movable,
            FitModel::Quadric,
            0.0,
            3,
            |_| true,
            &never,
            |_| {},
        )
        .expect("not cancelled");
        let run = |refit: &dyn Fn(u32) -> bool| {
            let mut p = start.clone();
            let stats = smooth_passes(
                &mesh,
                &topo,
                &mut p,
                &hoods,
                &movable,
                FitModel::Cubic,
                0.0,
                14,
                refit,
                &never,
                |_| {},
            )
            .expect("not cancelled");
            (p, stats)
        };
        let (every, every_stats) = run(&|_| true);
        let (reused, reused_stats) = run(&is_refit_pass);
        // Passes 0, 4, 12 and 13 fit; the other ten reuse weights.
        let fits = |s: &FitStats| s.cubic + s.quadric + s.plane_fallback + s.fixed_fallback;
        assert_eq!(fits(&every_stats), 14 * mesh.num_vertices() as u64);
        assert_eq!(fits(&reused_stats), 4 * mesh.num_vertices() as u64);
        assert_ne!(every, reused, "the reused weights were not used");
        let max_diff = every
            .iter()
            .zip(&reused)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0, f64::max);
        assert!(max_diff < 0.01, "moved {max_diff} apart");
        let (rms_every, rms_reused) = (
            shapes::rms_distance(&sphere, &every),
            shapes::rms_distance(&sphere, &reused),
        );
        assert!(rms_reused < 0.25 * shapes::rms_distance(&sphere, mesh.positions()));
        assert!(
            (rms_every - rms_reused).abs() < 0.002,
            "{rms_every} vs {rms_reused}"
        );
    }
}
