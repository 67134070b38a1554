//! The command-line interface: argument parsing (clap) and one module per subcommand.

pub mod info;

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
    /// Print what the loader reads from a volume file (or builtin:NAME).
    Info(info::InfoArgs),
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
        Some(Command::Info(args)) => info::run(&args),
    }
}
