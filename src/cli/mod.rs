//! The command-line interface: argument parsing (clap) and one module per subcommand.

pub mod plot;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// voxhap: haptic proxy rendering for volume data.
#[derive(Debug, Parser)]
#[command(name = "voxhap", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Plot a recorded force trace (CSV or MCAP) to a PNG or SVG image.
    Plot(plot::PlotArgs),
}

/// Parses the arguments, runs the subcommand and maps errors to a non-zero exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        None => Ok(()),
        Some(Command::Plot(args)) => plot::run(args),
    }
}
