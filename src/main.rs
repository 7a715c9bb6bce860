//! `meshsmooth`: the command-line tool and HTTP service over
//! `meshsmooth-core`.

mod cli;
mod service;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Quadric-fitting, curvature-adaptive surface mesh smoothing (Wang & Yu
/// 2009) with a quality report.
#[derive(Debug, Parser)]
#[command(name = "meshsmooth", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Smooth a mesh file and write the result (and optionally a report).
    Smooth(cli::SmoothArgs),
    /// Print the quality measures of a mesh without smoothing it.
    Report(cli::ReportArgs),
    /// Run the HTTP service.
    Serve(service::ServeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Smooth(args) => cli::smooth(args),
        Command::Report(args) => cli::report(args),
        Command::Serve(args) => service::serve(args),
    }
}
