//! The smoothing steps of Wang & Yu (IMR 2009), one file per step, plus the
//! baseline smoothers.

pub mod adaptive;
pub mod curvature;
pub mod fairing;
pub mod fidelity;
pub mod initial;
pub mod label;
pub mod laplacian;
pub mod local_height;
pub mod neighbourhood;
pub mod noise;
pub mod pinches;
pub mod project;
pub mod staircase;
pub mod taubin;
pub mod volume;
