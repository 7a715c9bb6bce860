//! Progress and cancellation: what a long run reports as it goes and how
//! it is stopped. A leaf that every step may use: it knows nothing of
//! meshes.

use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use thiserror::Error;

/// Pipeline stages, in order, as reported to [`Progress`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
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
    /// Quality fixes (twisted quads, short edges, sharp angles, folds).
    Quality,
    /// Measures of the output for the report.
    Report,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 6] = [
        Stage::Analyse,
        Stage::Initial,
        Stage::Label,
        Stage::Adaptive,
        Stage::Quality,
        Stage::Report,
    ];

    /// The stage whose [`Stage::name`] is `name`.
    pub fn named(name: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|s| s.name() == name)
    }

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

/// Checks `cancel` and returns [`Cancelled`] when it is raised.
#[inline]
pub fn check(cancel: &AtomicBool) -> Result<(), Cancelled> {
    if cancel.load(Ordering::Relaxed) {
        Err(Cancelled)
    } else {
        Ok(())
    }
}
