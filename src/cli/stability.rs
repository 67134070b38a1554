//! `voxhap stability`: how stiff a wall each simulated arm holds with the host alone, with a local model
//! rendered by the device at its own rate, and with a full-rate host loop; how far the force of a model up to
//! one host period old is from a full-rate render along the shipped sims' paths; and what the models take on
//! the link. The measurements are `voxhap::sim::stability`'s; this module runs them (on every core), prints
//! the tables (markdown or CSV) and writes the plots ([`svg`]).

use crate::sim::stability::{
    arms::arm_named, largest_passive, stale_force, ArmCase, Limit, LoopKind, StaleForce, ARMS,
};
use anyhow::Context;
use clap::{Args, ValueEnum};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

pub mod svg;

pub use svg::group_digits;

/// The table format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TableFormat {
    /// Markdown tables.
    Markdown,
    /// CSV, one row per measurement.
    Csv,
}

/// What to measure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Part {
    /// Both.
    All,
    /// The largest stable stiffness per arm.
    Stiffness,
    /// The force error of a stale model and the link use, per sim.
    ForceError,
}

#[derive(Debug, Args)]
pub struct StabilityArgs {
    /// Arms to measure, comma-separated: default (the simulated arm's own figures) and the presets touch,
    /// falcon, inverse3, woodenhaptics.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "default,touch,falcon,inverse3,woodenhaptics"
    )]
    pub arms: Vec<String>,
    /// The host's rate, Hz: the rate of the host alone and the rate it sends local models at.
    #[arg(long, default_value_t = 1000.0)]
    pub host_rate: f64,
    /// The device's own loop rate with a local model, Hz (a whole multiple of --host-rate).
    #[arg(long, default_value_t = 10000.0)]
    pub local_rate: f64,
    /// The rate of the full-rate host loop shown for comparison, Hz.
    #[arg(long, default_value_t = 10000.0)]
    pub full_rate: f64,
    /// Link latency, ms, comma-separated: each gets its own rows. It delays the host's forces, and the local
    /// models (not the device's own loop).
    #[arg(long, value_delimiter = ',', default_value = "0,1")]
    pub latency_ms: Vec<f64>,
    /// Bisection tolerance: the search stops when its bracket's ends are within this ratio (0.003 = 0.3 %).
    #[arg(long, default_value_t = 0.003)]
    pub tolerance: f64,
    /// The search runs from a quarter of each loop's passivity bound to this multiple of it (1.5 to 100).
    #[arg(long, default_value_t = 3.0)]
    pub ceiling: f64,
    /// Folder of the scenarios for the force error (every *.toml in it; the shipped brain sim names its scan
    /// in ../data: give --allow-outside-paths).
    #[arg(long, default_value = "sims")]
    pub sims: PathBuf,
    /// What to measure.
    #[arg(long, value_enum, default_value_t = Part::All)]
    pub only: Part,
    /// Table format.
    #[arg(long, value_enum, default_value_t = TableFormat::Markdown)]
    pub format: TableFormat,
    /// Write the plots into this folder (created if missing): stiffness.svg and force-error.svg. Existing plots
    /// of those names are replaced.
    #[arg(long, value_name = "DIR")]
    pub plots: Option<PathBuf>,
    /// Runs at once; default: the available cores.
    #[arg(long)]
    pub jobs: Option<usize>,
    #[command(flatten)]
    pub limits: super::common::VolumeLimitArgs,
}

/// The three loops of one row.
const LOOPS: [&str; 3] = ["host alone", "host + local model", "full-rate host"];

/// One loop of a row: its kind, the limit measured, and the exact zero-order-hold boundary.
struct LoopResult {
    kind: LoopKind,
    limit: Limit,
    exact_n_per_m: f64,
}

/// One row of the stiffness table: an arm at a latency, and each loop's result.
struct StiffnessRow {
    arm: &'static ArmCase,
    latency_s: f64,
    loops: [LoopResult; 3],
}

fn limit_text(limit: &Limit) -> String {
    match limit {
        Limit::Found(k) => format!("{} N/m", group_digits(*k)),
        Limit::AtLeast(k) => format!("≥ {} N/m", group_digits(*k)),
        Limit::Below(k) => format!("< {} N/m", group_digits(*k)),
    }
}

fn limit_kind(limit: &Limit) -> &'static str {
    match limit {
        Limit::Found(_) => "found",
        Limit::AtLeast(_) => "at_least",
        Limit::Below(_) => "below",
    }
}

/// Three significant digits, for forces and speeds; below 0.001 in scientific notation (`2.4e-8`).
fn sig3(value: f64) -> String {
    if value == 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    if value.abs() < 1e-3 {
        return format!("{value:.1e}");
    }
    let decimals = (2 - value.abs().log10().floor() as i32).max(0) as usize;
    format!("{value:.decimals$}")
}

/// Runs `jobs` closures on `threads` threads; results in input order.
fn run_parallel<T: Send, F: Fn(usize) -> anyhow::Result<T> + Sync>(
    count: usize,
    threads: usize,
    job: F,
) -> anyhow::Result<Vec<T>> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<anyhow::Result<T>>>> =
        Mutex::new((0..count).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, count.max(1)) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= count {
                    break;
                }
                let result = job(i);
                results.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(result);
            });
        }
    });
    results
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|r| r.unwrap_or_else(|| Err(anyhow::anyhow!("a measurement did not run"))))
        .collect()
}

fn check_args(args: &StabilityArgs) -> anyhow::Result<Vec<&'static ArmCase>> {
    let mut arms = Vec::new();
    for name in &args.arms {
        let arm = arm_named(name).with_context(|| {
            let names: Vec<&str> = ARMS.iter().map(ArmCase::name).collect();
            format!("--arms {name:?}: not an arm (one of {})", names.join(", "))
        })?;
        arms.push(arm);
    }
    for (flag, rate) in [
        ("--host-rate", args.host_rate),
        ("--local-rate", args.local_rate),
        ("--full-rate", args.full_rate),
    ] {
        if !(rate.is_finite() && rate > 0.0) {
            anyhow::bail!("{flag} {rate}: must be a positive number of Hz");
        }
    }
    for latency in &args.latency_ms {
        if !(latency.is_finite() && *latency >= 0.0) {
            anyhow::bail!("--latency-ms {latency}: must be zero or more");
        }
    }
    if !(1.5..=100.0).contains(&args.ceiling) {
        anyhow::bail!("--ceiling {}: must be from 1.5 to 100", args.ceiling);
    }
    if args.jobs == Some(0) {
        anyhow::bail!("--jobs 0: at least one");
    }
    Ok(arms)
}

/// The scenario files of the force-error table: every `*.toml` directly in `dir`, by name.
fn scenario_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("--sims {}: cannot read the folder", dir.display()))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry
            .with_context(|| format!("--sims {}: cannot read the folder", dir.display()))?
            .path();
        if path.is_file() && path.extension().is_some_and(|e| e == "toml") {
            files.push(path);
        }
    }
    files.sort();
    if files.is_empty() {
        anyhow::bail!("--sims {}: no .toml scenario in the folder", dir.display());
    }
    Ok(files)
}

fn measure_stiffness(
    args: &StabilityArgs,
    arms: &[&'static ArmCase],
    threads: usize,
) -> anyhow::Result<Vec<StiffnessRow>> {
    let mut jobs = Vec::new();
    for arm in arms {
        for latency_ms in &args.latency_ms {
            let latency_s = latency_ms * 1e-3;
            let kinds = [
                LoopKind::Host {
                    rate_hz: args.host_rate,
                    latency_s,
                    control: false,
                },
                LoopKind::Local {
                    host_rate_hz: args.host_rate,
                    device_rate_hz: args.local_rate,
                    latency_s,
                },
                LoopKind::Host {
                    rate_hz: args.full_rate,
                    latency_s,
                    control: false,
                },
            ];
            for kind in kinds {
                jobs.push((*arm, latency_s, kind));
            }
        }
    }
    let limits = run_parallel(jobs.len(), threads, |i| {
        let (arm, latency_s, kind) = jobs[i];
        largest_passive(arm, kind, args.ceiling, args.tolerance)
            .with_context(|| format!("{} at {} ms latency, {kind:?}", arm.name(), latency_s * 1e3))
    })?;
    let result = |(arm, _, kind): (&'static ArmCase, f64, LoopKind), limit: Limit| {
        let exact_n_per_m = kind
            .exact_boundary_n_per_m(arm.mass_kg, arm.damping_n_s_per_m)
            .with_context(|| format!("{}, {kind:?}", arm.name()))?;
        anyhow::Ok(LoopResult {
            kind,
            limit,
            exact_n_per_m,
        })
    };
    jobs.chunks(3)
        .zip(limits.chunks(3))
        .map(|(job, limit)| {
            Ok(StiffnessRow {
                arm: job[0].0,
                latency_s: job[0].1,
                loops: [
                    result(job[0], limit[0])?,
                    result(job[1], limit[1])?,
                    result(job[2], limit[2])?,
                ],
            })
        })
        .collect()
}

fn stiffness_markdown(args: &StabilityArgs, rows: &[StiffnessRow]) -> String {
    let host = group_digits(args.host_rate);
    let local = group_digits(args.local_rate);
    let full = group_digits(args.full_rate);
    let mut out = format!(
        "| arm | mass | damping `b` | latency | host {host} Hz alone | bound | exact | host {host} Hz + local model \
         {local} Hz | bound | exact | host {full} Hz | bound | exact |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for row in rows {
        let b = row.arm.damping_n_s_per_m;
        let _ = write!(
            out,
            "| {} | {} kg | {b} N s/m | {} ms |",
            row.arm.name(),
            row.arm.mass_kg,
            row.latency_s * 1e3
        );
        for r in &row.loops {
            let _ = write!(
                out,
                " {} | {} N/m | {} N/m |",
                limit_text(&r.limit),
                group_digits(r.kind.bound_n_per_m(b)),
                group_digits(r.exact_n_per_m)
            );
        }
        out.push('\n');
    }
    out
}

fn stiffness_csv(rows: &[StiffnessRow]) -> String {
    let mut out = String::from(
        "arm,mass_kg,damping_n_s_per_m,latency_s,loop,loop_rate_hz,limit,stiffness_n_per_m,bound_n_per_m,\
         exact_zoh_n_per_m\n",
    );
    for row in rows {
        for (r, name) in row.loops.iter().zip(LOOPS) {
            let _ = writeln!(
                out,
                "{},{},{},{},{name},{},{},{},{},{}",
                row.arm.name(),
                row.arm.mass_kg,
                row.arm.damping_n_s_per_m,
                row.latency_s,
                r.kind.loop_rate_hz(),
                limit_kind(&r.limit),
                r.limit.n_per_m(),
                r.kind.bound_n_per_m(row.arm.damping_n_s_per_m),
                r.exact_n_per_m
            );
        }
    }
    out
}

/// Full-speed USB's signalling rate, bits per second (USB 2.0 specification, section 3.2.2).
const FULL_SPEED_BITS_PER_S: f64 = 12e6;

fn force_error_markdown(results: &[StaleForce]) -> String {
    let mut out = String::from(
        "| sim | cycles compared | hand speed median / p99 | force error median | p99 | max | largest full-rate force |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in results {
        let _ = writeln!(
            out,
            "| {} | {} | {} / {} mm/s | {} N | {} N | {} N | {} N |",
            r.name,
            r.compared_cycles,
            sig3(r.speed_median_m_per_s * 1e3),
            sig3(r.speed_p99_m_per_s * 1e3),
            sig3(r.error_median_n),
            sig3(r.error_p99_n),
            sig3(r.error_max_n),
            sig3(r.reference_max_n)
        );
    }
    out.push_str(
        "\n| sim | primitives per model, mean / max | truncated models | model frame | at the host rate | share of 12 Mbit/s | SetForce frame |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in results {
        let bits = r.model_bits_per_s();
        let _ = writeln!(
            out,
            "| {} | {:.2} / {} | {} of {} | {} bytes | {} kbit/s | {:.1} % | {} bytes |",
            r.name,
            r.primitives_mean,
            r.primitives_max,
            r.truncated_models,
            r.models,
            r.model_frame_bytes,
            group_digits(bits / 1e3),
            100.0 * bits / FULL_SPEED_BITS_PER_S,
            r.set_force_frame_bytes
        );
    }
    out
}

fn force_error_csv(results: &[StaleForce]) -> String {
    let mut out = String::from(
        "sim,host_rate_hz,device_rate_hz,compared_cycles,speed_median_m_per_s,speed_p99_m_per_s,error_median_n,\
         error_p99_n,error_max_n,reference_max_n,models,primitives_mean,primitives_max,truncated_models,\
         model_frame_bytes,model_bits_per_s,set_force_frame_bytes\n",
    );
    for r in results {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.name,
            r.host_rate_hz,
            r.device_rate_hz,
            r.compared_cycles,
            r.speed_median_m_per_s,
            r.speed_p99_m_per_s,
            r.error_median_n,
            r.error_p99_n,
            r.error_max_n,
            r.reference_max_n,
            r.models,
            r.primitives_mean,
            r.primitives_max,
            r.truncated_models,
            r.model_frame_bytes,
            r.model_bits_per_s(),
            r.set_force_frame_bytes
        );
    }
    out
}

fn stiffness_plot(args: &StabilityArgs, rows: &[StiffnessRow]) -> String {
    let series = [
        svg::Series::new("host alone", "#d62728"),
        svg::Series::new("host + local model", "#2ca02c"),
        svg::Series::new("full-rate host", "#1f77b4"),
    ];
    let groups: Vec<svg::Group> = rows
        .iter()
        .map(|row| svg::Group {
            label: format!("{}, {} ms", row.arm.name(), row.latency_s * 1e3),
            values: row.loops.iter().map(|r| Some(r.limit.n_per_m())).collect(),
            markers: row
                .loops
                .iter()
                .map(|r| Some(r.kind.bound_n_per_m(row.arm.damping_n_s_per_m)))
                .collect(),
            dots: row.loops.iter().map(|r| Some(r.exact_n_per_m)).collect(),
        })
        .collect();
    svg::grouped_bars(
        &format!(
            "Largest passive stiffness: host {} Hz alone, + local model {} Hz, host {} Hz",
            group_digits(args.host_rate),
            group_digits(args.local_rate),
            group_digits(args.full_rate)
        ),
        "stiffness (N/m)",
        &svg::Notes {
            markers: "passivity bound b/(T/2+τ)",
            dots: Some("exact zero-order-hold boundary"),
        },
        1.0,
        &series,
        &groups,
    )
}

/// The force-error plot's axis starts at or above this, N: smaller errors (rounding) get no bar.
const FORCE_PLOT_FLOOR_N: f64 = 1e-6;

fn force_error_plot(results: &[StaleForce]) -> String {
    let series = [
        svg::Series::new("median", "#2ca02c"),
        svg::Series::new("99th percentile", "#ff7f0e"),
        svg::Series::new("max", "#d62728"),
    ];
    let groups: Vec<svg::Group> = results
        .iter()
        .map(|r| svg::Group {
            label: r.name.clone(),
            values: vec![
                Some(r.error_median_n),
                Some(r.error_p99_n),
                Some(r.error_max_n),
            ],
            markers: vec![None, None, Some(r.reference_max_n)],
            dots: Vec::new(),
        })
        .collect();
    let rate = results.first().map_or(0.0, |r| r.device_rate_hz);
    let host = results.first().map_or(0.0, |r| r.host_rate_hz);
    svg::grouped_bars(
        &format!(
            "Force error of the local model (host {} Hz, device {} Hz) against a {} Hz render",
            group_digits(host),
            group_digits(rate),
            group_digits(rate)
        ),
        "force error (N)",
        &svg::Notes {
            markers: "largest full-rate force (N)",
            dots: None,
        },
        FORCE_PLOT_FLOOR_N,
        &series,
        &groups,
    )
}

fn write_plot(dir: &Path, name: &str, svg: &str) -> anyhow::Result<()> {
    let path = dir.join(name);
    if path.is_symlink() {
        anyhow::bail!(
            "plot {}: a symbolic link; voxhap never writes a plot through one",
            path.display()
        );
    }
    std::fs::write(&path, svg).with_context(|| format!("cannot write {}", path.display()))
}

/// Measures, prints the tables and writes the plots.
pub fn run(args: &StabilityArgs) -> anyhow::Result<()> {
    let arms = check_args(args)?;
    args.limits.apply();
    let threads = args.jobs.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
    });
    if let Some(dir) = &args.plots {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--plots {}: cannot create the folder", dir.display()))?;
    }
    let mut out = String::new();
    if args.only != Part::ForceError {
        let rows = measure_stiffness(args, &arms, threads)?;
        out.push_str(&match args.format {
            TableFormat::Markdown => stiffness_markdown(args, &rows),
            TableFormat::Csv => stiffness_csv(&rows),
        });
        if let Some(dir) = &args.plots {
            write_plot(dir, "stiffness.svg", &stiffness_plot(args, &rows))?;
        }
    }
    if args.only != Part::Stiffness {
        let files = scenario_files(&args.sims)?;
        let results = run_parallel(files.len(), threads, |i| {
            stale_force(&files[i], args.local_rate)
                .with_context(|| format!("force error of {}", files[i].display()))
        })?;
        if !out.is_empty() {
            out.push('\n');
        }
        out.push_str(&match args.format {
            TableFormat::Markdown => force_error_markdown(&results),
            TableFormat::Csv => force_error_csv(&results),
        });
        if let Some(dir) = &args.plots {
            write_plot(dir, "force-error.svg", &force_error_plot(&results))?;
        }
    }
    super::print_out(out.trim_end())?;
    Ok(())
}
