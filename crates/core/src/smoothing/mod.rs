//! The smoothing steps of Wang & Yu (IMR 2009), one file per step, plus the
//! baseline smoothers.

pub mod adaptive;
pub mod curvature;
pub mod frame;
pub mod initial;
pub mod label;
pub mod laplacian;
pub mod neighbourhood;
pub mod normals;
pub mod project;
pub mod quadric_fit;
pub mod taubin;
pub mod volume;
