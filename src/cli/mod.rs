//! The command-line subcommands `smooth` and `report`. (Being written.)

use std::process::ExitCode;

/// Arguments of `meshsmooth smooth`.
#[derive(Debug, clap::Args)]
pub struct SmoothArgs {}

/// Arguments of `meshsmooth report`.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {}

/// Runs `meshsmooth smooth`.
pub fn smooth(_args: SmoothArgs) -> ExitCode {
    ExitCode::FAILURE
}

/// Runs `meshsmooth report`.
pub fn report(_args: ReportArgs) -> ExitCode {
    ExitCode::FAILURE
}
