//! `voxhap mock-device`: the simulated arm behind voxhap's device protocol on a pseudo-terminal, with fault
//! injection (crates/device/src/mock.rs). Prints the path it serves on, then runs until killed or `--duration` ends.

use crate::device::mock::{
    default_arm_config, run_mock_logged, FaultConfig, LocalModelConfig, MockEvent, ServeOn,
};
use crate::device::sim::SimArmConfig;
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

/// Arguments of `voxhap mock-device`.
#[derive(Debug, Args)]
pub struct MockDeviceArgs {
    /// Serve on a fresh pseudo-terminal and print its path (the default).
    #[arg(long, conflicts_with = "port")]
    pub pty: bool,
    /// Serve on a pseudo-terminal linked from PATH (a symbolic link, replaced on reconnect).
    #[arg(long, value_name = "PATH")]
    pub port: Option<PathBuf>,
    /// Simulated arm scenario: a TOML file with [arm], [hand] and [path] tables (default: a 2 cm circle).
    #[arg(long, value_name = "FILE")]
    pub arm: Option<PathBuf>,
    /// Probability that each byte, sent or received, gets one bit flipped.
    #[arg(long, default_value_t = 0.0, value_name = "RATE")]
    pub corrupt_rate: f64,
    /// Probability that each outgoing frame is dropped.
    #[arg(long, default_value_t = 0.0, value_name = "RATE")]
    pub drop_rate: f64,
    /// Delay added to every outgoing frame, milliseconds.
    #[arg(long, default_value_t = 0.0, value_name = "MS")]
    pub latency_ms: f64,
    /// Stop answering after this many seconds (the device keeps running, the watchdog still acts).
    #[arg(long, value_name = "S")]
    pub stop_after: Option<f64>,
    /// Close the pseudo-terminal after this many seconds.
    #[arg(long, value_name = "S")]
    pub disconnect_after: Option<f64>,
    /// After a disconnect, come back on a new pseudo-terminal this many seconds later (else exit).
    #[arg(long, value_name = "S", requires = "disconnect_after")]
    pub reconnect_after: Option<f64>,
    /// Exit after this many seconds.
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
    /// Seed of the fault generator.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Offer the local-model capability (protocol/SPEC.md section 10): take LocalModel messages and solve the
    /// proxy on the device with its own loop (docs/local-model.md).
    #[arg(long)]
    pub local_model: bool,
    /// Rate of the device's control loop (and local loop) with --local-model, Hz (100 to 20000).
    #[arg(
        long,
        default_value_t = 10_000,
        value_name = "HZ",
        requires = "local_model"
    )]
    pub local_rate_hz: u32,
    /// With --local-model, write the device's own log here: one CSV line per control cycle (time, mode, force,
    /// limit, model sequence, age and expiry, local status, ramp, the local proxy).
    #[arg(long, value_name = "FILE", requires = "local_model")]
    pub log: Option<PathBuf>,
    /// Write the handle's log here (a new file): one CSV line per control cycle with the handle's position
    /// and the force held on it, from which the energy the device absorbed is summed.
    #[arg(long, value_name = "FILE")]
    pub handle_log: Option<PathBuf>,
}

fn seconds_to_us(name: &str, seconds: Option<f64>) -> anyhow::Result<Option<u64>> {
    match seconds {
        None => Ok(None),
        Some(s) if (0.0..1e9).contains(&s) => Ok(Some((s * 1e6) as u64)),
        Some(s) => anyhow::bail!("--{name} {s}: must be a finite number of seconds >= 0"),
    }
}

/// Runs the mock device.
pub fn run(args: &MockDeviceArgs) -> anyhow::Result<()> {
    let arm: SimArmConfig = match &args.arm {
        None => default_arm_config(),
        Some(path) => {
            let text = crate::volume::io::read_text_file(path)
                .with_context(|| format!("reading the arm scenario {}", path.display()))?;
            toml::from_str(&text)
                .with_context(|| format!("parsing the arm scenario {}", path.display()))?
        }
    };
    let latency_us = seconds_to_us("latency-ms", Some(args.latency_ms / 1000.0))?.unwrap_or(0);
    let faults = FaultConfig {
        corrupt_rate: args.corrupt_rate,
        drop_rate: args.drop_rate,
        latency_us,
        stop_after_us: seconds_to_us("stop-after", args.stop_after)?,
        disconnect_after_us: seconds_to_us("disconnect-after", args.disconnect_after)?,
        down_for_us: seconds_to_us("reconnect-after", args.reconnect_after)?,
        seed: args.seed,
    };
    let serve = match &args.port {
        Some(path) => ServeOn::Link(path.clone()),
        None => ServeOn::Pty,
    };
    let duration_us = seconds_to_us("duration", args.duration)?;
    let shutdown = AtomicBool::new(false);
    let mut on_event = |event: MockEvent| {
        // Events go to stdout line by line (tests and scripts read them); a closed pipe is ignored.
        let line = match event {
            MockEvent::Serving(path) => format!("serving {path}"),
            MockEvent::WatchdogTripped(t_us) => {
                format!("watchdog tripped at {:.3} s", t_us as f64 * 1e-6)
            }
            MockEvent::StoppedAnswering => "stopped answering".to_string(),
            MockEvent::Disconnected => "disconnected".to_string(),
        };
        let _ = super::common::print_out(&line);
    };
    let local = args.local_model.then(|| LocalModelConfig {
        rate_hz: args.local_rate_hz,
        log: args.log.clone(),
    });
    let stats = run_mock_logged(
        arm,
        faults,
        &serve,
        duration_us,
        local.as_ref(),
        args.handle_log.as_deref(),
        &shutdown,
        &mut on_event,
    )?;
    super::common::print_out(&format!(
        "done: {} ticks, {} frames received ({} dropped by the decoder), {} sent, {} dropped and {} bytes corrupted \
         by fault injection, {} watchdog trips, {} not sent (nobody reading)",
        stats.ticks,
        stats.frames_ok,
        stats.frames_dropped,
        stats.frames_sent,
        stats.frames_dropped_injected,
        stats.bytes_corrupted,
        stats.watchdog_trips,
        stats.frames_unsent
    ))
}
