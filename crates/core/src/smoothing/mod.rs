//! The smoothing steps of Wang & Yu, one file per step.
