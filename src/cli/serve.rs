//! `voxhap serve`: run the servo loop on a device until Ctrl-C or SIGTERM (or `--duration`), optionally
//! recording every tick. With no flags it serves the simulated arm exploring the built-in scene.
//!
//! The visualiser server (page, REST API, WebSocket stream; [`crate::server`]) runs on the same tokio runtime
//! unless `--no-http`: on 127.0.0.1:8080 by default (a busy default port only warns), with a control token
//! printed at start.
//!
//! It also starts the Foxglove live view ([`crate::server::foxglove`], `--foxglove ADDR`, default
//! ws://127.0.0.1:8765; `--no-foxglove` to leave it out).
//!
//! Shutdown order on a signal: the visualiser server closes its clients (1001) and stops, the Foxglove view
//! stops and closes its clients, the servo thread
//! stops ticking and sends zero force, the device is disabled and closed, the recorder drains its ring and
//! finishes the trace, the statistics are printed, exit 0.

use crate::record::TraceFormat;
use crate::server::{self, HttpArgs, HttpSettings, ServerConfig};
use crate::servo::api::SessionApi;
use crate::servo::device::DeviceSpec;
use crate::servo::rt::RtMode;
use crate::servo::session::check_record_path;
use crate::servo::setup;
use crate::servo::{Session, SessionConfig};
use anyhow::{bail, Context};
use clap::Args;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// sim | mock:PATH | serial:PATH | hid:VID:PID[:SERIAL] | woodenhaptics:PATH | woodenhaptics-hid | haply2diy:PATH | haply-inverse[:ws://HOST:PORT] | replay:TRACE
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
    /// CPU to pin the servo thread to (default: the last one).
    #[arg(long)]
    pub cpu: Option<usize>,
    /// Stop after this many seconds (default: run until Ctrl-C or SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
    #[command(flatten)]
    pub http: HttpArgs,
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

/// Binds the visualiser server's address. A busy default address warns and gives `None`; a busy `--http` is
/// an error.
async fn bind_http(
    settings: HttpSettings,
) -> anyhow::Result<Option<(tokio::net::TcpListener, ServerConfig)>> {
    match tokio::net::TcpListener::bind(settings.addr).await {
        Ok(listener) => Ok(Some((listener, settings.config))),
        Err(error) if error.kind() == std::io::ErrorKind::AddrInUse && !settings.explicit => {
            eprintln!(
                "warning: http: {} is in use; continuing without the visualiser server (choose another address with --http ADDR, or --no-http)",
                settings.addr
            );
            Ok(None)
        }
        Err(error) => Err(anyhow::Error::new(error)
            .context(format!("--http {}: cannot listen there", settings.addr))),
    }
}

fn print_http(addr: SocketAddr, token: &str) -> anyhow::Result<()> {
    super::print_out(&format!("http: listening on http://{addr}"))?;
    super::print_out(&format!("http: control token {token}"))?;
    super::print_out(&format!("http: open http://{addr}/?token={token}"))
}

pub fn run(args: &ServeArgs) -> anyhow::Result<()> {
    let duration = match args.duration {
        Some(s) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
        Some(s) => bail!("--duration must be a number of seconds > 0, got {s}"),
        None => None,
    };
    let http = args.http.resolve()?;
    let foxglove = args.foxglove.resolve()?;
    let mut config = session_config(args)?;
    let label = config.setup.label.clone();
    let modes = config.setup.modes.len();
    let rate = config.rate_hz;
    let device = config.device.to_string();
    let record = config.record.clone();
    // Before any other thread starts: the runtime, recorder and connector inherit this and stay off the
    // servo thread's core.
    let reserved = crate::servo::rt::reserve_servo_cpu(config.rt, config.cpu);
    if let Some((servo, _)) = &reserved {
        config.cpu = Some(*servo);
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let bound = match http {
        Some(settings) => runtime.block_on(bind_http(settings))?,
        None => None,
    };
    let session = Session::start(config)?;
    super::print_out(&format!(
        "serving: device {device}, scene {label:?} ({modes} modes), {rate} Hz; Ctrl-C or SIGTERM to stop"
    ))?;
    if let Some((path, format)) = &record {
        super::print_out(&format!("recording: {} ({format})", path.display()))?;
    }
    if let Some((servo, others)) = &reserved {
        super::print_out(&format!(
            "cpus: servo thread alone on CPU {servo}, other threads on {others:?}"
        ))?;
    }
    let (stop_http, http_stopped) = tokio::sync::oneshot::channel::<()>();
    let mut http_task = None;
    if let Some((listener, server_config)) = bound {
        let addr = listener
            .local_addr()
            .context("the visualiser server's address")?;
        print_http(addr, &server_config.token)?;
        let api: Arc<dyn SessionApi> = session.api();
        let shutdown = async move {
            let _ = http_stopped.await;
        };
        http_task = Some(runtime.spawn(server::run(listener, api, server_config, shutdown)));
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
    // Clients first (close 1001), then the servo: the page sees the server go, not a frozen stream.
    let _ = stop_http.send(());
    if let Some(task) = http_task {
        let finished = runtime.block_on(async {
            tokio::time::timeout(server::SHUTDOWN_GRACE + Duration::from_secs(1), task).await
        });
        if let Ok(Ok(Err(error))) = finished {
            eprintln!("warning: http: the visualiser server stopped with an error: {error}");
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(addr: SocketAddr, explicit: bool) -> HttpSettings {
        HttpSettings {
            addr,
            explicit,
            config: ServerConfig {
                token: "test-token".to_owned(),
                max_clients: 4,
                idle_timeout: server::config::DEFAULT_IDLE_TIMEOUT,
            },
        }
    }

    #[test]
    fn a_busy_default_port_warns_and_a_busy_explicit_one_fails() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = taken.local_addr().unwrap();
        let quiet = runtime.block_on(bind_http(settings(addr, false))).unwrap();
        assert!(quiet.is_none(), "the default address only warns");
        let error = runtime
            .block_on(bind_http(settings(addr, true)))
            .unwrap_err();
        assert!(
            format!("{error:#}").contains("cannot listen there"),
            "{error:#}"
        );
        drop(taken);
        let bound = runtime.block_on(bind_http(settings(addr, true))).unwrap();
        assert!(bound.is_some());
    }
}
