//! `voxhap sim SCENARIO.toml --out TRACE [--format csv|mcap] [--solver exact|euler|constraint]`: run a
//! scenario headless and record its force trace (see [`crate::sim`]).
//!
//! A progress bar shows on a terminal (stderr) and nothing otherwise; one summary line goes to stdout.

use crate::haptics::tick::SolverKind;
use crate::record::{create_trace_writer, TraceFormat, TraceMeta};
use crate::sim::{self, LoadedScenario};
use anyhow::Context;
use clap::Args;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct SimArgs {
    /// The scenario file (TOML). Volume file paths in it are relative to its directory.
    pub scenario: PathBuf,
    /// The trace to write; its sidecar is TRACE.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Trace format; default: from the --out extension (.mcap is MCAP, anything else CSV).
    #[arg(long, value_enum)]
    pub format: Option<TraceFormat>,
    /// Proxy solver; default: the scenario's [solver] kind (exact unless it says otherwise).
    #[arg(long, value_enum)]
    pub solver: Option<SolverKind>,
    #[command(flatten)]
    pub limits: super::VolumeLimitArgs,
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
    args.limits.apply();
    let loaded = LoadedScenario::from_file(&args.scenario)?;
    let solver = args.solver.unwrap_or(loaded.scenario.solver.kind);
    let format = args
        .format
        .unwrap_or_else(|| TraceFormat::from_path(&args.out));
    let scenario_json = serde_json::to_value(&loaded.scenario)
        .context("cannot record the scenario in the trace metadata")?;
    let meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        scenario_json,
        loaded.volume_description.clone(),
        solver_label(solver),
    );
    let mut writer = create_trace_writer(&args.out, format, &meta)?;
    let ticks = loaded.scenario.tick_count();
    let bar = if std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(ticks);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{msg} [{bar:40}] {pos}/{len} ticks ({eta} left)",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(args.scenario.display().to_string());
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let result = sim::run(&loaded, solver, writer.as_mut(), |done| {
        bar.set_position(done)
    });
    bar.finish_and_clear();
    let summary = result.with_context(|| format!("sim {} stopped", args.scenario.display()))?;
    let written = writer.finish()?;
    let bound = if summary.max_error_bound_m.is_finite() {
        format!("{:.2e} m", summary.max_error_bound_m)
    } else {
        "none (uncertified solver)".to_owned()
    };
    super::print_out(&format!(
        "{}: {} ticks ({} s at {} Hz), solver {}, {} certified, largest bound {bound}, most sweeps {}, \
         largest force {:.3} N -> {} (+ {})",
        args.scenario.display(),
        summary.ticks,
        loaded.scenario.duration_s,
        loaded.scenario.rate_hz,
        solver.name(),
        summary.certified_ticks,
        summary.max_sweeps,
        summary.max_force_n,
        written.trace_path.display(),
        written.sidecar_path.display(),
    ))
}

/// The solver label recorded in the trace metadata.
pub fn solver_label(solver: SolverKind) -> &'static str {
    match solver {
        SolverKind::Exact => "exact-dual",
        SolverKind::Euler => "euler-baseline",
        SolverKind::Constraint => "constraint-baseline",
    }
}
