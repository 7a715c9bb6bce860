//! Initial smoothing (paper section 2.2): a few Jacobi passes of quadric
//! fits over the fixed 2-ring of every vertex.

use super::neighbourhood::Neighbourhoods;
use super::project::{Curvatures, FitStats, fit_pass};
use super::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use crate::pipeline::{Cancelled, check};
use glam::DVec3;
use std::sync::atomic::AtomicBool;

/// Runs `passes` passes over `hoods` starting from `positions` (updated in
/// place). Returns the summed fit statistics and the curvature of the last
/// pass's fits (before its projection), or `None` when `passes == 0`.
/// `model` and `min_cos` are [`fit_pass`]'s.
#[allow(clippy::too_many_arguments)]
pub fn smooth_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut Vec<DVec3>,
    hoods: &Neighbourhoods,
    movable: &[bool],
    model: FitModel,
    min_cos: f64,
    passes: u32,
    cancel: &AtomicBool,
    mut on_pass: impl FnMut(u32),
) -> Result<(FitStats, Option<Curvatures>), Cancelled> {
    let n = positions.len();
    let mut next = vec![DVec3::ZERO; n];
    let mut hk = vec![(0.0, 0.0); n];
    let mut stats = FitStats::default();
    for pass in 0..passes {
        check(cancel)?;
        let s = fit_pass(
            mesh, topo, positions, hoods, movable, model, min_cos, &mut next, &mut hk,
        );
        stats.accumulate(s);
        std::mem::swap(positions, &mut next);
        on_pass(pass + 1);
    }
    Ok((stats, (passes > 0).then_some(hk)))
}
