//! The HTTP service (`meshsmooth serve`). (Being written.)

use std::process::ExitCode;

/// Arguments of `meshsmooth serve`.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {}

/// Runs the service until SIGTERM/SIGINT.
pub fn serve(_args: ServeArgs) -> ExitCode {
    ExitCode::FAILURE
}
