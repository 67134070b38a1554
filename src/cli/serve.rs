//! `voxhap serve`: run the servo loop on a device until Ctrl-C or SIGTERM (or `--duration`), optionally
//! recording every tick. With no flags it serves the simulated arm exploring the built-in scene.
//!
//! It also starts the Foxglove live view (`crate::server::foxglove`, `--foxglove ADDR`, default
//! ws://127.0.0.1:8765; `--no-foxglove` to leave it out).
//!
//! Shutdown order on a signal: the Foxglove view stops and closes its clients, the servo thread stops ticking and sends zero force, the device is disabled
//! and closed, the recorder drains its ring and finishes the trace, the statistics are printed, exit 0.

use crate::record::TraceFormat;
use crate::servo::device::DeviceSpec;
use crate::servo::rt::RtMode;
use crate::servo::session::check_record_path;
use crate::servo::setup;
use crate::servo::{Session, SessionConfig};
use anyhow::{bail, Context};
use clap::Args;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// sim | mock:PATH | serial:PATH | hid:VID:PID[:SERIAL] | woodenhaptics | haply2diy:PATH | replay:TRACE
    #[arg(long, default_value = "sim", value_parser = parse_device)]
    pub device: DeviceSpec,
    /// A volume file (.nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd, .toml) or builtin:NAME; with --scene it
    /// replaces the scene's first volume, alone it is rendered as a surface at mid-range.
    #[arg(long)]
    pub volume: Option<String>,
    /// Scene file (TOML: k, modes, transfer functions, volumes, simulated arm); any sim scenario works.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Servo rate (Hz), 100 to 10000; default the scene's rate_hz or 1000.
    #[arg(long)]
    pub rate: Option<f64>,
    /// Record every tick to this trace (CSV, or MCAP for a .mcap name) with its JSON sidecar.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Trace format (default: from the file name).
    #[arg(long)]
    pub record_format: Option<TraceFormat>,
    /// Real-time scheduling: strict refuses to start without SCHED_FIFO, locked memory and a pinned core.
    #[arg(long, value_enum, default_value_t = RtMode::BestEffort)]
    pub rt: RtMode,
    /// How long before each deadline the servo thread stops sleeping and spins (µs).
    #[arg(long, default_value_t = 80)]
    pub spin_us: u64,
    /// How long before each deadline the servo thread warms its caches for the coming tick (µs; 0: off).
    #[arg(long, default_value_t = 30)]
    pub warm_us: u64,
    /// CPU to pin the servo thread to (default: the last one).
    #[arg(long)]
    pub cpu: Option<usize>,
    /// Stop after this many seconds (default: run until Ctrl-C or SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
    #[command(flatten)]
    pub foxglove: crate::server::foxglove::FoxgloveArgs,
}

/// `voxhap serve` with no flags (what `voxhap` alone runs).
#[derive(Debug, clap::Parser)]
struct DefaultServe {
    #[command(flatten)]
    args: ServeArgs,
}

impl ServeArgs {
    /// The defaults of every flag.
    pub fn defaults() -> ServeArgs {
        <DefaultServe as clap::Parser>::parse_from(["voxhap-serve"]).args
    }
}

fn parse_device(text: &str) -> Result<DeviceSpec, String> {
    text.parse()
        .map_err(|e: crate::servo::device::DeviceSpecError| e.to_string())
}

/// Builds the session configuration from the flags (loads the scene and volumes).
pub fn session_config(args: &ServeArgs) -> anyhow::Result<SessionConfig> {
    let setup = setup::resolve(args.scene.as_ref(), args.volume.as_deref())?;
    let mut config = SessionConfig::new(args.device.clone(), setup);
    if let Some(rate) = args.rate {
        config.rate_hz = rate;
    }
    config.rt = args.rt;
    config.spin_ns = args.spin_us.saturating_mul(1000);
    config.warm_lead_ns = args.warm_us.saturating_mul(1000);
    config.cpu = args.cpu;
    if let Some(path) = &args.record {
        check_record_path(path).map_err(|e| anyhow::anyhow!("--record {}: {e}", path.display()))?;
        let format = args
            .record_format
            .unwrap_or_else(|| TraceFormat::from_path(path));
        config.record = Some((path.clone(), format));
    }
    Ok(config)
}

/// Waits for Ctrl-C, SIGTERM or `duration`.
pub async fn wait_for_stop(duration: Option<Duration>) -> &'static str {
    let ctrl_c = tokio::signal::ctrl_c();
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
    let terminate = async {
        match term.as_mut() {
            Some(term) => {
                term.recv().await;
            }
            None => std::future::pending::<()>().await,
        }
    };
    let timer = async {
        match duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = ctrl_c => "interrupt",
        () = terminate => "SIGTERM",
        () = timer => "duration reached",
    }
}

pub fn run(args: &ServeArgs) -> anyhow::Result<()> {
    let duration = match args.duration {
        Some(s) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
        Some(s) => bail!("--duration must be a number of seconds > 0, got {s}"),
        None => None,
    };
    let foxglove = args.foxglove.resolve()?;
    let config = session_config(args)?;
    let label = config.setup.label.clone();
    let modes = config.setup.modes.len();
    let rate = config.rate_hz;
    let device = config.device.to_string();
    let record = config.record.clone();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let session = Session::start(config)?;
    super::print_out(&format!(
        "serving: device {device}, scene {label:?} ({modes} modes), {rate} Hz; Ctrl-C or SIGTERM to stop"
    ))?;
    if let Some((path, format)) = &record {
        super::print_out(&format!("recording: {} ({format})", path.display()))?;
    }
    let foxglove = runtime.block_on(crate::server::foxglove::start_for_serve(
        session.api(),
        foxglove,
    ))?;
    if let Some(server) = &foxglove {
        super::print_out(&format!(
            "foxglove: listening on ws://{}",
            server.local_addr()
        ))?;
    }
    let reason = runtime.block_on(wait_for_stop(duration));
    if let Some(server) = foxglove {
        runtime.block_on(server.stop());
    }
    let summary = session.stop();
    super::print_out(&format!("stopped ({reason}): force zeroed, device closed"))?;
    if let Some(trace) = &summary.trace {
        super::print_out(&format!(
            "trace: {} samples in {} (sidecar {})",
            trace.sample_count,
            trace.trace_path.display(),
            trace.sidecar_path.display()
        ))?;
    }
    super::print_out(&summary.stats.table())?;
    if let Some(error) = summary.recorder_error {
        bail!("recording failed: {error}");
    }
    Ok(())
}
