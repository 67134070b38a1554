//! `voxhap sim SCENARIO.toml --out TRACE [--format csv|mcap] [--solver exact|euler|constraint] [--force]
//! [--max-trace-bytes N]`: run a scenario headless and record its force trace (see [`crate::sim`]).
//!
//! Before anything is written: the output must not exist (unless `--force`) and is never one of the
//! run's inputs (the scenario, its volume files); the trace's size is estimated from the tick count and
//! the format, and a run over `--max-trace-bytes` (default 2 GB) is refused with the estimate.
//! A progress bar shows on a terminal (stderr) and nothing otherwise; one summary line goes to stdout.

use crate::haptics::tick::SolverKind;
use crate::record::{
    create_trace_writer_with, error_chain, estimate_trace_bytes, OutputPolicy, TraceFormat,
    TraceMeta,
};
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
    /// Replace an existing trace (never the scenario or one of its volume files).
    #[arg(long)]
    pub force: bool,
    /// Wall-clock UTC (ns since 1970) dated to the run's t = 0 in the trace's utc_ns column; default: now.
    /// A fixed value makes two runs' traces byte-for-byte identical.
    #[arg(long)]
    pub start_utc_ns: Option<i64>,
    /// Refuse to start when the trace is estimated to take more bytes than this.
    #[arg(long, default_value_t = DEFAULT_MAX_TRACE_BYTES)]
    pub max_trace_bytes: u64,
}

/// Default of `--max-trace-bytes`: 2 GB.
pub const DEFAULT_MAX_TRACE_BYTES: u64 = 2_000_000_000;

/// The run's input files: the scenario and the volume files it names (relative to its directory).
pub fn scenario_inputs(scenario_path: &std::path::Path, loaded: &LoadedScenario) -> Vec<PathBuf> {
    let base = scenario_path.parent().unwrap_or(std::path::Path::new(""));
    let mut inputs = vec![scenario_path.to_path_buf()];
    inputs.extend(
        loaded
            .scenario
            .volumes
            .iter()
            .filter_map(|v| v.file.as_ref().map(|f| base.join(f))),
    );
    inputs
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
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
    let ticks = loaded.scenario.tick_count();
    let estimate = estimate_trace_bytes(format, loaded.scene.mode_names().len(), ticks);
    if estimate > args.max_trace_bytes {
        anyhow::bail!(
            "the trace would take about {} ({ticks} ticks, {} s at {} Hz, {format}), more than --max-trace-bytes {}; \
             shorten the run, lower the rate, or raise --max-trace-bytes",
            human_bytes(estimate),
            loaded.scenario.duration_s,
            loaded.scenario.rate_hz,
            args.max_trace_bytes
        );
    }
    let policy = OutputPolicy {
        overwrite: args.force,
        inputs: scenario_inputs(&args.scenario, &loaded),
    };
    let mut meta = meta;
    if let Some(start) = args.start_utc_ns {
        meta.start_utc_ns = start;
    }
    let mut writer = create_trace_writer_with(&args.out, format, &meta, &policy)
        .map_err(|e| anyhow::anyhow!("--out: {}", error_chain(&e)))?;
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
    if let Err(error) = &result {
        // The sidecar says why the trace ends early.
        let _ = writer.fail(&error_chain(error));
    }
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

/// `bytes` as a short human figure (`1.9 GB`, `310 MB`, `12 kB`).
pub fn human_bytes(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= 1e9 {
        format!("{:.1} GB", b / 1e9)
    } else if b >= 1e6 {
        format!("{:.0} MB", b / 1e6)
    } else {
        format!("{:.0} kB", b / 1e3)
    }
}

/// The solver label recorded in the trace metadata.
pub fn solver_label(solver: SolverKind) -> &'static str {
    match solver {
        SolverKind::Exact => "exact-dual",
        SolverKind::Euler => "euler-baseline",
        SolverKind::Constraint => "constraint-baseline",
    }
}
