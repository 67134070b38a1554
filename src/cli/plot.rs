//! `voxhap plot TRACE --out FILE.png|svg`: draws a recorded force trace (CSV, Parquet or MCAP) with
//! [`crate::record::plot`]. Thin: argument parsing, the title, and error context. The trace is read in batches
//! into a reduction whose size does not depend on the trace's length ([`PlotData`]).

use anyhow::Context;
use clap::Args;
use std::path::PathBuf;

use crate::record::plot::{check_output_name, plot_data, read_plot_data, PlotData};
use crate::record::Trace;

/// Arguments of `voxhap plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The trace to plot: a CSV, Parquet or MCAP file written by voxhap (its sidecar TRACE.json is used when
    /// present).
    pub trace: PathBuf,
    /// Output image; the extension chooses the format: .png or .svg.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Image width in pixels, 400 to 8192.
    #[arg(long, default_value_t = 1200, value_parser = clap::value_parser!(u32).range(400..=8192))]
    pub width: u32,
    /// Image height in pixels, 300 to 8192.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(300..=8192))]
    pub height: u32,
    /// Title; by default the trace's file name, scenario name, rate and length.
    #[arg(long)]
    pub title: Option<String>,
    /// Also print the smallest and largest value drawn of each force series and path coordinate (N, mm).
    #[arg(long)]
    pub extents: bool,
}

/// Reads the trace and writes the plot.
pub fn run(args: PlotArgs) -> anyhow::Result<()> {
    check_output_name(&args.out)?;
    // The reader's errors name the file (and the line and column).
    let (trace, data) = read_plot_data(&args.trace, args.width)?;
    for warning in &trace.warnings {
        eprintln!("warning: {warning}");
    }
    let title = args
        .title
        .clone()
        .unwrap_or_else(|| default_title(&args, &trace, &data));
    plot_data(&data, &trace, &title, &args.out, args.height)
        .with_context(|| format!("cannot plot {}", args.trace.display()))?;
    eprintln!("wrote {} ({} samples)", args.out.display(), data.samples());
    if data.untimed_samples() > 0 {
        eprintln!(
            "warning: {} samples have no finite time and are not drawn",
            data.untimed_samples()
        );
    }
    if args.extents {
        for (name, low, high) in data.drawn_extents() {
            let unit = if name.starts_with('p') { "mm" } else { "N" };
            eprintln!("drawn {name}: {low} to {high} {unit}");
        }
    }
    Ok(())
}

fn default_title(args: &PlotArgs, trace: &Trace, data: &PlotData) -> String {
    let file = args
        .trace
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut title = file;
    if let Some(sidecar) = &trace.sidecar {
        if let Some(name) = sidecar.meta.scenario.get("name").and_then(|v| v.as_str()) {
            title.push_str(&format!(" - {name}"));
        }
        title.push_str(&format!(" - {} Hz", sidecar.meta.rate_hz));
    }
    if let Some((first, last)) = data.time_span_s() {
        title.push_str(&format!(
            " - {} ticks, {:.3} s",
            data.samples(),
            last - first
        ));
    }
    title
}
