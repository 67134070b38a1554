//! `voxhap bench-loop`: runs the servo loop on the simulated arm with the built-in three-mode scene for a
//! while and prints the lateness and compute histograms and the overrun count.
//! `--load-threads N` adds N busy threads (at normal priority) to measure under load. `--baseline` alternates
//! windows of the loop with windows of the same schedule with an empty tick on the same CPU
//! ([`crate::servo::baseline`]), so stalls of the machine show apart from the loop's own. Both end with the
//! steal time over the run ([`crate::servo::steal`]): on a virtual machine, the time the host ran something
//! else while the guest's CPUs had work.

use crate::api::{HistogramReport, RealtimeReport};
use crate::servo::baseline::run_empty_schedule;
use crate::servo::device::DeviceSpec;
use crate::servo::rt::RtMode;
use crate::servo::setup::SceneSetup;
use crate::servo::stats::{Histogram, HistogramCounts, DECADE_HEADS};
use crate::servo::steal::{self, StealReport};
use crate::servo::{Session, SessionConfig};
use anyhow::bail;
use clap::Args;
use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Args)]
pub struct BenchLoopArgs {
    /// How long to run (s), > 0 and <= 1e9.
    #[arg(long, default_value_t = 10.0, value_parser = super::common::parse_seconds)]
    pub seconds: f64,
    /// Servo rate (Hz), 100 to 10000.
    #[arg(long, default_value_t = 1000.0)]
    pub rate: f64,
    /// Print the statistics as JSON.
    #[arg(long)]
    pub json: bool,
    /// Busy threads to run alongside (to measure with the cores loaded), 0 to 64.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=64))]
    pub load_threads: u16,
    /// How long before each deadline the servo thread stops sleeping and spins (µs).
    #[arg(long, default_value_t = 80)]
    pub spin_us: u64,
    /// How long before each deadline the servo thread warms its caches for the coming tick (µs; 0: off).
    #[arg(long, default_value_t = 30)]
    pub warm_us: u64,
    /// Real-time scheduling (as for serve).
    #[arg(long, value_enum, default_value_t = RtMode::BestEffort)]
    pub rt: RtMode,
    /// Alternate windows (at most 2 s each, --seconds in all) of the loop and of the same schedule (rate, spin,
    /// CPU, real-time setup) with an empty tick, and print both lateness rows: what the empty tick shows comes
    /// from the machine, not from voxhap.
    #[arg(long)]
    pub baseline: bool,
}

pub fn run(args: &BenchLoopArgs) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        bail!("--seconds must be > 0, got {}", args.seconds);
    }
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin()?);
    config.rate_hz = args.rate;
    config.rt = args.rt;
    config.spin_ns = args.spin_us.saturating_mul(1000);
    config.warm_lead_ns = args.warm_us.saturating_mul(1000);
    let stop_load = Arc::new(AtomicBool::new(false));
    let load: Vec<_> = (0..args.load_threads)
        .map(|_| {
            let stop = stop_load.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
                    std::hint::black_box(x);
                }
            })
        })
        .collect();
    // After the load threads (they are meant to load every core), before the session's own threads.
    if let Some((servo, _)) = crate::servo::rt::reserve_servo_cpu(config.rt, config.cpu) {
        config.cpu = Some(servo);
    }
    let stop_load_threads = || {
        stop_load.store(true, Ordering::Relaxed);
        for thread in load {
            let _ = thread.join();
        }
    };
    if args.baseline {
        let comparison = side_by_side(args, &config);
        stop_load_threads();
        let comparison = comparison?;
        return print_report(args, &comparison, || comparison.table());
    }
    let steal_before = steal::sample();
    let session = Session::start(config)?;
    let shared = session.api();
    std::thread::sleep(Duration::from_secs_f64(args.seconds));
    let summary = session.stop();
    let steal = steal::since(steal_before.as_ref(), summary.stats.realtime.pinned_cpu);
    let decades = shared.servo_stats().lateness.counts().by_decade();
    stop_load_threads();
    print_report(args, &summary.stats, || {
        format!(
            "{}\n{}{}",
            summary.stats.table(),
            decade_table(&[("ticks", &decades)]),
            steal::describe(steal.as_ref())
        )
    })
}

/// Prints `report` as JSON (`--json`), or as its text `table` under the run's header line.
fn print_report(
    args: &BenchLoopArgs,
    report: &impl Serialize,
    table: impl FnOnce() -> String,
) -> anyhow::Result<()> {
    if args.json {
        return super::common::print_out(&serde_json::to_string_pretty(report)?);
    }
    super::common::print_out(&format!(
        "bench-loop: simulated arm, built-in 3-mode scene, {} s at {} Hz, {} load threads\n{}",
        args.seconds,
        args.rate,
        args.load_threads,
        table()
    ))
}

/// Longest window of `--baseline`'s alternation (s).
const BASELINE_WINDOW_MAX_S: f64 = 2.0;

/// One side of `--baseline`'s comparison, pooled over its windows.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct WindowsReport {
    /// Ticks run (deadlines waited for).
    pub ticks: u64,
    /// Lateness after the deadline (µs): percentiles of the pooled windows (bucket upper edges), exact maximum.
    pub lateness: HistogramReport,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
    /// Deadlines skipped by them.
    pub skipped_ticks: u64,
    /// The lateness histogram: ticks up to 1 µs late, 1 to 10 µs, 10 to 100 µs, 0.1 to 1 ms, 1 to 10 ms, and
    /// over 10 ms (`HistogramCounts::by_decade`).
    pub lateness_by_decade: [u64; 6],
}

/// The lateness histogram as text: one row of tick counts per decade for each named histogram.
fn decade_table(rows: &[(&str, &[u64; 6])]) -> String {
    let mut text = format!("{:<24}", "lateness histogram");
    for head in DECADE_HEADS {
        text += &format!(" {head:>10}");
    }
    text += "\n";
    for (name, counts) in rows {
        text += &format!("{name:<24}");
        for count in counts.iter() {
            text += &format!(" {count:>10}");
        }
        text += "\n";
    }
    text
}

/// `bench-loop --baseline`: the loop and the empty schedule in alternating windows of one run.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SideBySide {
    /// Pairs of windows (loop, then empty schedule).
    pub pairs: u32,
    /// Length of each window (s).
    pub window_s: f64,
    /// The servo loop on the simulated arm (a new session each window; its start-up ticks included).
    #[serde(rename = "loop")]
    pub servo_loop: WindowsReport,
    /// The same schedule with an empty tick.
    pub baseline: WindowsReport,
    /// What the servo thread was granted of its real-time setup (the empty schedule asks the same).
    #[serde(flatten)]
    pub realtime: RealtimeReport,
    /// Steal time over the whole alternation (`null` where /proc/stat is not readable).
    pub steal: Option<StealReport>,
}

impl SideBySide {
    fn table(&self) -> String {
        let row = |name: &str, w: &WindowsReport| {
            let h = &w.lateness;
            format!(
                "{name:<12} {:>10} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>10} {:>10}\n",
                w.ticks, h.p50_us, h.p99_us, h.p999_us, h.max_us, w.overruns, w.skipped_ticks
            )
        };
        let mut text = format!(
            "{} pairs of {:.2} s windows, alternating: the loop, then the same schedule with an empty tick\n",
            self.pairs, self.window_s
        );
        text += &format!(
            "{:<12} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}\n",
            "lateness us", "ticks", "p50", "p99", "p99.9", "max", "overruns", "skipped"
        );
        text += &row("loop", &self.servo_loop);
        text += &row("empty tick", &self.baseline);
        text += &decade_table(&[
            ("loop (ticks)", &self.servo_loop.lateness_by_decade),
            ("empty tick (ticks)", &self.baseline.lateness_by_decade),
        ]);
        text += &self.realtime.summary();
        text += "\n";
        text += &steal::describe(self.steal.as_ref());
        text
    }
}

/// Runs `--baseline`'s alternation: windows of at most [`BASELINE_WINDOW_MAX_S`] adding up to `--seconds`,
/// each pair a servo session on the simulated arm, then the empty schedule on the same CPU with the same
/// real-time setup, so both meet the same machine (a shared machine's load drifts within seconds).
fn side_by_side(args: &BenchLoopArgs, config: &SessionConfig) -> anyhow::Result<SideBySide> {
    let pairs = (args.seconds / BASELINE_WINDOW_MAX_S)
        .ceil()
        .clamp(1.0, u32::MAX as f64) as u32;
    let window_s = args.seconds / f64::from(pairs);
    let steal_before = steal::sample();
    let empty_lateness = Arc::new(Histogram::new());
    let mut servo_loop = WindowsReport {
        ticks: 0,
        lateness: HistogramReport::default(),
        overruns: 0,
        skipped_ticks: 0,
        lateness_by_decade: [0; 6],
    };
    let mut baseline = servo_loop;
    let mut loop_counts = HistogramCounts::default();
    let mut loop_max_ns = 0u64;
    let mut realtime = None;
    for _ in 0..pairs {
        let session = Session::start(config.clone())?;
        let shared = session.api();
        std::thread::sleep(Duration::from_secs_f64(window_s));
        let summary = session.stop();
        loop_counts.add(&shared.servo_stats().lateness.counts());
        loop_max_ns = loop_max_ns.max(shared.servo_stats().lateness.max_ns());
        servo_loop.ticks += summary.stats.ticks;
        servo_loop.overruns += summary.stats.overruns;
        servo_loop.skipped_ticks += summary.stats.skipped_ticks;
        realtime = Some(summary.stats.realtime);
        let empty = run_empty_schedule(
            args.rate,
            config.spin_ns,
            config.rt,
            config.cpu,
            window_s,
            empty_lateness.clone(),
        )?;
        baseline.ticks += empty.ticks;
        baseline.overruns += empty.overruns;
        baseline.skipped_ticks += empty.skipped_ticks;
    }
    servo_loop.lateness = loop_counts.report(loop_max_ns);
    servo_loop.lateness_by_decade = loop_counts.by_decade();
    baseline.lateness = empty_lateness.report();
    baseline.lateness_by_decade = empty_lateness.counts().by_decade();
    Ok(SideBySide {
        pairs,
        window_s,
        servo_loop,
        baseline,
        realtime: realtime.unwrap_or_default(),
        steal: steal::since(steal_before.as_ref(), realtime.and_then(|r| r.pinned_cpu)),
    })
}
