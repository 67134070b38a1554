//! The mock device: the simulated arm ([`SimArm`]) behind voxhap's real device protocol on a pseudo-terminal,
//! with fault injection. `voxhap mock-device` runs it as a separate process, so the host's serial driver, safety
//! pipeline and reconnection are tested against a real peer over a real tty.
//!
//! Where it sits: on the device side of the wire (the role firmware plays). A 1 kHz control loop steps the arm
//! with the force the protocol crate's [`DeviceSession`] says to apply (zero unless enabled, dropped by the
//! device watchdog when the host stops sending), and the session answers each SetForce with a State as soon as it
//! arrives (lockstep), so the round trip measures the link and not the control period.
//!
//! Faults, all driven by a seeded generator so runs repeat: each byte sent or received is corrupted (one bit
//! flipped) with probability `corrupt_rate`; each outgoing frame is dropped with probability `drop_rate`;
//! outgoing frames are delayed by `latency_us`; after `stop_after_us` the device keeps running but sends nothing;
//! after `disconnect_after_us` the pseudo-terminal is closed (the host sees a hang-up), and after `down_for_us` a
//! new one is opened and the link path re-pointed to it.

use crate::sim::{
    ArmParams, DeviceEffects, HandParams, HandPath, SimArm, SimArmConfig, SimError, Workspace,
    DEFAULT_SUBSTEPS_PER_TICK, DEFAULT_WALL_DAMPING_N_S_PER_M, DEFAULT_WALL_STIFFNESS_N_PER_M,
};
use glam::DVec3;
use serialport::{SerialPort, TTYPort};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::{
    encode_frame, DeviceInfo, DeviceSample, DeviceSession, DriveState, FrameDecoder, HostToDevice,
    Label, RateSet, MAX_WIRE_FRAME_LEN, PROTOCOL_VERSION,
};

/// Fault injection settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultConfig {
    /// Probability that a byte (either direction) gets one bit flipped, 0..=1.
    pub corrupt_rate: f64,
    /// Probability that an outgoing frame is dropped, 0..=1.
    pub drop_rate: f64,
    /// Delay added to every outgoing frame (µs).
    pub latency_us: u64,
    /// Stop answering (send nothing) after this time (µs).
    pub stop_after_us: Option<u64>,
    /// Close the pseudo-terminal after this time (µs).
    pub disconnect_after_us: Option<u64>,
    /// Come back on a new pseudo-terminal this long after a disconnect (µs); `None` ends the run instead.
    pub down_for_us: Option<u64>,
    /// Seed of the fault generator.
    pub seed: u64,
}

impl Default for FaultConfig {
    fn default() -> Self {
        FaultConfig {
            corrupt_rate: 0.0,
            drop_rate: 0.0,
            latency_us: 0,
            stop_after_us: None,
            disconnect_after_us: None,
            down_for_us: None,
            seed: 1,
        }
    }
}

/// Why the mock device could not run.
#[derive(Debug, thiserror::Error)]
pub enum MockError {
    /// A fault setting is out of range.
    #[error("mock device: {0}")]
    Config(String),
    /// The simulated arm's configuration is invalid.
    #[error("mock device: {0}")]
    Arm(#[from] SimError),
    /// No pseudo-terminal could be opened.
    #[error("mock device: cannot open a pseudo-terminal: {0}")]
    Pty(String),
    /// The link path could not be made.
    #[error("mock device: cannot link {path} to the pseudo-terminal")]
    Link {
        /// The path asked for.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The device log could not be written.
    #[error("mock device: cannot write the device log {path}")]
    Log {
        /// The log's path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Reading or writing the pseudo-terminal failed.
    #[error("mock device: pseudo-terminal I/O failed while {during}")]
    Io {
        /// What the mock was doing.
        during: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
}

/// What the mock reports while it runs.
#[derive(Debug, Clone, PartialEq)]
pub enum MockEvent {
    /// Serving on this path (the pseudo-terminal, or the link to it).
    Serving(String),
    /// The device watchdog dropped the force to zero at this device time (µs).
    WatchdogTripped(u64),
    /// The fault injector stopped all answers.
    StoppedAnswering,
    /// The pseudo-terminal was closed.
    Disconnected,
}

/// Counters of a mock run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MockStats {
    /// Messages received intact.
    pub frames_ok: u64,
    /// Frames dropped by the decoder (CRC, COBS, ...).
    pub frames_dropped: u64,
    /// Frames sent.
    pub frames_sent: u64,
    /// Frames dropped by fault injection.
    pub frames_dropped_injected: u64,
    /// Frames not (or not wholly) sent because the terminal's buffer stayed full: nobody was reading, as a UART
    /// with no host on the other end (a streaming device keeps sending after its host died).
    pub frames_unsent: u64,
    /// Bytes corrupted by fault injection.
    pub bytes_corrupted: u64,
    /// Device watchdog trips.
    pub watchdog_trips: u64,
    /// Control ticks run.
    pub ticks: u64,
}

/// Where the mock serves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServeOn {
    /// A fresh pseudo-terminal; its path is reported in [`MockEvent::Serving`].
    Pty,
    /// A fresh pseudo-terminal with a symbolic link at this path (replaced on reconnect).
    Link(PathBuf),
}

/// The device info the mock announces.
pub fn mock_device_info() -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("voxhap-mock").unwrap_or_default(),
        serial_number: Label::new("sim-0001").unwrap_or_default(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[100, 200, 250, 500, 1000]).unwrap_or_default(),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 2000.0,
    }
}

/// The default arm: a hand moving the handle round a 2 cm circle every 4 s.
pub fn default_arm_config() -> SimArmConfig {
    SimArmConfig {
        arm: ArmParams {
            mass_kg: 0.1,
            damping_n_s_per_m: 1.0,
            workspace: Workspace::Unbounded,
            // What an `[arm]` table that leaves these keys out gets (checked in the tests below).
            substeps_per_tick: DEFAULT_SUBSTEPS_PER_TICK,
            wall_stiffness_n_per_m: DEFAULT_WALL_STIFFNESS_N_PER_M,
            wall_damping_n_s_per_m: DEFAULT_WALL_DAMPING_N_S_PER_M,
            effects: DeviceEffects::default(),
        },
        hand: HandParams {
            stiffness_n_per_m: 200.0,
            damping_n_s_per_m: 2.0,
        },
        path: HandPath::Circle {
            center_m: DVec3::ZERO,
            radius_m: 0.02,
            normal: DVec3::Z,
            period_s: 4.0,
        },
        local_model: None,
    }
}

/// SplitMix64: a small, seedable generator for fault injection.
#[derive(Debug, Clone)]
struct Faults {
    state: u64,
}

impl Faults {
    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn chance(&mut self, probability: f64) -> bool {
        probability > 0.0 && ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64) < probability
    }

    fn corrupt(&mut self, bytes: &mut [u8], rate: f64) -> u64 {
        let mut count = 0;
        if rate > 0.0 {
            for byte in bytes {
                if self.chance(rate) {
                    *byte ^= 1 << (self.next_u64() % 8);
                    count += 1;
                }
            }
        }
        count
    }
}

struct Pty {
    master: TTYPort,
    _slave: TTYPort,
}

fn open_pty(serve: &ServeOn) -> Result<(Pty, String), MockError> {
    let (master, slave) = TTYPort::pair().map_err(|error| MockError::Pty(error.to_string()))?;
    let pty_path = slave
        .name()
        .ok_or_else(|| MockError::Pty("the pseudo-terminal has no path".to_string()))?;
    let shown = match serve {
        ServeOn::Pty => pty_path,
        ServeOn::Link(link) => {
            remove_link(link)?;
            std::os::unix::fs::symlink(&pty_path, link).map_err(|source| MockError::Link {
                path: link.clone(),
                source,
            })?;
            link.display().to_string()
        }
    };
    Ok((
        Pty {
            master,
            _slave: slave,
        },
        shown,
    ))
}

/// Removes `link` if it is a symbolic link; refuses to remove anything else.
fn remove_link(link: &Path) -> Result<(), MockError> {
    match std::fs::symlink_metadata(link) {
        Ok(meta) if meta.file_type().is_symlink() => {
            std::fs::remove_file(link).map_err(|source| MockError::Link {
                path: link.to_path_buf(),
                source,
            })
        }
        Ok(_) => Err(MockError::Link {
            path: link.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "exists and is not a symbolic link; not replacing it",
            ),
        }),
        Err(_) => Ok(()),
    }
}

/// The device's own log (one CSV line per control cycle), buffered; flushed at the end of the run.
struct DeviceLog {
    out: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
}

impl DeviceLog {
    fn create(path: &Path, header: &str) -> Result<Self, MockError> {
        // A new file only: an existing one is never replaced.
        let file = std::fs::File::options()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|source| MockError::Log {
                path: path.to_path_buf(),
                source,
            })?;
        let mut log = DeviceLog {
            out: std::io::BufWriter::with_capacity(1 << 16, file),
            path: path.to_path_buf(),
        };
        log.line(format_args!("{header}"))?;
        Ok(log)
    }

    fn line(&mut self, args: std::fmt::Arguments) -> Result<(), MockError> {
        writeln!(self.out, "{args}").map_err(|source| MockError::Log {
            path: self.path.clone(),
            source,
        })
    }

    fn cycle(
        &mut self,
        now_us: u64,
        session: &DeviceSession,
        local: &LocalLoop,
        force: [f32; 3],
    ) -> Result<(), MockError> {
        let magnitude = force
            .iter()
            .map(|f| f64::from(*f).powi(2))
            .sum::<f64>()
            .sqrt();
        let max_n = f64::from(session.info().max_force_n);
        let enabled = session.drive_state() == DriveState::Enabled;
        // `off` first: whatever the session holds, a drive that is not Enabled must apply zero force.
        let (mode, limit, sequence, age, expiry) = match session.local_model() {
            _ if !enabled => ("off", max_n, 0, 0, 0),
            Some((model, at_us)) => (
                "local",
                model.force_limit_n().min(max_n),
                model.sequence,
                now_us.saturating_sub(at_us),
                model.expiry_us,
            ),
            None => ("set_force", max_n, 0, 0, 0),
        };
        let status = local.last_status().0;
        let ramp = local.ramp_factor();
        // Shortest round-trip form: a reader gets the loop's f64 proxy back exactly.
        let [x, y, z] = local
            .proxy_m()
            .map_or([String::new(), String::new(), String::new()], |p| {
                p.map(|c| format!("{c:e}"))
            });
        // The passivity observer's books since the loop started (SPEC 10.5 step 4b).
        let passivity = local.passivity_totals();
        let (generated, dissipated) = (passivity.generated_j, passivity.dissipated_j);
        self.line(format_args!(
            "{now_us},{mode},{magnitude:.9},{limit:.9},{sequence},{age},{expiry},{status},{ramp:.6},{x},{y},{z},\
             {generated:e},{dissipated:e}"
        ))
    }

    /// One control cycle of the handle: its position as the cycle starts and the force held over it.
    fn handle(&mut self, now_us: u64, position_m: DVec3, force_n: DVec3) -> Result<(), MockError> {
        let (p, f) = (position_m, force_n);
        self.line(format_args!(
            "{now_us},{:.12},{:.12},{:.12},{:.9},{:.9},{:.9}",
            p.x, p.y, p.z, f.x, f.y, f.z
        ))
    }

    fn flush(&mut self) -> Result<(), MockError> {
        self.out.flush().map_err(|source| MockError::Log {
            path: self.path.clone(),
            source,
        })
    }
}

fn to_f32(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// The arm's current state as the session's sample (the mock has no buttons).
fn arm_sample(arm: &SimArm) -> DeviceSample {
    DeviceSample {
        position_m: to_f32(arm.position_m()),
        velocity_m_per_s: to_f32(arm.velocity_m_per_s()),
        buttons: 0,
    }
}

/// One control cycle of the arm from `now_us` under `force` (N), held for `tick_us`; the handle log (when
/// kept) gets the cycle's line first.
fn step_arm(
    arm: &mut SimArm,
    handle_log: Option<&mut DeviceLog>,
    now_us: u64,
    tick_us: u64,
    force: [f32; 3],
) -> Result<(), MockError> {
    let force_n = DVec3::from(force.map(f64::from));
    if let Some(log) = handle_log {
        log.handle(now_us, arm.position_m(), force_n)?;
    }
    arm.step(now_us as f64 * 1e-6, tick_us as f64 * 1e-6, force_n)?;
    Ok(())
}

/// The local-model capability of the mock (protocol/SPEC.md section 10): its loop rate and its log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LocalModelConfig {
    /// Control (and local loop) rate, Hz: 100..=20000.
    pub rate_hz: u32,
    /// Where to write the device's log: one line per control cycle (see [`LOCAL_LOG_HEADER`]).
    pub log: Option<PathBuf>,
}

impl Default for LocalModelConfig {
    fn default() -> Self {
        Self {
            rate_hz: 10_000,
            log: None,
        }
    }
}

/// The columns of the mock's device log: device time (µs), mode (`off`: the drive is not Enabled; else `local`:
/// rendering a local model, or `set_force`), the applied force's magnitude (N), the force limit in force (N: the model's limit capped by the
/// device's maximum, or the maximum), the model's sequence and age (µs, 0 without a model), its expiry (µs), the
/// local status bits, the ramp factor, the local loop's proxy (m, device frame; empty before its first
/// solve), and its passivity observer's generated energy and its controller's dissipated energy since the loop
/// started (J; both 0 while the models' passivity mode is `off`).
pub const LOCAL_LOG_HEADER: &str =
    "t_us,mode,force_n,limit_n,model_sequence,model_age_us,expiry_us,\
     local_status,ramp,proxy_x_m,proxy_y_m,proxy_z_m,passivity_generated_j,passivity_dissipated_j";

/// The columns of the mock's handle log (`voxhap mock-device --handle-log`): device time (µs), the handle's
/// position as the control cycle starts (m) and the force held on it over the cycle (N), one line per cycle.
/// The arm integrates each cycle exactly under that force, so the work the host's force did on the handle
/// over a cycle is the force times the step to the next line's position: the energy the device absorbed.
pub const HANDLE_LOG_HEADER: &str = "t_us,x_m,y_m,z_m,fx_n,fy_n,fz_n";

/// Runs the mock device until `shutdown` is set, `duration_us` has passed, or it disconnects for good.
pub fn run_mock(
    arm_config: SimArmConfig,
    faults: FaultConfig,
    serve: &ServeOn,
    duration_us: Option<u64>,
    shutdown: &AtomicBool,
    on_event: &mut dyn FnMut(MockEvent),
) -> Result<MockStats, MockError> {
    run_mock_logged(
        arm_config,
        faults,
        serve,
        duration_us,
        None,
        None,
        shutdown,
        on_event,
    )
}

/// [`run_mock`] with the local-model capability when `local` is given: the device sets `LOCAL_MODEL`, takes
/// LocalModel messages and renders them with `voxhap-local`'s loop at `local.rate_hz` (the arm steps at that
/// rate too); SetForce works as before. With `handle_log`, writes the handle log ([`HANDLE_LOG_HEADER`]) there
/// (a new file only).
#[allow(clippy::too_many_arguments)]
pub fn run_mock_logged(
    arm_config: SimArmConfig,
    faults: FaultConfig,
    serve: &ServeOn,
    duration_us: Option<u64>,
    local: Option<&LocalModelConfig>,
    handle_log: Option<&Path>,
    shutdown: &AtomicBool,
    on_event: &mut dyn FnMut(MockEvent),
) -> Result<MockStats, MockError> {
    for (name, rate) in [
        ("corrupt rate", faults.corrupt_rate),
        ("drop rate", faults.drop_rate),
    ] {
        if !(0.0..=1.0).contains(&rate) {
            return Err(MockError::Config(format!(
                "{name} {rate} must be between 0 and 1"
            )));
        }
    }
    if let Some(local) = local {
        if !(100..=20_000).contains(&local.rate_hz) {
            return Err(MockError::Config(format!(
                "local loop rate {} Hz must be between 100 and 20000",
                local.rate_hz
            )));
        }
    }
    let tick_us: u64 = local.map_or(1_000, |l| 1_000_000 / u64::from(l.rate_hz));
    let new_session = || match local {
        Some(_) => DeviceSession::with_local_model(mock_device_info()),
        None => DeviceSession::new(mock_device_info()),
    };
    let mut log = match local.and_then(|l| l.log.as_ref()) {
        Some(path) => Some(DeviceLog::create(path, LOCAL_LOG_HEADER)?),
        None => None,
    };
    let mut handle_log = match handle_log {
        Some(path) => Some(DeviceLog::create(path, HANDLE_LOG_HEADER)?),
        None => None,
    };
    let mut local_loop = LocalLoop::new(LoopConfig {
        period_us: tick_us as u32,
        ..LoopConfig::default()
    });
    let mut arm = SimArm::new(arm_config, DVec3::ZERO)?;
    let mut session = new_session();
    let mut decoder = FrameDecoder::<HostToDevice>::new();
    let mut rng = Faults { state: faults.seed };
    let mut stats = MockStats::default();
    let mut delayed: VecDeque<(u64, [u8; MAX_WIRE_FRAME_LEN], usize)> = VecDeque::new();
    let (mut pty, shown) = open_pty(serve)?;
    on_event(MockEvent::Serving(shown));
    let start = Instant::now();
    let now_us = || u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX);
    let mut next_tick_us = tick_us;
    let mut stopped = false;
    let mut disconnected_at: Option<u64> = None;
    let mut buffer = [0u8; 1024];

    while !shutdown.load(Ordering::Relaxed) {
        let now = now_us();
        if duration_us.is_some_and(|limit| now >= limit) {
            break;
        }
        if let Some(at) = faults.disconnect_after_us {
            if disconnected_at.is_none() && now >= at {
                disconnected_at = Some(now);
                if let ServeOn::Link(link) = serve {
                    remove_link(link)?;
                }
                let (fresh, shown) = match faults.down_for_us {
                    None => {
                        on_event(MockEvent::Disconnected);
                        break;
                    }
                    Some(down_for_us) => {
                        // Close the old terminal (the host sees a hang-up), wait, come back on a new one.
                        drop(pty);
                        on_event(MockEvent::Disconnected);
                        std::thread::sleep(Duration::from_micros(down_for_us));
                        open_pty(serve)?
                    }
                };
                pty = fresh;
                session = new_session();
                decoder.reset();
                delayed.clear();
                on_event(MockEvent::Serving(shown));
                next_tick_us = now_us() + tick_us;
                continue;
            }
        }
        if !stopped && faults.stop_after_us.is_some_and(|at| now >= at) {
            stopped = true;
            on_event(MockEvent::StoppedAnswering);
        }

        let mut wait_us = next_tick_us.saturating_sub(now);
        if let Some((release_us, _, _)) = delayed.front() {
            wait_us = wait_us.min(release_us.saturating_sub(now));
        }
        pty.master
            .set_timeout(Duration::from_micros(wait_us))
            .map_err(|error| MockError::Pty(error.to_string()))?;
        let received = match pty.master.read(&mut buffer) {
            Ok(n) => n,
            Err(error) if error.kind() == std::io::ErrorKind::TimedOut => 0,
            Err(error) if error.kind() == std::io::ErrorKind::Interrupted => 0,
            Err(source) => {
                return Err(MockError::Io {
                    during: "reading",
                    source,
                })
            }
        };
        let now = now_us();
        if received > 0 {
            stats.bytes_corrupted += rng.corrupt(&mut buffer[..received], faults.corrupt_rate);
            for &byte in &buffer[..received] {
                if let Some(Ok(message)) = decoder.push(byte) {
                    session.on_message(&message, now);
                }
            }
            // Answer at once (lockstep): the control loop's sample is the arm's current state.
            session.poll(now, &arm_sample(&arm));
        }
        if now >= next_tick_us {
            let trips = session.stats().watchdog_trips;
            if local.is_some() {
                // The local loop: force from the current sample (the session's SetForce force when no model),
                // then the arm moves under it for one period.
                let force = local_loop.step(&mut session, now, &arm_sample(&arm));
                if let Some(log) = log.as_mut() {
                    log.cycle(now, &session, &local_loop, force)?;
                }
                step_arm(&mut arm, handle_log.as_mut(), now, tick_us, force)?;
            } else {
                step_arm(
                    &mut arm,
                    handle_log.as_mut(),
                    now,
                    tick_us,
                    session.force_n(),
                )?;
                session.poll(now, &arm_sample(&arm));
            }
            if session.stats().watchdog_trips > trips {
                on_event(MockEvent::WatchdogTripped(now));
            }
            stats.ticks += 1;
            // Never a burst of catch-up ticks: skip ahead when behind.
            next_tick_us = if now - next_tick_us >= tick_us {
                now + tick_us
            } else {
                next_tick_us + tick_us
            };
        }
        while let Some(reply) = session.poll_transmit() {
            if stopped || rng.chance(faults.drop_rate) {
                stats.frames_dropped_injected += 1;
                continue;
            }
            let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
            let Ok(len) = encode_frame(&reply, &mut frame) else {
                continue;
            };
            stats.bytes_corrupted += rng.corrupt(&mut frame[..len], faults.corrupt_rate);
            delayed.push_back((now + faults.latency_us, frame, len));
        }
        while delayed
            .front()
            .is_some_and(|(release_us, _, _)| *release_us <= now)
        {
            if let Some((_, frame, len)) = delayed.pop_front() {
                match pty.master.write_all(&frame[..len]) {
                    Ok(()) => stats.frames_sent += 1,
                    // The terminal's buffer is full and stays so for the read timeout: nobody reads. A UART
                    // drops such bytes; so does the mock (a partial frame is ended by the next delimiter).
                    Err(error)
                        if matches!(
                            error.kind(),
                            std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                        ) =>
                    {
                        stats.frames_unsent += 1;
                    }
                    Err(source) => {
                        return Err(MockError::Io {
                            during: "writing",
                            source,
                        })
                    }
                }
            }
        }
    }
    let decoded = decoder.stats();
    stats.frames_ok = decoded.frames_ok;
    stats.frames_dropped = decoded.dropped();
    stats.watchdog_trips = session.stats().watchdog_trips;
    if let Some(log) = log.as_mut() {
        log.flush()?;
    }
    if let Some(log) = handle_log.as_mut() {
        log.flush()?;
    }
    if let ServeOn::Link(link) = serve {
        let _ = remove_link(link);
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_arm_and_info_are_valid() {
        SimArm::new(default_arm_config(), DVec3::ZERO).unwrap();
        let info = mock_device_info();
        assert_eq!(info.model.as_str(), "voxhap-mock");
        assert!(info.supported_rates.contains_hz(1000));
    }

    /// The built-in arm leaves every optional `[arm]` key as a scene table that omits it has it: written out,
    /// its `[arm]` cut to the mass, damping and workspace, it reads back as the same arm.
    #[test]
    fn built_in_arm_has_the_arm_tables_defaults() {
        let arm = default_arm_config();
        let mut table: toml::Table = toml::from_str(&toml::to_string(&arm).unwrap()).unwrap();
        let given = ["mass_kg", "damping_n_s_per_m", "workspace"];
        let arm_table = table
            .get_mut("arm")
            .and_then(toml::Value::as_table_mut)
            .unwrap();
        arm_table.retain(|key, _| given.contains(&key));
        assert_eq!(arm_table.len(), given.len());
        let read: SimArmConfig = toml::from_str(&toml::to_string(&table).unwrap()).unwrap();
        assert_eq!(read, arm);
    }

    #[test]
    fn fault_generator_hits_its_rate() {
        let mut faults = Faults { state: 7 };
        let hits = (0..100_000).filter(|_| faults.chance(0.1)).count();
        assert!((9_000..11_000).contains(&hits), "{hits}");
        assert!(!(0..1000).any(|_| faults.chance(0.0)));
    }
}
