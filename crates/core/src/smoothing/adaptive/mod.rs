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
    EarlyStop, FLAT_MOMENTUM, FLAT_RING, REFIT_TOLERANCE, flat_passes, is_refit_pass, smooth_passes,
};
