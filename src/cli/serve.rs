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
//! With `--igtl [ADDR]` it also runs the OpenIGTLink server for 3D Slicer ([`crate::server::igtl`], default
//! 127.0.0.1:18944), which takes the same control token (printed as `igtl: control token T`, also with
//! `--no-http`).
//!
//! With `--ros2` it also publishes the CRTK topics over ROS 2 (DDS; [`super::ros2_output`], docs/ros2.md) from a
//! thread of its own, reading the same snapshots.
//!
//! Shutdown order on a signal: the visualiser server closes its clients (1001) and stops, the Foxglove view
//! and the OpenIGTLink server stop and close their clients, the ROS 2 output leaves its domain, the servo thread
//! stops ticking and sends zero force, the device is disabled and closed, the recorder drains its ring and
//! finishes the trace, the statistics are printed, exit 0.

use crate::api::folders::{ConfinedVolumes, RecordDir, VolumeDirs};
use crate::api::SessionApi;
use crate::device::profile::{DeviceProfile, MappingChoice};
use crate::record::TraceFormat;
use crate::server::{self, HttpArgs, HttpSettings, ServerConfig};
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
    /// sim | mock:PATH | serial:PATH | hid:VID:PID[:SERIAL] | woodenhaptics:PATH | woodenhaptics-hid | haply2diy:PATH | haply-inverse[:ws://HOST:PORT[,events=ws://HOST:PORT]] | falcon[:SERIAL|:PATH][,firmware=FILE] | replay:TRACE[,seek=S][,speed=X][,loop]
    #[arg(long, default_value = "sim")]
    pub device: DeviceSpec,
    /// A volume file (.nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd, .toml) or builtin:NAME; with --scene it
    /// replaces the scene's first volume (which is then not loaded); alone, a scalar volume is rendered as a
    /// surface at --iso or at Otsu's threshold of its values (`voxhap info` prints it), a vector volume is
    /// followed (vector_follow).
    #[arg(long)]
    pub volume: Option<String>,
    /// The value where a lone --volume's surface starts (0 N there, 2 N at 5 % of the value range above);
    /// default: Otsu's threshold of the volume's values.
    #[arg(
        long,
        requires = "volume",
        conflicts_with = "scene",
        allow_negative_numbers = true
    )]
    pub iso: Option<f64>,
    /// Scene file (TOML: k, modes, transfer functions, volumes, simulated arm); any sim scenario works.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Servo rate (Hz), 100 to 10000; default the scene's rate_hz or 1000.
    #[arg(long)]
    pub rate: Option<f64>,
    /// Record every tick to this trace (CSV, MCAP for a .mcap name, Parquet for .parquet) with its JSON sidecar.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Trace format (default: from the file name).
    #[arg(long, value_parser = super::common::trace_format_parser())]
    pub record_format: Option<TraceFormat>,
    /// Replace an existing --record trace (never an input of the run: the scene, a volume, a replayed
    /// trace).
    #[arg(long)]
    pub force: bool,
    /// Real-time scheduling: strict refuses to start without SCHED_FIFO, locked memory and a pinned core.
    #[arg(long, value_enum, default_value_t = RtMode::BestEffort)]
    pub rt: RtMode,
    /// How long before each deadline the servo thread stops sleeping and spins (µs).
    #[arg(long, default_value_t = 80)]
    pub spin_us: u64,
    /// CPU to pin the servo thread to (default: the last one).
    #[arg(long)]
    pub cpu: Option<usize>,
    /// How long connecting to the device may take in all, in seconds, 0.1 to 600: for a voxhap-protocol
    /// device, the DeviceInfo answering Hello (Hello sent again after 0.1, 0.2, 0.4, 0.8 s, then every
    /// second) and the State answering the first zero force; for the Haply Inverse3, the whole connect to the
    /// service; on every reconnect too. A port where nothing answers fails `serve` after this long; a missing
    /// port fails at once.
    #[arg(long, value_name = "SECONDS", default_value_t = 3.0, value_parser = parse_connect_timeout)]
    pub connect_timeout: f64,
    /// Stop after this many seconds, > 0 and <= 1e9 (default: run until Ctrl-C or SIGTERM).
    #[arg(long, value_parser = super::common::parse_seconds)]
    pub duration: Option<f64>,
    /// A folder the control API may load volume files from (`POST /api/volume`, `load_volume`); repeat for
    /// more. Without it the API loads only builtin:NAME volumes.
    #[arg(long, value_name = "DIR")]
    pub volume_dir: Vec<PathBuf>,
    /// The folder the control API may record traces into (`POST /api/record/start`, `start_recording`),
    /// which then names a plain file name in it. Without it the API cannot start a recording (--record
    /// still records from the start).
    #[arg(long, value_name = "DIR")]
    pub record_dir: Option<PathBuf>,
    #[command(flatten)]
    pub limits: super::common::VolumeLimitArgs,
    /// Device profile: a built-in name (sim, haply-inverse, haply2diy, woodenhaptics, woodenhaptics-hid,
    /// falcon) or a TOML file: workspace mapping, limits that only lower the device's, velocity filter,
    /// kinematics constants (docs/workspace.md). Replaces the scene's [device] table. Default: the scene's
    /// [device] table, else the device's built-in profile (a real device) or the identity (sim, replay).
    #[arg(long, value_name = "NAME|FILE")]
    pub device_profile: Option<String>,
    /// Map the device's declared workspace onto the first volume's bounds: centre on centre, the smallest
    /// uniform scale at which the whole volume is reachable, the profile's rotation kept (docs/workspace.md).
    /// A real device (not sim or replay) whose profile gives no [mapping] gets this automatically when the
    /// volume is out of reach.
    #[arg(long, conflicts_with = "no_fit_volume")]
    pub fit_volume: bool,
    /// Never fit the volume automatically: a real device keeps its profile's mapping even when the volume is
    /// out of reach.
    #[arg(long)]
    pub no_fit_volume: bool,
    /// Exit with code 3 after a clean stop when any of these occurred: uncertified (some tick's bound
    /// above the solver tolerance, or a baseline solver), disconnect, device-error, overrun, active (the
    /// energy ledger's net generated energy rose by more than 0.1 mJ over some window), oscillation (a
    /// contact limit cycle). beyond-bound applies to `sim` only. Comma-separated.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub fail_on: Vec<super::sim::FailOn>,
    /// Accept an external force (the control API's set_external_force, the Python package, and with --ros2
    /// the /voxhap/servo_cf topic) added to the rendered force before the safety pipeline (docs/safety.md).
    #[arg(long)]
    pub external_force: bool,
    /// With --external-force: how long, in seconds (0.001 to 5), an external force is applied after it
    /// arrives; then it is zero unless a newer one came.
    #[arg(long, value_name = "SECONDS", default_value_t = 0.1, requires = "external_force",
          value_parser = parse_external_force_timeout)]
    pub external_force_timeout: f64,
    #[command(flatten)]
    pub http: HttpArgs,
    #[command(flatten)]
    pub foxglove: crate::server::foxglove::FoxgloveArgs,
    #[command(flatten)]
    pub igtl: crate::server::igtl::IgtlArgs,
    #[command(flatten)]
    pub ros2: super::ros2_output::Ros2Args,
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

/// A number of seconds from `min` to `max`.
fn seconds_in(text: &str, (min, max): (f64, f64)) -> Result<f64, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if seconds.is_finite() && (min..=max).contains(&seconds) {
        Ok(seconds)
    } else {
        Err(format!("{text} s is outside {min} ..= {max} s"))
    }
}

fn parse_connect_timeout(text: &str) -> Result<f64, String> {
    let (min_us, max_us) = crate::device::supervisor::CONNECT_TIMEOUT_RANGE_US;
    seconds_in(text, (min_us as f64 * 1e-6, max_us as f64 * 1e-6))
}

fn parse_external_force_timeout(text: &str) -> Result<f64, String> {
    seconds_in(text, crate::servo::external_force::TIMEOUT_RANGE_S)
}

/// Builds the session configuration from the flags (loads the scene and volumes).
pub fn session_config(args: &ServeArgs) -> anyhow::Result<SessionConfig> {
    args.limits.apply();
    let setup = setup::resolve(args.scene.as_ref(), args.volume.as_deref(), args.iso)?;
    let mut config = SessionConfig::new(args.device.clone(), setup);
    if let Some(rate) = args.rate {
        config.rate_hz = rate;
    }
    config.rt = args.rt;
    // Range-checked when parsed (parse_connect_timeout); SupervisorConfig::validate checks it again.
    config.supervisor.connect_timeout_us = (args.connect_timeout * 1e6).round() as u64;
    config.spin_ns = args.spin_us.saturating_mul(1000);
    config.cpu = args.cpu;
    config.profile = device_profile(args)?;
    if args.external_force {
        // Range-checked when parsed (parse_external_force_timeout).
        config.external_force_timeout = Some(Duration::from_secs_f64(args.external_force_timeout));
    }
    if let Some(path) = &args.record {
        check_record_path(path).map_err(|e| anyhow::anyhow!("--record {}: {e}", path.display()))?;
        let format = args
            .record_format
            .unwrap_or_else(|| TraceFormat::from_path(path));
        let mut inputs: Vec<PathBuf> = args.scene.iter().cloned().collect();
        inputs.extend(args.volume.iter().map(PathBuf::from));
        inputs.extend(
            config
                .setup
                .volumes
                .iter()
                .map(|v| PathBuf::from(&v.source)),
        );
        if let DeviceSpec::Replay { path: trace, .. } = &args.device {
            inputs.push(trace.clone());
        }
        config.record_policy = crate::record::OutputPolicy {
            overwrite: args.force,
            inputs,
        };
        crate::record::check_output_path(path, &config.record_policy)
            .map_err(|e| anyhow::anyhow!("--record: {e}"))?;
        config.record = Some((path.clone(), format));
    }
    Ok(config)
}

/// True for a physical device (its workspace is a real box the volume must fit in): everything but the
/// simulated arm and trace replay, which keep the identity unless told otherwise.
fn is_real_device(spec: &DeviceSpec) -> bool {
    !matches!(spec, DeviceSpec::Sim | DeviceSpec::Replay { .. })
}

/// The device profile from `--device-profile`, else the scene's `[device]` table, else the device's default
/// (its built-in profile for a real device); with `--fit-volume` its mapping becomes the fit (its rotation
/// kept). A real device whose profile gives no `[mapping]` of its own is fitted when the volume is out of
/// reach, unless `--no-fit-volume`.
pub fn device_profile(args: &ServeArgs) -> anyhow::Result<DeviceProfile> {
    let family = crate::servo::device::spec_family(&args.device);
    let default_profile = || -> anyhow::Result<DeviceProfile> {
        Ok(if is_real_device(&args.device) {
            DeviceProfile::default_for(&family)?
        } else {
            DeviceProfile::default()
        })
    };
    let mut profile = match (&args.device_profile, &args.scene) {
        (Some(given), _) => DeviceProfile::resolve(given)?,
        (None, Some(scene)) => {
            let text = crate::volume::io::read_text_file(scene)
                .map_err(|e| anyhow::anyhow!("{}: {e}", scene.display()))?;
            let table: toml::Table = text
                .parse()
                .map_err(|e| anyhow::anyhow!("{}: {e}", scene.display()))?;
            match table.get("device") {
                Some(toml::Value::Table(device)) => DeviceProfile::from_table(
                    device.clone(),
                    &format!("{} [device]", scene.display()),
                )?,
                Some(_) => anyhow::bail!("{}: device must be a table ([device])", scene.display()),
                None => default_profile()?,
            }
        }
        (None, None) => default_profile()?,
    };
    if is_real_device(&args.device) && !profile.mapping_given && !args.no_fit_volume {
        profile.fit_when_out_of_reach();
    }
    if args.fit_volume {
        let rotation = match profile.mapping {
            MappingChoice::Fixed(mapping) | MappingChoice::FitWhenOutOfReach(mapping) => {
                mapping.rotation()
            }
            MappingChoice::FitVolume { rotation } => rotation,
        };
        profile.mapping = MappingChoice::FitVolume { rotation };
    }
    Ok(profile)
}

/// The signals that stop `serve` cleanly (zero force, Disable, trace finished, exit 0): SIGINT (Ctrl-C),
/// SIGTERM, SIGHUP (the terminal closed), SIGQUIT and SIGUSR1. Their handlers are installed before the device is
/// opened, so none of them can kill the process with force on the arm.
pub struct StopSignals {
    interrupt: tokio::signal::unix::Signal,
    others: Vec<(tokio::signal::unix::Signal, &'static str)>,
}

impl StopSignals {
    /// Installs the handlers (inside a tokio runtime).
    pub fn install() -> anyhow::Result<StopSignals> {
        use tokio::signal::unix::{signal, SignalKind};
        let mut others = Vec::new();
        for (kind, name) in [
            (SignalKind::terminate(), "SIGTERM"),
            (SignalKind::hangup(), "SIGHUP"),
            (SignalKind::quit(), "SIGQUIT"),
            (SignalKind::user_defined1(), "SIGUSR1"),
        ] {
            others.push((
                signal(kind).with_context(|| format!("installing the {name} handler"))?,
                name,
            ));
        }
        Ok(StopSignals {
            interrupt: signal(SignalKind::interrupt()).context("installing the SIGINT handler")?,
            others,
        })
    }

    /// Waits for any stop signal or `duration`; says which.
    pub async fn wait(&mut self, duration: Option<Duration>) -> &'static str {
        let timer = async {
            match duration {
                Some(d) => tokio::time::sleep(d).await,
                None => std::future::pending::<()>().await,
            }
        };
        let others =
            futures_util::future::select_all(self.others.iter_mut().map(|(signal, name)| {
                Box::pin(async move {
                    signal.recv().await;
                    *name
                })
            }));
        tokio::select! {
            _ = self.interrupt.recv() => "interrupt",
            (name, _, _) = others => name,
            () = timer => "duration reached",
        }
    }

    /// Waits for a second SIGINT (which shortens the stop; the force is still zeroed).
    pub async fn second_interrupt(&mut self) {
        self.interrupt.recv().await;
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
    super::common::print_out(&format!("http: listening on http://{addr}"))?;
    super::common::print_out(&format!("http: control token {token}"))?;
    super::common::print_out(&format!("http: open http://{addr}/?token={token}"))
}

pub fn run(args: &ServeArgs) -> anyhow::Result<()> {
    // Range-checked when parsed (super::common::parse_seconds), so the conversion cannot overflow.
    let duration = args.duration.map(Duration::from_secs_f64);
    let http = args.http.resolve()?;
    let foxglove = args.foxglove.resolve()?;
    let volume_dirs = VolumeDirs::new(&args.volume_dir).map_err(anyhow::Error::msg)?;
    let record_dir = RecordDir::new(args.record_dir.as_deref()).map_err(anyhow::Error::msg)?;
    let igtl = args.igtl.resolve()?;
    let ros2 = super::ros2_output::resolve(&args.ros2)?;
    // The OpenIGTLink server takes the HTTP server's control token; with --no-http, --token (checked by
    // the same rules) or a random one.
    let igtl_token = match (&igtl, &http) {
        (None, _) => None,
        (Some(_), Some(settings)) => Some(settings.config.token.clone()),
        (Some(_), None) => {
            let mut flags = args.http.clone();
            flags.no_http = false;
            flags.resolve()?.map(|settings| settings.config.token)
        }
    };
    let mut config = session_config(args)?;
    let label = config.setup.label.clone();
    let modes = config.setup.modes.len();
    let config_tolerance_m = config.setup.solver.tolerance_m;
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
    let mut signals = runtime.block_on(async { StopSignals::install() })?;
    let bound = match http {
        Some(settings) => runtime.block_on(bind_http(settings))?,
        None => None,
    };
    let connect_timeout = args.connect_timeout;
    let session = Session::start(config).map_err(|error| {
        let timed_out = matches!(&error, crate::servo::session::SessionError::Connect { cause, .. }
            if cause.kind == crate::device::ErrorKind::Timeout);
        if timed_out {
            anyhow::anyhow!(
                "{error}; a device that needs longer to answer (a bootloader, a slow adapter) can be given more \
                 with --connect-timeout SECONDS (now {connect_timeout} s)"
            )
        } else {
            anyhow::Error::new(error)
        }
    })?;
    for notice in session.notices() {
        eprintln!("notice: {notice}");
    }
    super::common::print_out(&format!(
        "serving: device {device}, scene {label:?} ({modes} modes), {rate} Hz; Ctrl-C or SIGTERM to stop"
    ))?;
    if let Some((path, format)) = &record {
        super::common::print_out(&format!("recording: {} ({format})", path.display()))?;
    }
    if args.external_force {
        super::common::print_out(&format!(
            "external force: accepted (set_external_force{}), added before the safety pipeline, zero {} s after the last one",
            if super::ros2_output::enabled(&args.ros2) { ", /voxhap/servo_cf" } else { "" },
            args.external_force_timeout
        ))?;
    }
    if let Some((servo, others)) = &reserved {
        super::common::print_out(&format!(
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
        // load_volume commands through the API may only name files in the --volume-dir folders, and
        // start_recording commands only a file name in the --record-dir folder.
        let api: Arc<dyn SessionApi> =
            Arc::new(ConfinedVolumes::new(session.api(), volume_dirs).with_record_dir(record_dir));
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
        super::common::print_out(&format!(
            "foxglove: listening on ws://{}",
            server.local_addr()
        ))?;
    }
    let igtl = match (igtl, igtl_token) {
        (Some(config), Some(token)) => {
            let server = runtime.block_on(crate::server::igtl::IgtlServer::start(
                session.api(),
                &config,
                token.clone(),
            ))?;
            super::common::print_out(&format!(
                "igtl: listening on {} (OpenIGTLink, {} Hz)",
                server.local_addr(),
                config.rate_hz
            ))?;
            super::common::print_out(&format!("igtl: control token {token}"))?;
            Some(server)
        }
        _ => None,
    };
    let ros2 = super::ros2_output::start(ros2, rate, &session, args.external_force)?;
    let reason = runtime.block_on(signals.wait(duration));
    // Clients first (close 1001), then the servo: the page sees the server go, not a frozen stream. A second
    // Ctrl-C skips the wait for the clients; the servo still zeroes the force and disables the device.
    let _ = stop_http.send(());
    let shortened = runtime.block_on(async {
        let clients = async {
            if let Some(task) = http_task {
                let finished =
                    tokio::time::timeout(server::SHUTDOWN_GRACE + Duration::from_secs(1), task)
                        .await;
                if let Ok(Ok(Err(error))) = finished {
                    eprintln!(
                        "warning: http: the visualiser server stopped with an error: {error}"
                    );
                }
            }
            if let Some(server) = foxglove {
                server.stop().await;
            }
            if let Some(server) = igtl {
                server.stop().await;
            }
        };
        tokio::select! {
            () = clients => false,
            () = signals.second_interrupt() => true,
        }
    });
    if shortened {
        eprintln!("second interrupt: stopping now (force zeroed, device disabled)");
    }
    if let Some(output) = ros2 {
        super::ros2_output::stop(output)?;
    }
    let tolerance_m = config_tolerance_m;
    let summary = session.stop();
    super::common::print_out(&format!("stopped ({reason}): force zeroed, device closed"))?;
    if let Some(trace) = &summary.trace {
        super::common::print_out(&format!(
            "trace: {} samples in {} (sidecar {})",
            trace.sample_count,
            trace.trace_path.display(),
            trace.sidecar_path.display()
        ))?;
    }
    super::common::print_out(&summary.stats.table())?;
    if let Some(error) = summary.recorder_error {
        bail!("recording failed: {error}");
    }
    let findings = serve_fail_on_findings(&args.fail_on, &summary.stats, tolerance_m);
    if !findings.is_empty() {
        return Err(super::sim::fail_on_exit(format!(
            "--fail-on: {}",
            findings.join("; ")
        )));
    }
    Ok(())
}

/// What `--fail-on` found in a finished session's statistics.
fn serve_fail_on_findings(
    fail_on: &[super::sim::FailOn],
    stats: &crate::api::StatsReport,
    tolerance_m: f64,
) -> Vec<String> {
    use super::sim::FailOn;
    let mut found = Vec::new();
    for condition in fail_on {
        match condition {
            FailOn::Uncertified if stats.worst_error_bound_m.is_nan() || stats.worst_error_bound_m > tolerance_m => found.push(format!(
                "uncertified: the worst certificate bound {:.3e} m is above the tolerance {tolerance_m:.1e} m",
                stats.worst_error_bound_m
            )),
            FailOn::Disconnect if stats.disconnects > 0 => {
                found.push(format!("disconnect: {} device disconnects", stats.disconnects))
            }
            FailOn::DeviceError if stats.device_errors > 0 => {
                found.push(format!("device-error: {} device errors", stats.device_errors))
            }
            FailOn::Overrun if stats.overruns > 0 => {
                found.push(format!("overrun: {} ticks started late", stats.overruns))
            }
            FailOn::Active | FailOn::Oscillation => {
                found.extend(super::sim::energy_finding(*condition, &stats.energy))
            }
            _ => {}
        }
    }
    found
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
                header_timeout: server::config::DEFAULT_HEADER_TIMEOUT,
                allowed_hosts: Vec::new(),
                allowed_origins: Vec::new(),
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

    /// `serve --fail-on active` and `--fail-on oscillation` read the energy ledger's verdicts in the
    /// statistics, as `sim` does, and say what they found; without the verdicts they find nothing.
    #[test]
    fn fail_on_active_and_oscillation_read_the_energy_ledger() {
        use super::super::sim::FailOn;
        use crate::api::{EnergyReport, StatsReport};
        let both = [FailOn::Active, FailOn::Oscillation];
        let quiet = StatsReport::default();
        assert!(serve_fail_on_findings(&both, &quiet, 1e-12).is_empty());
        let loud = StatsReport {
            energy: EnergyReport {
                largest_rise_j: 2.5e-3,
                contacts: 41,
                longest_cycle_run: 40,
                active: true,
                oscillating: true,
                ..EnergyReport::default()
            },
            ..StatsReport::default()
        };
        let found = serve_fail_on_findings(&both, &loud, 1e-12);
        assert_eq!(found.len(), 2, "{found:?}");
        assert!(
            found[0].starts_with("active: ") && found[0].contains("2.500 mJ"),
            "{found:?}"
        );
        assert!(
            found[1].starts_with("oscillation: 40 undecaying"),
            "{found:?}"
        );
        assert!(serve_fail_on_findings(&[FailOn::Overrun], &loud, 1e-12).is_empty());
    }
}
