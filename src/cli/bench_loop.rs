//! `voxhap bench-loop`: runs the servo loop on the simulated arm with the built-in three-mode scene for a
//! while and prints the lateness and compute histograms and the overrun count (the servo issue's benchmark).
//! `--load-threads N` adds N busy threads (at normal priority) to measure under load.

use crate::servo::device::DeviceSpec;
use crate::servo::rt::RtMode;
use crate::servo::setup::SceneSetup;
use crate::servo::{Session, SessionConfig};
use anyhow::bail;
use clap::Args;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Args)]
pub struct BenchLoopArgs {
    /// How long to run (s), > 0 and <= 1e9.
    #[arg(long, default_value_t = 10.0, value_parser = super::parse_seconds)]
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
    let session = Session::start(config)?;
    std::thread::sleep(Duration::from_secs_f64(args.seconds));
    let summary = session.stop();
    stop_load.store(true, Ordering::Relaxed);
    for thread in load {
        let _ = thread.join();
    }
    if args.json {
        super::print_out(&serde_json::to_string_pretty(&summary.stats)?)
    } else {
        super::print_out(&format!(
            "bench-loop: simulated arm, built-in 3-mode scene, {} s at {} Hz, {} load threads\n{}",
            args.seconds,
            args.rate,
            args.load_threads,
            summary.stats.table()
        ))
    }
}
