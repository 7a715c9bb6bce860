//! Step 7: adaptive smoothing (paper section 2.3, algorithm notes
//! section 7): grown neighbourhoods ([`growth`]), the seeds whose growth
//! their neighbours share ([`seeds`]), and the passes that fit over them
//! ([`passes`]).
//!
//! Starting from the 2-ring, a vertex's neighbourhood grows ring by ring
//! while (a) the vertices of the next ring carry the vertex's own label
//! (up to a tolerated fraction, with a margin, see [`agrees`](crate::smoothing::label::agrees)), (b) the
//! standard deviation of the scale-free mean curvature `H l` over the grown
//! set does not rise (up to a tolerance) and stays below a bound, (c) a fit
//! reaching the next ring would not bias the projection by more than a bound
//! (`rho^4 kappa^3 / 48`, the gap between a paraboloid and a sphere), and
//! (d) `k < k_max`. The chosen neighbourhood is then thinned to at most
//! `max_points` well-spread vertices ([`push_thinned`](crate::smoothing::neighbourhood::push_thinned)) so a fit's cost does
//! not grow with `k`. Where growth is clear-cut (it reaches `k_max` with
//! every test passed by a margin) a seed's outer rings serve its
//! neighbours too ([`seeds::SHARED_FROM_RING`]), so the long walk is made once
//! for a few vertices.
//! Connectivity never changes, so neighbourhoods are chosen once and reused
//! by every adaptive pass.
//!
//! Not every pass fits anew ([`is_refit_pass`]): a fit's height is linear
//! in its points' heights, so between refits a pass moves each vertex by the
//! latest fit's linear weights ([`weighted_pass`](crate::smoothing::project::weighted_pass)),
//! one weighted sum instead of a cubic fit. The frame coordinates and point
//! weights the linear weights hold change little once the initial passes
//! have taken the staircase out, and a refit only fits the vertices near
//! which the surface has moved since ([`REFIT_TOLERANCE`]). Vertices whose
//! neighbourhood grew to [`FLAT_RING`] rings move with momentum and stop
//! after [`flat_passes`] of the passes.

pub mod growth;
pub mod passes;
pub mod seeds;

pub use growth::{AdaptiveNeighbourhoods, GrowthRule, adaptive_neighbourhoods, agreement_masks};
pub use passes::{
    EarlyStop, FLAT_MOMENTUM, FLAT_RING, PassPlan, REFIT_TOLERANCE, ShapeStop, flat_passes,
    is_refit_pass, smooth_passes,
};

use crate::control::Cancelled;
use crate::fit::quadric_fit::FitModel;
use crate::mesh::{Mesh, Topology};
use crate::smoothing::curvature::Curvatures;
use crate::smoothing::fidelity::Fidelity;
use crate::smoothing::label::Label;
use crate::smoothing::neighbourhood::release_walk_scratch;
use crate::smoothing::project::FitStats;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;

/// Grows every vertex's neighbourhood by `rule` from the labelled surface
/// at `positions`: `labels`, `curvature` (`(H, K)`) and unit `normals` have
/// one entry per vertex. Takes the curvature and normals to free them (and
/// the growth's scratch) before the passes allocate theirs: the passes are
/// where a run's memory peaks.
pub fn grow_neighbourhoods(
    topo: &Topology,
    positions: &[DVec3],
    labels: &[Label],
    curvature: Curvatures,
    normals: Vec<Vec3>,
    rule: GrowthRule,
) -> AdaptiveNeighbourhoods {
    // Single precision: growth compares spreads of about 0.005.
    let h_scaled: Vec<f32> = curvature
        .par_iter()
        .map(|&(h, _)| (h * rule.edge_length) as f32)
        .collect();
    let agreement = agreement_masks(&curvature, &rule);
    drop(curvature);
    let grown = adaptive_neighbourhoods(
        topo, positions, labels, &agreement, &h_scaled, &normals, rule,
    );
    drop((h_scaled, normals, agreement));
    release_walk_scratch();
    grown
}

/// How the adaptive passes fit.
#[derive(Debug, Clone, Copy)]
pub struct PassSettings<'a> {
    /// Which vertices may move.
    pub movable: &'a [bool],
    /// Passes to run.
    pub passes: u32,
    /// The surface model of the fits.
    pub model: FitModel,
    /// Neighbours facing away by a cosine below this are left out of a fit.
    pub min_cos: f64,
    /// The fidelity bound every pass keeps to; `None`: no bound.
    pub fidelity: Option<&'a Fidelity<'a>>,
    /// Vertices whose neighbourhood stayed within this many rings lie on
    /// the shape and make only `shape_passes` passes ([`ShapeStop`]).
    pub shape_ring: u8,
    /// Passes of the vertices on the shape.
    pub shape_passes: u32,
}

/// The adaptive passes over the `grown` neighbourhoods, moving `positions`
/// in place: refits on the schedule of [`is_refit_pass`], selective after
/// the first ([`REFIT_TOLERANCE`]); vertices grown to [`FLAT_RING`] rings
/// move with momentum and stop after [`flat_passes`]. Returns the fit
/// statistics and each vertex's final ring size.
pub fn adaptive_passes(
    mesh: &Mesh,
    topo: &Topology,
    positions: &mut [DVec3],
    grown: AdaptiveNeighbourhoods,
    settings: PassSettings,
    cancel: &AtomicBool,
    on_pass: impl FnMut(u32),
) -> Result<(FitStats, Vec<u8>), Cancelled> {
    let AdaptiveNeighbourhoods { hoods, ring } = grown;
    let flat: Vec<bool> = ring.par_iter().map(|&k| k >= FLAT_RING).collect();
    let on_shape: Vec<bool> = ring.par_iter().map(|&k| k <= settings.shape_ring).collect();
    let plan = PassPlan {
        hoods: &hoods,
        movable: settings.movable,
        model: settings.model,
        min_cos: settings.min_cos,
        passes: settings.passes,
        refit: &is_refit_pass,
        refit_tolerance: Some(REFIT_TOLERANCE),
        early: Some(EarlyStop {
            vertices: &flat,
            momentum: FLAT_MOMENTUM,
            passes: flat_passes(settings.passes),
        }),
        fidelity: settings.fidelity,
        shape_stop: Some(ShapeStop {
            vertices: &on_shape,
            passes: settings.shape_passes,
        }),
    };
    let stats = smooth_passes(mesh, topo, positions, &plan, cancel, on_pass)?;
    Ok((stats, ring))
}
