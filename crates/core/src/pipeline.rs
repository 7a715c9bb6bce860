//! `run(mesh, &params, &progress, &cancel)`: the whole smoothing pipeline,
//! one entry point shared by the CLI and the service.

use crate::mesh::{Mesh, Topology, VertexKind, mean_edge_length};
use crate::params::{BoundaryRule, ParamError, Params};
use crate::smoothing::adaptive::{
    AdaptiveNeighbourhoods, BEAM_WIDTH, GrowthRule, adaptive_neighbourhoods,
};
use crate::smoothing::curvature::vertex_curvatures;
use crate::smoothing::initial::smooth_passes;
use crate::smoothing::label::{Label, label};
use crate::smoothing::neighbourhood::{Neighbourhoods, push_thinned};
use crate::smoothing::project::{Curvatures, FitStats};
use crate::smoothing::volume::restore_volume;
use std::time::Instant;
use crate::report::QualityReport;
use glam::DVec3;
use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use thiserror::Error;

/// Pipeline stages, in order, as reported to [`Progress`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Topology and measures of the input.
    Analyse,
    /// Initial smoothing (fixed 2-ring fits), or the baseline method.
    Initial,
    /// Curvature estimation and labelling.
    Label,
    /// Adaptive smoothing (grown neighbourhoods).
    Adaptive,
    /// Quality fixes (twisted quads, short edges, sharp angles).
    Quality,
    /// Measures of the output for the report.
    Report,
}

impl Stage {
    /// Stable snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Analyse => "analyse",
            Stage::Initial => "initial",
            Stage::Label => "label",
            Stage::Adaptive => "adaptive",
            Stage::Quality => "quality",
            Stage::Report => "report",
        }
    }
}

/// Receives progress from the pipeline; called from worker threads.
pub trait Progress: Sync {
    /// `fraction` in `[0, 1]` of the current `stage`.
    fn update(&self, stage: Stage, fraction: f64);
}

/// A [`Progress`] that ignores every update.
pub struct NoProgress;

impl Progress for NoProgress {
    fn update(&self, _: Stage, _: f64) {}
}

/// The run was cancelled through its flag.
#[derive(Debug, Error, Clone, Copy, PartialEq, Eq)]
#[error("the smoothing run was cancelled")]
pub struct Cancelled;

/// Why a run did not produce a result.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SmoothError {
    /// A parameter is out of range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// The cancellation flag was raised.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

impl SmoothError {
    /// Stable snake_case code.
    pub fn code(&self) -> &'static str {
        match self {
            SmoothError::Params(e) => e.code(),
            SmoothError::Cancelled(_) => "cancelled",
        }
    }
}

/// Per-vertex results of a run, one entry per vertex each.
#[derive(Debug, Clone, Default)]
pub struct PerVertex {
    /// Label of Table 2 (0 flat, 1 minimal, 2 convex, 3 concave); empty for
    /// baseline methods.
    pub label: Vec<u8>,
    /// Mean curvature `H` from the last fit (outward normals: convex < 0).
    pub mean_curvature: Vec<f64>,
    /// Gaussian curvature `K` from the last fit.
    pub gaussian_curvature: Vec<f64>,
    /// Distance each vertex moved.
    pub displacement: Vec<f64>,
}

/// What a run returns: new positions (one per input vertex), the report and
/// per-vertex results.
#[derive(Debug, Clone)]
pub struct SmoothOutput {
    /// Smoothed positions, one per vertex, in input order.
    pub positions: Vec<DVec3>,
    /// The quality report.
    pub report: QualityReport,
    /// Per-vertex results.
    pub per_vertex: PerVertex,
}

/// Checks `cancel` and returns [`Cancelled`] when it is raised.
#[inline]
pub fn check(cancel: &AtomicBool) -> Result<(), Cancelled> {
    if cancel.load(Ordering::Relaxed) {
        Err(Cancelled)
    } else {
        Ok(())
    }
}

/// Which vertices may move: not isolated, not non-manifold, and not on the
/// boundary unless the boundary rule lets them move along their normal.
pub fn movable_mask(topo: &Topology, boundary: BoundaryRule) -> Vec<bool> {
    topo.kinds()
        .iter()
        .map(|k| match k {
            VertexKind::Interior => true,
            VertexKind::Boundary => boundary == BoundaryRule::NormalOnly,
            VertexKind::NonManifold | VertexKind::Isolated => false,
        })
        .collect()
}

/// Intermediate results of the Wang-Yu stages.
#[derive(Debug, Clone)]
pub struct WangYuRun {
    /// Positions after initial smoothing.
    pub initial: Vec<DVec3>,
    /// Positions after adaptive smoothing (and volume restoration).
    pub adaptive: Vec<DVec3>,
    /// `(H, K)` per vertex from the last fits.
    pub curvature: Curvatures,
    /// Label per vertex (from the curvature after initial smoothing).
    pub labels: Vec<Label>,
    /// Final ring size per vertex.
    pub ring: Vec<u8>,
    /// Fit statistics of the initial passes.
    pub initial_fits: FitStats,
    /// Fit statistics of the adaptive passes.
    pub adaptive_fits: FitStats,
    /// Offset along the normals applied to restore the volume (0 if none).
    pub volume_offset: f64,
    /// Milliseconds per stage.
    pub timings_ms: Vec<(Stage, f64)>,
}

/// Initial smoothing, labelling and adaptive smoothing with volume
/// restoration (paper sections 2.2-2.3), without the quality fixes.
pub fn wang_yu(
    mesh: &Mesh,
    topo: &Topology,
    movable: &[bool],
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<WangYuRun, Cancelled> {
    let mut timings_ms = Vec::new();
    let max_points = params.max_fit_points as usize;
    let t = Instant::now();
    let two_ring = Neighbourhoods::two_ring(topo, max_points);
    let mut positions = mesh.positions().to_vec();
    let passes = params.initial_passes;
    let (initial_fits, hk) = smooth_passes(
        mesh,
        topo,
        &mut positions,
        &two_ring,
        movable,
        passes,
        cancel,
        |p| progress.update(Stage::Initial, p as f64 / passes.max(1) as f64),
    )?;
    let initial = positions.clone();
    timings_ms.push((Stage::Initial, ms(t)));

    let t = Instant::now();
    check(cancel)?;
    let _ = hk;
    let curvature_hoods = Neighbourhoods::build(topo, |v, w, out| {
        w.start(topo, v);
        for r in 0..params.curvature_ring {
            let beam = if r < 2 { usize::MAX } else { BEAM_WIDTH };
            if w.grow_beam(topo, beam).is_empty() {
                w.discard_last();
                break;
            }
        }
        push_thinned(w, max_points, out);
    });
    let hk = vertex_curvatures(mesh, topo, &positions, &curvature_hoods).0;
    drop(curvature_hoods);
    drop(two_ring);
    let l = mean_edge_length(mesh, &positions);
    let labels: Vec<Label> = hk
        .iter()
        .map(|&(h, k)| label(h, k, l, params.tolerance_h, params.tolerance_k))
        .collect();
    let h_scaled: Vec<f64> = hk.iter().map(|&(h, _)| h * l).collect();
    // Largest principal curvature magnitude, scaled by l.
    let kappa: Vec<f64> = hk
        .iter()
        .map(|&(h, k)| (h.abs() + (h * h - k).max(0.0).sqrt()) * l)
        .collect();
    let rule = GrowthRule {
        k_max: params.k_max,
        max_points,
        std_bound: params.curvature_std_bound,
        std_tolerance: params.std_tolerance,
        bias_bound: params.bias_bound,
        edge_length: l,
        tolerance_h: params.tolerance_h,
        tolerance_k: params.tolerance_k,
        label_margin: params.label_margin,
        label_disagreement: params.label_disagreement,
    };
    let AdaptiveNeighbourhoods { hoods, ring } =
        adaptive_neighbourhoods(topo, &positions, &labels, &hk, &h_scaled, &kappa, rule);
    timings_ms.push((Stage::Label, ms(t)));
    progress.update(Stage::Label, 1.0);

    let t = Instant::now();
    let passes = params.adaptive_passes;
    let (adaptive_fits, hk_last) = smooth_passes(
        mesh,
        topo,
        &mut positions,
        &hoods,
        movable,
        passes,
        cancel,
        |p| progress.update(Stage::Adaptive, p as f64 / passes.max(1) as f64),
    )?;
    let curvature = hk_last.unwrap_or(hk);
    let mut volume_offset = 0.0;
    if params.preserve_volume && topo.num_boundary_edges() == 0 {
        let target = mesh.signed_volume();
        volume_offset = restore_volume(mesh, topo, &mut positions, movable, target);
    }
    timings_ms.push((Stage::Adaptive, ms(t)));
    Ok(WangYuRun {
        initial,
        adaptive: positions,
        curvature,
        labels,
        ring,
        initial_fits,
        adaptive_fits,
        volume_offset,
        timings_ms,
    })
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Smooths `mesh` with `params`. Never changes connectivity.
pub fn run(
    mesh: &Mesh,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<SmoothOutput, SmoothError> {
    params.validate()?;
    let topo = Topology::build(mesh);
    let movable = movable_mask(&topo, params.boundary);
    let r = wang_yu(mesh, &topo, &movable, params, progress, cancel)?;
    let displacement = r
        .adaptive
        .iter()
        .zip(mesh.positions())
        .map(|(a, b)| a.distance(*b))
        .collect();
    Ok(SmoothOutput {
        per_vertex: PerVertex {
            label: r.labels.iter().map(|&l| l as u8).collect(),
            mean_curvature: r.curvature.iter().map(|c| c.0).collect(),
            gaussian_curvature: r.curvature.iter().map(|c| c.1).collect(),
            displacement,
        },
        positions: r.adaptive,
        report: QualityReport::default(),
    })
}
