//! `voxhap sim SCENARIO.toml --out TRACE [--format csv|mcap|parquet] [--solver exact|euler|constraint] [--force]
//! [--max-trace-bytes N] [--set KEY=VALUE]... [--duration S] [--rate HZ] [--fail-on LIST]`: run a scenario
//! headless and record its force trace (see [`crate::sim`]).
//!
//! Overrides (`--set`, `--duration`, `--rate`) change the scenario before it is validated
//! ([`crate::sim::overrides`]); the trace's metadata records the scenario as run. `--fail-on` makes a run
//! that completed exit with [`EXIT_FAIL_ON`] when one of the named conditions occurred (the trace is
//! still written and finished).
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
    /// Trace format; default: from the --out extension (.mcap is MCAP, .parquet Parquet, anything else CSV).
    #[arg(long, value_parser = super::common::trace_format_parser())]
    pub format: Option<TraceFormat>,
    /// Proxy solver; default: the scenario's [solver] kind (exact unless it says otherwise).
    #[arg(long, value_parser = super::common::solver_kind_parser())]
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
    /// Override a scenario key before validation: KEY=VALUE, KEY a dotted path with array indices
    /// (k_n_per_m=200, modes[1].mu=0.4, path.speed_m_per_s=0.01); repeatable, applied in order.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Override the scenario's duration_s (s).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Override the scenario's rate_hz (Hz).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Exit with code 3 (after writing the trace) when any of these occurred: uncertified (a tick the
    /// exact solver did not certify, or any tick of a baseline solver), device-error (a non-finite force
    /// or probe replaced by zero), disconnect, overrun (never in a sim: it has no device link and no
    /// clock), active (the coupling's net generated energy rose by more than 0.1 mJ), oscillation (a
    /// contact limit cycle); beyond-bound refuses to start (exit 3, nothing written) when k_n_per_m is
    /// above the arm's passivity bound b / (T/2 + tau) (T: the servo period, or with [local_model] the
    /// device loop's). Comma-separated.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub fail_on: Vec<FailOn>,
    #[command(flatten)]
    pub limits: super::common::VolumeLimitArgs,
}

/// Conditions `--fail-on` can make a run fail on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FailOn {
    /// A tick without a certificate within the solver's tolerance.
    Uncertified,
    /// The device disconnected.
    Disconnect,
    /// A device error (in a sim: a non-finite force or probe replaced by zero).
    DeviceError,
    /// A tick started late (the schedule skipped).
    Overrun,
    /// The coupling generated energy: its net generated energy rose by more than 0.1 mJ over some window.
    Active,
    /// A contact limit cycle: contact lost and regained repeatedly with undecaying force.
    Oscillation,
    /// The scenario's stiffness is above the arm's passivity bound (checked before the run).
    BeyondBound,
}

/// Exit code of a run that finished but met a `--fail-on` condition.
pub const EXIT_FAIL_ON: u8 = 3;

/// The outcome of a run that met a `--fail-on` condition: `message` on stderr, exit code [`EXIT_FAIL_ON`].
pub fn fail_on_exit(message: String) -> anyhow::Error {
    super::common::ExitWith {
        code: EXIT_FAIL_ON,
        message,
    }
    .into()
}

/// The scenario file with `--set`, `--duration` and `--rate` applied, validated and loaded.
pub fn load_scenario(
    path: &std::path::Path,
    set: &[String],
    duration_s: Option<f64>,
    rate_hz: Option<f64>,
) -> anyhow::Result<LoadedScenario> {
    let mut overrides = set.to_vec();
    if let Some(duration) = duration_s {
        overrides.push(format!("duration_s={duration:?}"));
    }
    if let Some(rate) = rate_hz {
        overrides.push(format!("rate_hz={rate:?}"));
    }
    if overrides.is_empty() {
        return Ok(LoadedScenario::from_file(path)?);
    }
    let origin = path.display().to_string();
    // Bounded like every scenario read (`Scenario::read`): a regular file of at most 16 MiB.
    let text = crate::volume::io::read_text_file(path)
        .with_context(|| format!("cannot read scenario file {origin}"))?;
    let text = crate::sim::overrides::apply_overrides(&text, &overrides)
        .with_context(|| format!("{origin}: overrides"))?;
    let scenario = crate::sim::Scenario::parse_edited(&text, &format!("{origin} (with --set)"))?;
    let base_dir = path.parent().unwrap_or(std::path::Path::new(""));
    Ok(scenario.load(base_dir, &origin)?)
}

/// What `--fail-on` found in a finished run, as a sentence per condition met.
pub fn fail_on_findings(fail_on: &[FailOn], summary: &crate::sim::SimSummary) -> Vec<String> {
    let mut found = Vec::new();
    for condition in fail_on {
        match condition {
            FailOn::Uncertified if summary.certified_ticks < summary.ticks => found.push(format!(
                "uncertified: {} of {} ticks without a certificate within tolerance",
                summary.ticks - summary.certified_ticks,
                summary.ticks
            )),
            FailOn::DeviceError if summary.non_finite_ticks > 0 => found.push(format!(
                "device-error: {} ticks with a non-finite force or probe replaced by zero",
                summary.non_finite_ticks
            )),
            FailOn::Active | FailOn::Oscillation => {
                found.extend(energy_finding(*condition, &summary.energy.report()))
            }
            _ => {}
        }
    }
    found
}

/// What `--fail-on active` or `--fail-on oscillation` found in the energy ledger's totals (`sim`, `sweep`
/// and `serve`), as a sentence; `None` when the condition was not met or is not an energy condition.
pub fn energy_finding(condition: FailOn, energy: &crate::api::EnergyReport) -> Option<String> {
    match condition {
        FailOn::Active if energy.active => Some(format!(
            "active: the coupling's net generated energy rose by {:.3} mJ (tolerance {} mJ)",
            energy.largest_rise_j * 1e3,
            crate::servo::energy::ACTIVE_TOLERANCE_J * 1e3
        )),
        FailOn::Oscillation if energy.oscillating => Some(format!(
            "oscillation: {} undecaying contacts in a row ({} contacts in all)",
            energy.longest_cycle_run, energy.contacts
        )),
        _ => None,
    }
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

/// The warning when the scenario's stiffness is above the arm's passivity bound (`None` when within). The bound
/// is that of the loop that closes the contact: the servo's at `rate_hz`, or with `[local_model]` the device's own
/// loop at its `rate_hz`.
pub fn stiffness_warning(loaded: &LoadedScenario) -> Option<String> {
    let local = loaded.scenario.local_model;
    let period_s = local.map_or(loaded.scenario.dt_s(), |l| 1.0 / l.rate_hz);
    let physics = loaded.arm.physics();
    let bound = physics.max_stiffness_n_per_m(period_s);
    let k = loaded.scenario.k_n_per_m;
    let whose = match local {
        Some(l) => format!("passivity bound in the device's {} Hz loop", l.rate_hz),
        None => "passivity bound".to_owned(),
    };
    (k > bound).then(|| {
        format!(
            "k_n_per_m = {k} N/m is above the arm's {whose}: {}; contact may bounce",
            physics.notice(period_s)
        )
    })
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
    args.limits.apply();
    let loaded = load_scenario(&args.scenario, &args.set, args.duration, args.rate)?;
    if let Some(warning) = stiffness_warning(&loaded) {
        if args.fail_on.contains(&FailOn::BeyondBound) {
            return Err(fail_on_exit(format!("--fail-on: beyond-bound: {warning}")));
        }
        eprintln!("warning: {warning}");
    }
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
    let estimate = estimate_trace_bytes(
        format,
        loaded.scene.mode_names().len(),
        ticks,
        loaded.scenario.rate_hz,
    );
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
    let written = match writer.finish() {
        Ok(written) => written,
        Err(error) => {
            // The sidecar says why the trace ends early, and counts what reached the file.
            let _ = writer.fail(&error_chain(&error));
            return Err(anyhow::anyhow!("{}", error_chain(&error)));
        }
    };
    let bound = if summary.max_error_bound_m.is_finite() {
        format!("{:.2e} m", summary.max_error_bound_m)
    } else {
        "none (uncertified solver)".to_owned()
    };
    let findings = fail_on_findings(&args.fail_on, &summary);
    super::common::print_out(&format!(
        "{}: {} ticks ({} s at {} Hz{}), solver {}, {} certified, largest bound {bound}, most sweeps {}, \
         largest force {:.3} N, generated {:.4} mJ (net of the arm's damping {:.4} mJ, active work {:.4} mJ), \
         {} contact{} -> {} (+ {})",
        args.scenario.display(),
        summary.ticks,
        loaded.scenario.duration_s,
        loaded.scenario.rate_hz,
        loaded
            .scenario
            .local_model
            .map_or(String::new(), |l| format!(", device loop at {} Hz", l.rate_hz)),
        solver.name(),
        summary.certified_ticks,
        summary.max_sweeps,
        summary.max_force_n,
        summary.energy.generated_j * 1e3,
        summary.energy.net_generated_j * 1e3,
        summary.energy.active_work_j * 1e3,
        summary.energy.contacts,
        if summary.energy.contacts == 1 { "" } else { "s" },
        written.trace_path.display(),
        written.sidecar_path.display(),
    ))?;
    if summary.passivity_mode == crate::servo::passivity::PassivityMode::Control
        || summary.events_applied > 0
    {
        eprintln!(
            "passivity: {}, dissipated {:.4} mJ in {} ticks (largest force {:.3} N); {} event(s) applied, {} introduced passively",
            summary.passivity_mode.name(),
            summary.passivity.dissipated_j * 1e3,
            summary.passivity.active_ticks,
            summary.passivity.max_force_n,
            summary.events_applied,
            summary.changes_introduced,
        );
    }
    if !findings.is_empty() {
        return Err(fail_on_exit(format!("--fail-on: {}", findings.join("; "))));
    }
    Ok(())
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
