//! A running servo session: the servo thread, the recorder thread, and the control side that a CLI or a
//! server talks to ([`SessionApi`]).
//!
//! Threads and boundaries (docs/design.md, "Threads"):
//!
//! ```text
//!  control side (any thread, a Mutex among themselves)      servo thread (ServoLoop)      recorder thread
//!    validate, build SceneBundle ── command ring (SPSC) ──▶ apply at tick boundary
//!    drop retired bundles        ◀── retire ring (SPSC) ─── old bundle
//!    snapshot()                  ◀── triple buffer ──────── Snapshot every tick
//!    scene(), slice(): read the control side's SceneSetup (volumes shared through Arc), no servo involvement
//!    stats()                     ◀── atomics ────────────── histograms, counters
//!                                                           TraceSample ── sample ring ──▶ writer
//!    start/stop recording ─────────────────────────── mpsc ────────────────────────────▶
//! ```
//!
//! The servo thread never waits on any of these: a full sample ring is counted, commands are polled, the
//! snapshot buffer is wait-free. A control command returns once the servo thread has applied it (it polls
//! the applied-command counter), or with an error that says why and changes nothing.

use super::control::{trace_meta, Control};
pub use super::control::{SessionShared, APPLY_TIMEOUT, MAX_HAND_TARGET_M};
use super::device::{
    open_device_with_profile, ConnectError, DeviceSpec, OpenError, OpenedDevice, ServoDevice,
};
use super::external_force;
use super::join::join_within;
use super::monitor::{Monitor, MonitorConfig, StopSlot, EVENT_RING};
use super::passivity::{LinkFollower, ObserverLatency, PassivityController};
use super::recorder::{run_recorder, RecorderError, RecorderRequest, SCENE_FRAME_RING};
use super::rt::{self, RtMode, RtRefused};
use super::runner::{LoopIo, LoopTiming, ServoLoop};
use super::schedule::{SpinSleepWaiter, Waiter};
use super::setup::SceneSetup;
use super::stats::ServoStats;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use voxhap_api::slice::{check_request, pick_volume, sample_slice};
use voxhap_api::{
    ControlCommand, ControlError, ControlReply, SceneReport, SessionApi, Slice, SliceRequest,
    Snapshot, StatsReport,
};
use voxhap_device::safety::CouplingCaps;
use voxhap_device::supervisor::{SupervisorConfig, TickClock, TickInput};
use voxhap_record::{TraceError, TraceFormat, TraceSummary};

/// Slowest and fastest servo rates accepted (Hz).
pub const RATE_RANGE_HZ: (f64, f64) = (100.0, 10_000.0);
/// Capacity of the command and retire rings.
pub const COMMAND_RING: usize = 64;
/// Longest [`Session::stop`] waits for the servo thread to stop ticking, zero the force and close the device
/// (the connector thread's share of it is at most `reconnect::CONNECTOR_STOP_BOUND`). Past it the session
/// stops without it and says so in the summary's `recorder_error` (the trace cannot be finished then).
pub const SERVO_STOP_BOUND: Duration = Duration::from_secs(3);

/// How to run a session.
#[derive(Debug, Clone)]
pub struct SessionConfig {
    pub device: DeviceSpec,
    pub setup: SceneSetup,
    /// Servo rate (Hz), 100 ..= 10 000.
    pub rate_hz: f64,
    pub rt: RtMode,
    /// Core to pin the servo thread to (default: the last one).
    pub cpu: Option<usize>,
    /// Record from the first tick.
    pub record: Option<(PathBuf, TraceFormat)>,
    /// What `record` may replace (`--force`) and the run's inputs, which it never may.
    pub record_policy: voxhap_record::OutputPolicy,
    /// The exact solver's time budget, as a fraction of the period.
    pub solver_budget_fraction: f64,
    /// The tick's compute budget (modes + solve), as a fraction of the period; over it, the last safe force
    /// goes out instead.
    pub compute_budget_fraction: f64,
    /// How long before each deadline the servo thread stops sleeping and spins (ns); at most a quarter of
    /// the period is used.
    pub spin_ns: u64,
    /// How long before each deadline the servo thread warms its caches for the coming tick (ns; 0: off); at
    /// most a quarter of the period is used.
    pub warm_lead_ns: u64,
    /// Samples the recorder ring holds (default: 4 s of ticks).
    pub sample_ring: Option<usize>,
    pub supervisor: SupervisorConfig,
    /// The device profile: workspace mapping, limits, kinematics (default: identity, the device's limits).
    pub profile: voxhap_device::profile::DeviceProfile,
    /// Periods without a tick after which the monitor thread stops the device itself.
    pub stall_periods: u32,
    /// The external force input's staleness timeout; `None` (the default) keeps the input off
    /// (crate::external_force).
    pub external_force_timeout: Option<Duration>,
}

impl SessionConfig {
    /// Defaults for `setup` on `device`: 1 kHz, best-effort real time, solver budget 30 % and compute
    /// budget 60 % of the period, 80 µs spin, caches warmed 30 µs before each deadline.
    pub fn new(device: DeviceSpec, setup: SceneSetup) -> Self {
        SessionConfig {
            device,
            rate_hz: setup.rate_hz.unwrap_or(1000.0),
            setup,
            rt: RtMode::BestEffort,
            cpu: None,
            record: None,
            record_policy: voxhap_record::OutputPolicy::default(),
            solver_budget_fraction: 0.3,
            compute_budget_fraction: 0.6,
            spin_ns: 80_000,
            warm_lead_ns: 30_000,
            sample_ring: None,
            supervisor: SupervisorConfig::default(),
            profile: voxhap_device::profile::DeviceProfile::default(),
            stall_periods: 20,
            external_force_timeout: None,
        }
    }
}

/// Why a session did not start.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("--rate {0} Hz is outside {min} ..= {max} Hz", min = RATE_RANGE_HZ.0, max = RATE_RANGE_HZ.1)]
    Rate(f64),
    #[error("scene: {0}")]
    Scene(String),
    /// The cause is part of the message and deliberately not `source()`, so an error chain printed with
    /// `{:#}` names it once.
    #[error("device {spec}: {cause}")]
    Open { spec: String, cause: OpenError },
    #[error("device {spec}: could not connect: {cause}")]
    Connect { spec: String, cause: ConnectError },
    #[error(transparent)]
    Realtime(#[from] RtRefused),
    #[error("record {path}: {source}")]
    Record { path: PathBuf, source: TraceError },
    #[error("could not start a thread: {0}")]
    Thread(std::io::Error),
}

/// What a session did, returned by [`Session::stop`].
#[derive(Debug)]
pub struct SessionSummary {
    pub stats: StatsReport,
    /// The trace that was being recorded at the end, finished.
    pub trace: Option<TraceSummary>,
    /// A recorder failure (disk full, ...), if there was one.
    pub recorder_error: Option<String>,
}

/// A running session. Dropping it stops it (as [`Session::stop`] does, discarding the summary).
pub struct Session {
    shared: Arc<SessionShared>,
    servo: Option<JoinHandle<()>>,
    recorder: Option<JoinHandle<Result<Option<TraceSummary>, TraceError>>>,
    monitor: Option<Monitor>,
    /// The device's stop channel: fired by the session itself when the servo thread outlives
    /// [`SERVO_STOP_BOUND`].
    stop_slot: Arc<StopSlot>,
    /// What `serve` should tell the operator at start (coupling caps applied, ...).
    notices: Vec<String>,
}

impl Session {
    /// Opens the device, builds the scene, starts the recorder and servo threads. Returns once the servo
    /// thread has its real-time settings (or refused to start without them in `strict` mode).
    pub fn start(config: SessionConfig) -> Result<Session, SessionError> {
        let (min, max) = RATE_RANGE_HZ;
        if !(config.rate_hz.is_finite() && (min..=max).contains(&config.rate_hz)) {
            return Err(SessionError::Rate(config.rate_hz));
        }
        let period_s = (1e9 / config.rate_hz).round() * 1e-9;
        let spec_label = config.device.to_string();
        let volume_bounds_m = config
            .setup
            .volumes
            .first()
            .map(|v| v.volume.grid().bounds_world());
        let opened = open_device_with_profile(
            &config.device,
            config.supervisor,
            (config.setup.arm.clone(), config.setup.start_m),
            period_s,
            &config.profile,
            volume_bounds_m,
        )
        .map_err(|cause| SessionError::Open {
            spec: spec_label.clone(),
            cause,
        })?;
        Self::start_opened(config, opened)
    }

    /// [`Session::start`] after the device is opened (tests give a device double here).
    pub(crate) fn start_opened(
        config: SessionConfig,
        opened: OpenedDevice,
    ) -> Result<Session, SessionError> {
        let period_ns = (1e9 / config.rate_hz).round() as u64;
        let period_s = period_ns as f64 * 1e-9;
        let spec_label = config.device.to_string();
        let mut device: Box<dyn ServoDevice> = opened.device;
        let stop_slot = StopSlot::new();
        device.set_stop_slot(stop_slot.clone());
        device.connect(0).map_err(|cause| SessionError::Connect {
            spec: spec_label.clone(),
            cause,
        })?;
        let mut notices = Vec::new();
        notices.extend(device.profile_notes());
        // Hand targets come in scene coordinates; the simulated arm's hand moves in the device frame.
        let hand_mapping = device.workspace_mapping();
        let caps = CouplingCaps::new(device.max_stiffness_n_per_m().unwrap_or(0.0), period_s)
            .with_damping_limit(device.max_damping_n_s_per_m());
        let max_stiffness_n_per_m = caps.max_stiffness_n_per_m;
        let (k, damping) = (
            config.setup.stiffness_n_per_m,
            config.setup.damping_n_s_per_m,
        );
        let (k_capped, damping_capped) = caps.cap(k, damping);
        if k_capped < k {
            notices.push(format!(
                "the scene's stiffness {k} N/m is above what device {spec_label} renders stably at {} Hz; using \
                 {k_capped} N/m (its declared maximum at 1 kHz, scaled to this rate)",
                config.rate_hz
            ));
        }
        if damping_capped < damping {
            notices.push(format!(
                "the scene's damping {damping} N s/m is above the passivity bound for device {spec_label} at \
                 k = {k_capped} N/m; using {damping_capped:.3} N s/m (README, Safety)"
            ));
        }
        let mut setup = config.setup.clone();
        setup.stiffness_n_per_m = k_capped;
        setup.damping_n_s_per_m = damping_capped;
        // One zero-force exchange gives the first probe position; the proxy starts there.
        let first_state = device
            .exchange(TickInput {
                force_n: DVec3::ZERO,
                now_us: 0,
                clock: TickClock::Monotonic,
                on_time: false,
                force_valid: false,
                local: None,
            })
            .state;

        let sample_capacity = config
            .sample_ring
            .unwrap_or((config.rate_hz * 4.0) as usize)
            .max(1024);
        let bundle = setup
            .bundle(period_ns, config.solver_budget_fraction, 1)
            .map_err(|e| SessionError::Scene(e.to_string()))?;
        // The passivity controller: `control` for a real device unless the scene says otherwise. Its observer
        // pairs each force with the motion it meets `d` ticks later: `[passivity] latency_s` when written, else
        // the simulated arm's `[arm] latency_s`, else the driver's worst-case link latency (crate::passivity).
        let simulated_arm = opened.hand_target.is_some();
        let passivity_mode = setup.passivity.mode_for(simulated_arm);
        let latency = ObserverLatency::choose(
            &setup.passivity,
            simulated_arm.then_some(setup.arm.arm.effects.latency_s),
            device.link_latency(),
            period_s,
        );
        notices.extend(latency.notice(passivity_mode, &spec_label, config.rate_hz));
        let passivity = PassivityController::new(passivity_mode, &setup.passivity, latency.ticks);
        // A device rendering local models runs the same mode on its own loop (crate::local_model).
        let local_passivity =
            crate::local_model::passivity_request(passivity_mode, &setup.passivity);
        let link_follower = LinkFollower::new(&latency, Duration::from_nanos(period_ns));
        let (command_tx, command_rx) = rtrb::RingBuffer::new(COMMAND_RING);
        let command_claim = Arc::new(AtomicU64::new(0));
        let (event_tx, event_rx) = rtrb::RingBuffer::new(EVENT_RING);
        let (retire_tx, retire_rx) = rtrb::RingBuffer::new(COMMAND_RING);
        let (sample_tx, sample_rx) = rtrb::RingBuffer::new(sample_capacity);
        let (frame_tx, frame_rx) = rtrb::RingBuffer::new(SCENE_FRAME_RING);
        let (snapshot_in, snapshot_out) = triple_buffer::triple_buffer(&None);
        let stats = Arc::new(ServoStats::new(config.rate_hz));
        stats.link_delay.start(latency.ticks, device.link_latency());
        let (external_sender, external_receiver) = match config.external_force_timeout {
            Some(timeout) => {
                let (sender, receiver) = external_force::channel(timeout, period_ns);
                (Some(sender), Some(receiver))
            }
            None => (None, None),
        };

        // Recorder.
        let (recorder_tx, recorder_rx) = mpsc::channel();
        let recorder_error: RecorderError = Arc::default();
        let mut recording = None;
        if let Some((path, format)) = &config.record {
            let meta = trace_meta(&config.setup, config.rate_hz, &spec_label);
            let writer = voxhap_record::create_trace_writer_with(
                path,
                *format,
                &meta,
                &config.record_policy,
            )
            .map_err(|source| SessionError::Record {
                path: path.clone(),
                source,
            })?;
            let _ = recorder_tx.send(RecorderRequest::Start {
                writer,
                first_tick: 0,
            });
            recording = Some(path.clone());
        }
        let error_slot = recorder_error.clone();
        let recorder_stats = stats.clone();
        let recorder = std::thread::Builder::new()
            .name("voxhap-recorder".to_owned())
            .spawn(move || {
                run_recorder(sample_rx, frame_rx, recorder_rx, error_slot, recorder_stats)
            })
            .map_err(SessionError::Thread)?;

        // Servo thread.
        let stop = Arc::new(AtomicBool::new(false));
        let servo_running = Arc::new(AtomicBool::new(true));
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        let timing = LoopTiming {
            period_ns,
            compute_budget_ns: (period_ns as f64 * config.compute_budget_fraction) as u64,
            warm_lead_ns: capped_busy_wait_ns(config.warm_lead_ns, period_ns),
        };
        let io = LoopIo {
            commands: command_rx,
            command_claim: command_claim.clone(),
            retired: retire_tx,
            samples: sample_tx,
            scene_frames: frame_tx,
            snapshot: snapshot_in,
            events: event_tx,
        };
        let thread_stats = stats.clone();
        let thread_stop = stop.clone();
        let running = servo_running.clone();
        // Spinning (and warming) at most a quarter of the period each: a SCHED_FIFO thread that is busy
        // more than 95 % of a second is throttled by Linux for the rest of it (sched_rt_runtime_us), which
        // at 10 kHz with an 80 µs spin meant a 50 ms stall every second.
        let spin_ns = capped_busy_wait_ns(config.spin_ns, period_ns);
        let (rt_mode, cpu) = (config.rt, config.cpu);
        let servo = std::thread::Builder::new()
            .name("voxhap-servo".to_owned())
            .spawn(move || {
                let granted = rt::apply(rt_mode, cpu);
                let report = match granted {
                    Ok((report, warnings)) => {
                        let _ = ready_tx.send(Ok(warnings));
                        report
                    }
                    Err(refused) => {
                        let mut device = device;
                        device.stop();
                        running.store(false, Ordering::Release);
                        let _ = ready_tx.send(Err(refused));
                        return;
                    }
                };
                thread_stats.set_realtime(report);
                let mut waiter = SpinSleepWaiter::new(spin_ns);
                let origin_ns = waiter.now_ns() + period_ns;
                // The loop's clock starts at 0 again after the set-up since the first exchange above.
                let mut device = device;
                device.restart_clock(0);
                let mut servo = ServoLoop::new(
                    Box::new(bundle),
                    device,
                    io,
                    thread_stats,
                    timing,
                    origin_ns,
                    first_state,
                );
                servo.set_passivity(passivity);
                servo.set_local_passivity(local_passivity);
                servo.set_link_follower(link_follower);
                if let Some(receiver) = external_receiver {
                    servo.set_external_force(receiver);
                }
                servo.run(&mut waiter, &thread_stop);
                running.store(false, Ordering::Release);
            })
            .map_err(SessionError::Thread)?;
        let warnings = match ready_rx.recv() {
            Ok(Ok(warnings)) => warnings,
            Ok(Err(refused)) => {
                let _ = servo.join();
                return Err(SessionError::Realtime(refused));
            }
            Err(_) => Vec::new(),
        };
        for warning in warnings {
            eprintln!("warning: servo thread: {warning}; continuing without it (--rt best-effort)");
        }
        let monitor = Monitor::spawn(
            MonitorConfig {
                period: Duration::from_nanos(period_ns),
                stall_periods: config.stall_periods,
            },
            stats.clone(),
            servo_running.clone(),
            stop_slot.clone(),
            event_rx,
        )
        .map_err(SessionError::Thread)?;
        let simulated = simulated_arm;
        let shared = Arc::new(SessionShared {
            stats,
            snapshot: Mutex::new(snapshot_out),
            control: Mutex::new(Control {
                commands: command_tx,
                claim: command_claim,
                retired: retire_rx,
                sent: 0,
                setup,
                generation: 1,
                recorder: recorder_tx,
                recording,
                recorder_errors_at_start: 0,
                hand: opened.hand_target,
                hand_mapping,
            }),
            hand_target: Mutex::new(None),
            external_force: Mutex::new(external_sender),
            external_force_timeout: config.external_force_timeout,
            stop,
            servo_running,
            device_label: spec_label,
            simulated,
            max_stiffness_n_per_m,
            coupling_caps: caps,
            rate_hz: config.rate_hz,
            period_ns,
            solver_budget_fraction: config.solver_budget_fraction,
            recorder_error,
        });
        Ok(Session {
            shared,
            servo: Some(servo),
            recorder: Some(recorder),
            monitor: Some(monitor),
            stop_slot,
            notices,
        })
    }

    /// What the operator should know about how the session started (coupling caps applied, ...).
    pub fn notices(&self) -> &[String] {
        &self.notices
    }

    /// The shared side, for servers.
    pub fn api(&self) -> Arc<SessionShared> {
        self.shared.clone()
    }

    /// True while the servo thread runs.
    pub fn is_running(&self) -> bool {
        self.shared.servo_running.load(Ordering::Acquire)
    }

    /// Stops the servo (zero force, device disabled and closed), then the recorder (trace flushed and
    /// finished), and returns the statistics. The servo thread is waited for at most [`SERVO_STOP_BOUND`].
    pub fn stop(mut self) -> SessionSummary {
        self.stop_inner()
    }

    fn stop_inner(&mut self) -> SessionSummary {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(monitor) = &self.monitor {
            monitor.note_stopping();
        }
        let mut servo_stuck = false;
        if let Some(servo) = self.servo.take() {
            // A servo thread still inside a device's close after the bound is left behind (its trace
            // cannot be finished: the recorder ends when the servo thread lets go of the sample ring).
            servo_stuck = join_within(servo, SERVO_STOP_BOUND).is_err();
        }
        // After the servo thread: the monitor prints the last device events (the stop's included).
        if let Some(mut monitor) = self.monitor.take() {
            monitor.stop();
        }
        let mut recorder_error = None;
        if servo_stuck {
            // Whatever the monitor did during the wait (its stall stop, once per stall), the device gets zero
            // force and Disable through its stop channel now, from this thread, before the session lets go.
            let stopped = match self.stop_slot.fire() {
                Ok(true) => {
                    "zero force and Disable were sent through the device's stop channel".to_owned()
                }
                Ok(false) => {
                    "this device has no stop channel, so its own watchdog must stop it".to_owned()
                }
                Err(error) => {
                    format!("sending zero force through the device's stop channel failed: {error}")
                }
            };
            self.recorder.take();
            recorder_error = Some(format!(
                "the servo thread did not finish stopping the device within {} s; the session stopped without \
                 it (the trace is not finished); {stopped}",
                SERVO_STOP_BOUND.as_secs()
            ));
        }
        let trace = match self.recorder.take().map(JoinHandle::join) {
            Some(Ok(Ok(trace))) => trace,
            Some(Ok(Err(error))) => {
                recorder_error = Some(error.to_string());
                None
            }
            Some(Err(_)) => {
                recorder_error = Some("the recorder thread panicked".to_owned());
                None
            }
            None => None,
        };
        if recorder_error.is_none() {
            recorder_error = self
                .shared
                .recorder_error
                .lock()
                .ok()
                .and_then(|e| e.clone());
        }
        SessionSummary {
            stats: self.shared.stats.report(),
            trace,
            recorder_error,
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        if self.servo.is_some() {
            self.stop_inner();
        }
    }
}

/// The part of `requested_ns` (a spin or a cache-warming lead) the servo thread may use: at most a quarter of
/// the period, so spinning plus warming keep the thread well under Linux's real-time limit of 95 % of a
/// second (`sched_rt_runtime_us`); past it, the kernel stops the thread for the rest of the second.
pub fn capped_busy_wait_ns(requested_ns: u64, period_ns: u64) -> u64 {
    requested_ns.min(period_ns / 4)
}

impl SessionShared {
    /// The servo's live statistics, histograms included (read-only use: benchmarks copy the lateness
    /// histogram's counts at window edges to compare parts of one session; everyone else wants
    /// [`SessionApi::stats`]).
    pub fn servo_stats(&self) -> &ServoStats {
        &self.stats
    }
}

impl SessionApi for SessionShared {
    fn snapshot(&self) -> Option<Snapshot> {
        let mut snapshot = (*self.snapshot.lock().ok()?.read())?;
        snapshot.hand_target_m = self.hand_target.lock().ok().and_then(|t| *t);
        Some(snapshot)
    }

    fn stats(&self) -> StatsReport {
        self.stats.report()
    }

    fn scene(&self) -> SceneReport {
        let control = match self.control.lock() {
            Ok(control) => control,
            Err(poisoned) => poisoned.into_inner(),
        };
        SceneReport {
            stiffness_n_per_m: control.setup.stiffness_n_per_m,
            damping_n_s_per_m: control.setup.damping_n_s_per_m,
            modes: control.setup.modes.clone(),
            volumes: control.setup.volumes.iter().map(|v| v.report()).collect(),
            device: self.device_label.clone(),
            simulated: self.simulated,
            recording: control.recording.clone(),
            recording_error: self.recorder_error.lock().ok().and_then(|e| e.clone()),
        }
    }

    fn control(&self, command: ControlCommand) -> Result<ControlReply, ControlError> {
        // Not behind the control lock: a stream of forces never waits for a scene being built.
        if let ControlCommand::SetExternalForce { force_n } = command {
            return self.set_external_force(force_n);
        }
        let mut control = match self.control.lock() {
            Ok(control) => control,
            Err(poisoned) => poisoned.into_inner(),
        };
        self.apply(&mut control, command)
    }

    fn slice(&self, request: SliceRequest) -> Result<Slice, ControlError> {
        check_request(&request)?;
        // The control lock (never taken by the servo thread) only long enough to clone the volume's handle;
        // the samples are shared, and sampling runs after it is released.
        let volume = {
            let control = match self.control.lock() {
                Ok(control) => control,
                Err(poisoned) => poisoned.into_inner(),
            };
            pick_volume(&control.setup.volumes, request.volume.as_deref())?.clone()
        };
        let at_m = request
            .at_m
            .or_else(|| self.snapshot().map(|s| s.proxy_m))
            .unwrap_or_else(|| {
                let (min_m, max_m) = volume.volume.grid().bounds_world();
                (min_m + max_m) * 0.5
            });
        sample_slice(&volume, &request, at_m)
    }
}

/// A `--record` path whose directory does not exist.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("directory {} does not exist", .directory.display())]
pub struct MissingRecordDirectory {
    /// The directory the trace would be written in.
    pub directory: PathBuf,
}

/// Checks that `path`'s directory exists (for `--record`, before anything starts).
pub fn check_record_path(path: &Path) -> Result<(), MissingRecordDirectory> {
    match path.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(parent) if !parent.is_dir() => Err(MissingRecordDirectory {
            directory: parent.to_path_buf(),
        }),
        _ => Ok(()),
    }
}

/// A session on the built-in scene with a device double opened by `opener`, through the same reconnecting
/// supervisor serial devices use (the session's tests).
#[cfg(test)]
fn start_on_double<D: voxhap_device::HapticDevice + Send + 'static>(
    opener: impl FnMut() -> Result<D, voxhap_device::DeviceError> + Send + 'static,
) -> Session {
    let device = crate::device::Reconnecting::new(SupervisorConfig::default(), Box::new(opener));
    let opened = OpenedDevice {
        device: Box::new(device.unwrap()),
        hand_target: None,
    };
    let config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
    Session::start_opened(config, opened).unwrap()
}

#[cfg(test)]
#[path = "session_start_tests.rs"]
mod start_tests;

#[cfg(test)]
#[path = "session_stop_tests.rs"]
mod stop_tests;

#[cfg(test)]
mod tests {
    use super::capped_busy_wait_ns;

    #[test]
    fn spin_and_warm_leads_are_capped_at_a_quarter_of_the_period() {
        // 1 kHz: the defaults (80 µs spin, 30 µs warming) pass unchanged.
        assert_eq!(capped_busy_wait_ns(80_000, 1_000_000), 80_000);
        assert_eq!(capped_busy_wait_ns(30_000, 1_000_000), 30_000);
        // 10 kHz: an 80 µs spin would keep the thread busy most of each 100 µs period, past the kernel's
        // real-time limit (it was throttled for 50 ms a second); 25 µs is used.
        assert_eq!(capped_busy_wait_ns(80_000, 100_000), 25_000);
        assert_eq!(capped_busy_wait_ns(0, 100_000), 0);
    }
}
