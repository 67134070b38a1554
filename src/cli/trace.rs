//! `voxhap trace repair FILE [--out OUT] [--force]`: recover what a crash left of a trace (see
//! [`crate::record::repair`]). The input is never modified; the repaired trace goes to `OUT` (default
//! `NAME.repaired.EXT` next to it) with a sidecar that says what was recovered.

use crate::record::repair::{default_repair_output, repair_trace};
use crate::record::{error_chain, OutputPolicy, TraceFormat};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct TraceArgs {
    #[command(subcommand)]
    pub command: TraceCommand,
}

#[derive(Debug, Subcommand)]
pub enum TraceCommand {
    /// Read what a crashed recording left (a partial last CSV line, an MCAP file without its summary) and
    /// write it as a finished trace.
    Repair(RepairArgs),
}

#[derive(Debug, Args)]
pub struct RepairArgs {
    /// The damaged trace (CSV, MCAP or Parquet); it is never modified.
    pub file: PathBuf,
    /// Where to write the repaired trace; default NAME.repaired.EXT next to FILE.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Format of the repaired trace; default the input's.
    #[arg(long, value_parser = super::common::trace_format_parser())]
    pub format: Option<TraceFormat>,
    /// Replace an existing output file (never the input).
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: &TraceArgs) -> anyhow::Result<()> {
    match &args.command {
        TraceCommand::Repair(repair) => run_repair(repair),
    }
}

fn run_repair(args: &RepairArgs) -> anyhow::Result<()> {
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_repair_output(&args.file));
    let policy = OutputPolicy {
        overwrite: args.force,
        inputs: Vec::new(),
    };
    let report = repair_trace(&args.file, &out, args.format, &policy)
        .map_err(|e| anyhow::anyhow!("{}", error_chain(&e)))?;
    for warning in &report.warnings {
        eprintln!("warning: {warning}");
    }
    super::common::print_out(&format!(
        "{}: {} samples recovered -> {}",
        args.file.display(),
        report.sample_count,
        report.output.display()
    ))
}
