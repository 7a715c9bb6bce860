//! The quality report (algorithm notes, section 9). (Being written.)
use serde::Serialize;
/// The quality report of a run.
#[derive(Debug, Clone, Default, Serialize)]
pub struct QualityReport {}
