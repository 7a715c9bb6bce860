//! Fitting primitives shared by the smoothing steps and the quality fixes:
//! a vertex's local frame, vertex normals, and the weighted quadric (and
//! cubic) fits of paper section 2.1 with the curvature they give.

pub mod frame;
pub mod normals;
pub mod quadric_fit;
