//! `run(mesh, &params, &progress, &cancel)`: the whole smoothing pipeline,
//! one entry point shared by the CLI and the service.

use crate::mesh::Mesh;
use crate::params::{ParamError, Params};
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

/// Smooths `mesh` with `params`. Never changes connectivity.
pub fn run(
    mesh: &Mesh,
    params: &Params,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<SmoothOutput, SmoothError> {
    params.validate()?;
    let _ = (mesh, progress, cancel);
    todo!("pipeline under construction")
}
