//! The device end of the servo loop: which device `--device` names, how it is opened, and the one object
//! ([`ServoDevice`]) the servo thread talks to, whatever the device is.
//!
//! Every device runs inside a [`Supervisor`] (lifecycle, safety pipeline, reconnection; see
//! `device::supervisor`), so the safety pipeline is applied to every force of every device, the simulated
//! arm included. [`ServoDevice`] erases the driver type so the servo thread holds one `Box<dyn
//! ServoDevice>`.
//!
//! The in-process simulated arm ([`SimDevice`]) is the default device: a [`SimArm`] stepped one servo period
//! per force written, its virtual hand following a scripted path, or, when a client sets one through the
//! session, a hand target (a triple buffer, so setting it never blocks the servo thread).

use super::monitor::StopSlot;
use crate::device::drivers::falcon::{Falcon, FalconConfig};
use crate::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use crate::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use crate::device::drivers::protocol::{HidLink, ProtocolConfig, ProtocolDevice, SerialLink};
use crate::device::drivers::replay::ReplayDevice;
use crate::device::drivers::woodenhaptics::{self, WoodenHaptics, WoodenHapticsConfig};
use crate::device::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig};
use crate::device::plausibility::InputCounters;
use crate::device::sim::{SimArm, SimArmConfig, SimError};
use crate::device::supervisor::{
    ClearFaultOutcome, OutputState, Supervisor, SupervisorConfig, SupervisorConfigError,
    SupervisorCounters, TickInput, TickOutput,
};
use crate::device::transport::{HidTransport, SerialTransport};
use crate::device::Lifecycle;
use crate::device::{DeviceError, DeviceInfo, DeviceState, ErrorKind, HapticDevice};
use glam::DVec3;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Why a device could not be connected: the kind, and the driver's own words (with the OS reason).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct ConnectError {
    /// The kind of failure.
    pub kind: ErrorKind,
    /// What the driver said.
    pub message: String,
}

impl ConnectError {
    fn from_error<E: crate::device::Error>(error: &E) -> ConnectError {
        ConnectError {
            kind: error.kind(),
            message: error.to_string(),
        }
    }
}

/// The device as the servo thread sees it: one exchange per tick, plus a few queries.
pub trait ServoDevice: Send {
    /// Makes the tick's force safe, sends it and reads the answering state (see [`Supervisor::tick`]).
    fn exchange(&mut self, input: TickInput) -> TickOutput;
    /// The supervisor's counters.
    fn counters(&self) -> SupervisorCounters;
    /// The input checks' counters.
    fn input_counters(&self) -> InputCounters;
    /// True once the safety pipeline passes forces at full strength.
    fn engaged(&self) -> bool;
    /// Where the output stands.
    fn output_state(&self) -> OutputState;
    /// The operator's `clear_fault` (ClearFault goes out on the next tick).
    fn request_clear_fault(&mut self) -> ClearFaultOutcome;
    /// Zero force, disable, close.
    fn stop(&mut self);
    /// Opens the device now (before the loop starts), so a missing device fails `serve` at once.
    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError>;
    /// The device's capabilities, while connected.
    fn info(&self) -> Option<DeviceInfo>;
    /// The servo period (µs), for the slew limit.
    fn set_period_us(&mut self, period_us: u64);
    /// Where the stall monitor finds the device's stop channel, and the flag it raises after using it.
    fn set_stop_slot(&mut self, slot: Arc<StopSlot>);
    /// The connected device's declared maximum stiffness at 1 kHz (N/m), without allocating.
    fn max_stiffness_n_per_m(&self) -> Option<f64>;
}

impl<D, F> ServoDevice for Supervisor<D, F>
where
    D: HapticDevice + Send,
    F: FnMut() -> Result<D, DeviceError> + Send,
{
    fn exchange(&mut self, input: TickInput) -> TickOutput {
        self.tick(input)
    }

    fn counters(&self) -> SupervisorCounters {
        Supervisor::counters(self)
    }

    fn input_counters(&self) -> InputCounters {
        Supervisor::input_counters(self)
    }

    fn engaged(&self) -> bool {
        self.safety().is_engaged()
    }

    fn output_state(&self) -> OutputState {
        Supervisor::output_state(self)
    }

    fn request_clear_fault(&mut self) -> ClearFaultOutcome {
        Supervisor::request_clear_fault(self)
    }

    fn stop(&mut self) {
        Supervisor::stop(self);
    }

    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError> {
        Supervisor::connect(self, now_us).map_err(|kind| ConnectError {
            kind,
            message: format!("could not open the device ({kind:?})"),
        })
    }

    fn info(&self) -> Option<DeviceInfo> {
        self.device().map(|d| d.info().clone())
    }

    fn set_period_us(&mut self, period_us: u64) {
        Supervisor::set_period_us(self, period_us);
    }

    fn set_stop_slot(&mut self, slot: Arc<StopSlot>) {
        if let Some(device) = self.device() {
            slot.install(device.emergency_stop());
        }
        self.set_stall_flag(slot.tripped_flag());
    }

    fn max_stiffness_n_per_m(&self) -> Option<f64> {
        self.device().map(|d| d.info().max_stiffness_n_per_m)
    }
}

/// How a device is (re)opened: called off the servo thread only.
type Opener<D> = Box<dyn FnMut() -> Result<D, DeviceError> + Send>;

fn no_opener<D>() -> Result<D, DeviceError> {
    Err(DeviceError::Config {
        what: "reconnection happens on the connector thread".to_owned(),
    })
}

/// Opens a device (handshake included) without enabling it: the supervisor enables it once the servo loop
/// runs steadily.
fn open_only<D: HapticDevice>(opener: &Mutex<Opener<D>>) -> Result<Lifecycle<D>, ConnectError> {
    let mut opener = opener.lock().map_err(|_| ConnectError {
        kind: ErrorKind::Other,
        message: "the device opener panicked earlier".to_owned(),
    })?;
    let mut device = Lifecycle::new((*opener)().map_err(|e| ConnectError::from_error(&e))?);
    device.open().map_err(|e| ConnectError::from_error(&e))?;
    Ok(device)
}

/// How often an opened device that waits to be handed to the servo thread is kept alive (SPEC: heartbeat
/// while the host is not streaming).
const KEEP_ALIVE_INTERVAL: Duration = Duration::from_millis(100);

/// A supervised device whose reconnection runs on its own thread, so the servo thread never blocks on a
/// port open or a handshake and never frees the lost device's buffers: when the link is lost, the servo
/// hands the dead device to the connector thread (a ring) and raises a flag; the connector closes it (zero
/// and Disable once more), reopens every `reconnect_interval_us`, keeps the opened device alive with
/// heartbeats until the servo asks for it, installs its stop channel for the stall monitor, and hands it back
/// (another ring); the next tick attaches it, and the supervisor enables it once the loop runs steadily.
pub struct Reconnecting<D: HapticDevice + Send + 'static> {
    supervisor: Supervisor<D, fn() -> Result<D, DeviceError>>,
    opener: Arc<Mutex<Opener<D>>>,
    opened: rtrb::Consumer<Lifecycle<D>>,
    lost: rtrb::Producer<Lifecycle<D>>,
    lost_slot: Option<Lifecycle<D>>,
    wanted: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    stop_slot: SharedStopSlot,
    thread: Option<JoinHandle<()>>,
}

impl<D: HapticDevice + Send + 'static> Reconnecting<D> {
    /// A supervised device opened by `opener`; starts the connector thread.
    pub fn new(config: SupervisorConfig, opener: Opener<D>) -> Result<Self, OpenError> {
        let mut supervisor: Supervisor<D, fn() -> Result<D, DeviceError>> =
            Supervisor::new(config, no_opener::<D> as fn() -> Result<D, DeviceError>)?;
        supervisor.set_auto_reconnect(false);
        let opener = Arc::new(Mutex::new(opener));
        let (opened_tx, opened) = rtrb::RingBuffer::new(1);
        let (lost, lost_rx) = rtrb::RingBuffer::new(4);
        let wanted = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let stop_slot: SharedStopSlot = Arc::default();
        let interval = Duration::from_micros(config.reconnect_interval_us.max(1000));
        let thread = {
            let connector = Connector {
                opener: opener.clone(),
                opened: opened_tx,
                lost: lost_rx,
                wanted: wanted.clone(),
                stop: stop.clone(),
                stop_slot: stop_slot.clone(),
                interval,
            };
            std::thread::Builder::new()
                .name("voxhap-connector".to_owned())
                .spawn(move || connector.run())
                .map_err(|e| OpenError::Thread(e.to_string()))?
        };
        Ok(Reconnecting {
            supervisor,
            opener,
            opened,
            lost,
            lost_slot: None,
            wanted,
            stop,
            stop_slot,
            thread: Some(thread),
        })
    }

    fn stop_connector(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

struct Connector<D: HapticDevice> {
    opener: Arc<Mutex<Opener<D>>>,
    opened: rtrb::Producer<Lifecycle<D>>,
    lost: rtrb::Consumer<Lifecycle<D>>,
    wanted: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    stop_slot: SharedStopSlot,
    interval: Duration,
}

/// The stop slot a [`Reconnecting`] device shares with its connector, once the session has given one.
type SharedStopSlot = Arc<Mutex<Option<Arc<StopSlot>>>>;

/// Installs `handle` (a device's stop channel, or `None`) in the session's stop slot, if there is one yet.
fn install_stop(shared: &SharedStopSlot, handle: Option<Box<dyn crate::device::EmergencyStop>>) {
    if let Ok(slot) = shared.lock() {
        if let Some(slot) = slot.as_ref() {
            slot.install(handle);
        }
    }
}

impl<D: HapticDevice + Send> Connector<D> {
    fn run(mut self) {
        let mut ready: Option<Lifecycle<D>> = None;
        let mut last_keep_alive = Instant::now();
        while !self.stop.load(Ordering::Acquire) {
            // Close dead devices first (zero and Disable once more): a serial port is opened exclusively, so
            // the old handle must go.
            while let Ok(mut dead) = self.lost.pop() {
                // The stop channel holds a second handle of the port: release it too, or the port stays
                // busy (serial ports are opened exclusively) and cannot be reopened.
                install_stop(&self.stop_slot, None);
                let _ = dead.close();
            }
            if ready.is_none() && self.wanted.load(Ordering::Acquire) {
                match open_only(&self.opener) {
                    Ok(device) => {
                        ready = Some(device);
                        last_keep_alive = Instant::now();
                    }
                    Err(_) => std::thread::sleep(self.interval),
                }
            }
            if let Some(mut device) = ready.take() {
                if self.wanted.load(Ordering::Acquire) && self.opened.slots() > 0 {
                    install_stop(&self.stop_slot, device.emergency_stop());
                    match self.opened.push(device) {
                        Ok(()) => self.wanted.store(false, Ordering::Release),
                        Err(rtrb::PushError::Full(device)) => ready = Some(device),
                    }
                } else {
                    if last_keep_alive.elapsed() >= KEEP_ALIVE_INTERVAL {
                        last_keep_alive = Instant::now();
                        if device.keep_alive().is_err() {
                            let _ = device.close();
                            continue;
                        }
                    }
                    ready = Some(device);
                }
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        if let Some(mut device) = ready {
            let _ = device.close();
        }
    }
}

impl<D: HapticDevice + Send + 'static> ServoDevice for Reconnecting<D> {
    fn exchange(&mut self, input: TickInput) -> TickOutput {
        let mut attached = false;
        if !self.supervisor.is_connected() {
            if let Ok(device) = self.opened.pop() {
                self.supervisor.attach(device, input.now_us);
                attached = true;
            } else {
                self.wanted.store(true, Ordering::Release);
            }
        }
        let mut output = self.supervisor.tick(input);
        if attached {
            output.report_connected();
        }
        if self.lost_slot.is_none() {
            self.lost_slot = self.supervisor.take_lost();
        }
        if let Some(dead) = self.lost_slot.take() {
            if let Err(rtrb::PushError::Full(dead)) = self.lost.push(dead) {
                self.lost_slot = Some(dead);
            }
            self.wanted.store(true, Ordering::Release);
        }
        output
    }

    fn counters(&self) -> SupervisorCounters {
        self.supervisor.counters()
    }

    fn input_counters(&self) -> InputCounters {
        self.supervisor.input_counters()
    }

    fn engaged(&self) -> bool {
        self.supervisor.safety().is_engaged()
    }

    fn output_state(&self) -> OutputState {
        self.supervisor.output_state()
    }

    fn request_clear_fault(&mut self) -> ClearFaultOutcome {
        self.supervisor.request_clear_fault()
    }

    fn stop(&mut self) {
        self.supervisor.stop();
        self.stop_connector();
    }

    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError> {
        let device = open_only(&self.opener)?;
        install_stop(&self.stop_slot, device.emergency_stop());
        self.supervisor.attach(device, now_us);
        Ok(())
    }

    fn info(&self) -> Option<DeviceInfo> {
        self.supervisor.device().map(|d| d.info().clone())
    }

    fn set_period_us(&mut self, period_us: u64) {
        self.supervisor.set_period_us(period_us);
    }

    fn set_stop_slot(&mut self, slot: Arc<StopSlot>) {
        if let Some(device) = self.supervisor.device() {
            slot.install(device.emergency_stop());
        }
        self.supervisor.set_stall_flag(slot.tripped_flag());
        if let Ok(mut shared) = self.stop_slot.lock() {
            *shared = Some(slot);
        }
    }

    fn max_stiffness_n_per_m(&self) -> Option<f64> {
        self.supervisor
            .device()
            .map(|d| d.info().max_stiffness_n_per_m)
    }
}

impl<D: HapticDevice + Send + 'static> Drop for Reconnecting<D> {
    fn drop(&mut self) {
        self.stop_connector();
    }
}

/// Which device to drive: the `--device` argument.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceSpec {
    /// `sim`: the in-process simulated arm.
    Sim,
    /// `mock:PATH`: `voxhap mock-device` on the pseudo-terminal at PATH (voxhap protocol over serial).
    Mock(PathBuf),
    /// `serial:PATH`: a device speaking the voxhap protocol on the serial port at PATH.
    Serial(PathBuf),
    /// `hid:VID:PID[:SERIAL]`: a device speaking the voxhap protocol over USB HID (hex ids).
    Hid {
        vendor_id: u16,
        product_id: u16,
        serial: Option<String>,
    },
    /// `woodenhaptics-hid`: WoodenHaptics 1.5 over USB HID (legacy mbed firmware).
    WoodenHaptics,
    /// `woodenhaptics:PATH`: WoodenHaptics, Polhem or a retrofitted PHANTOM on the Teensy firmware (USB serial);
    /// the model comes from the device's reports.
    WoodenHapticsSerial(PathBuf),
    /// `haply2diy:PATH`: Haply 2DIY on the USB serial port at PATH.
    Haply2Diy(PathBuf),
    /// `replay:TRACE`: plays the probe positions of a recorded trace (loops at the end).
    Replay(PathBuf),
    /// `haply-inverse[:ws://HOST:PORT]`: Haply Inverse3 through the Haply Inverse Service.
    HaplyInverse(String),
    /// `falcon[:SERIAL|:PATH][,firmware=FILE]`: Novint Falcon on its FTDI serial port (`ftdi_sio`), chosen by
    /// USB serial number or port path (default: the first Falcon found); FILE is Novint's firmware, uploaded
    /// when none is running.
    Falcon {
        select: Option<String>,
        firmware: Option<PathBuf>,
    },
}

/// Why `--device` was not understood.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("--device {given:?}: {problem}; expected sim, mock:PATH, serial:PATH, hid:VID:PID[:SERIAL], woodenhaptics:PATH, woodenhaptics-hid, haply2diy:PATH, haply-inverse[:ws://HOST:PORT], falcon[:SERIAL|:PATH][,firmware=FILE] or replay:TRACE")]
pub struct DeviceSpecError {
    pub given: String,
    pub problem: String,
}

impl FromStr for DeviceSpec {
    type Err = DeviceSpecError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let error = |problem: &str| DeviceSpecError {
            given: text.to_owned(),
            problem: problem.to_owned(),
        };
        if let Some(rest) = text.strip_prefix("falcon") {
            if rest.is_empty() || rest.starts_with(':') || rest.starts_with(',') {
                return parse_falcon(rest).map_err(|problem| error(&problem));
            }
        }
        let (kind, rest) = match text.split_once(':') {
            Some((kind, rest)) => (kind, Some(rest)),
            None => (text, None),
        };
        let path = |rest: Option<&str>| match rest {
            Some(p) if !p.is_empty() => Ok(PathBuf::from(p)),
            _ => Err(error("a path is needed after the colon")),
        };
        match kind {
            "sim" if rest.is_none() => Ok(DeviceSpec::Sim),
            "woodenhaptics-hid" if rest.is_none() => Ok(DeviceSpec::WoodenHaptics),
            "woodenhaptics" if rest.is_none() => Err(error(
                "needs the serial port of the Teensy firmware, e.g. woodenhaptics:/dev/ttyACM0 \
                 (the retired mbed HID firmware is woodenhaptics-hid)",
            )),
            "woodenhaptics" => Ok(DeviceSpec::WoodenHapticsSerial(path(rest)?)),
            "mock" => Ok(DeviceSpec::Mock(path(rest)?)),
            "serial" => Ok(DeviceSpec::Serial(path(rest)?)),
            "haply2diy" => Ok(DeviceSpec::Haply2Diy(path(rest)?)),
            "replay" => Ok(DeviceSpec::Replay(path(rest)?)),
            "haply-inverse" => match rest {
                None => Ok(DeviceSpec::HaplyInverse(
                    crate::device::transport::inverse_service::DEFAULT_URL.to_owned(),
                )),
                Some(url) if url.starts_with("ws://") && url.len() > "ws://".len() => {
                    Ok(DeviceSpec::HaplyInverse(url.to_owned()))
                }
                Some(_) => Err(error(
                    "the Inverse Service address must be ws://HOST:PORT (default ws://127.0.0.1:10001)",
                )),
            },
            "hid" => {
                let rest = rest.ok_or_else(|| error("hid needs VID:PID"))?;
                let mut parts = rest.splitn(3, ':');
                let mut id = |what: &str| {
                    let part = parts.next().unwrap_or("");
                    let digits = part.trim_start_matches("0x");
                    u16::from_str_radix(digits, 16)
                        .map_err(|_| error(&format!("{what} {part:?} is not a 16-bit hex number")))
                };
                let vendor_id = id("vendor id")?;
                let product_id = id("product id")?;
                let serial = parts.next().filter(|s| !s.is_empty()).map(str::to_owned);
                Ok(DeviceSpec::Hid {
                    vendor_id,
                    product_id,
                    serial,
                })
            }
            "sim" | "woodenhaptics-hid" => Err(error("takes no argument")),
            _ => Err(error("unknown device kind")),
        }
    }
}

/// The part of a `falcon` spec after the word: `[:SERIAL|:PATH][,firmware=FILE]`.
fn parse_falcon(rest: &str) -> Result<DeviceSpec, String> {
    let rest = rest.strip_prefix(':').unwrap_or(rest);
    let mut parts = rest.split(',');
    let select = parts.next().filter(|s| !s.is_empty()).map(str::to_owned);
    let mut firmware = None;
    for option in parts {
        match option.split_once('=') {
            Some(("firmware", path)) if !path.is_empty() => firmware = Some(PathBuf::from(path)),
            _ => {
                return Err(format!(
                    "unknown falcon option {option:?} (the only one is firmware=FILE)"
                ))
            }
        }
    }
    Ok(DeviceSpec::Falcon { select, firmware })
}

impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceSpec::Sim => f.write_str("sim"),
            DeviceSpec::Mock(p) => write!(f, "mock:{}", p.display()),
            DeviceSpec::Serial(p) => write!(f, "serial:{}", p.display()),
            DeviceSpec::Hid {
                vendor_id,
                product_id,
                serial,
            } => {
                write!(f, "hid:{vendor_id:04x}:{product_id:04x}")?;
                match serial {
                    Some(s) => write!(f, ":{s}"),
                    None => Ok(()),
                }
            }
            DeviceSpec::WoodenHaptics => f.write_str("woodenhaptics-hid"),
            DeviceSpec::WoodenHapticsSerial(p) => write!(f, "woodenhaptics:{}", p.display()),
            DeviceSpec::Haply2Diy(p) => write!(f, "haply2diy:{}", p.display()),
            DeviceSpec::Replay(p) => write!(f, "replay:{}", p.display()),
            DeviceSpec::HaplyInverse(url) => write!(f, "haply-inverse:{url}"),
            DeviceSpec::Falcon { select, firmware } => {
                f.write_str("falcon")?;
                if let Some(select) = select {
                    write!(f, ":{select}")?;
                }
                match firmware {
                    Some(path) => write!(f, ",firmware={}", path.display()),
                    None => Ok(()),
                }
            }
        }
    }
}

/// Why a device could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(transparent)]
    Safety(#[from] SupervisorConfigError),
    #[error("simulated arm: {0}")]
    Sim(#[from] SimError),
    #[error("replay trace {path}: {message}")]
    Replay { path: PathBuf, message: String },
    #[error("device path {0:?} is not valid UTF-8")]
    Path(PathBuf),
    #[error("could not start the connector thread: {0}")]
    Thread(String),
}

/// The simulated arm as a [`HapticDevice`]: each `write_force` steps the arm one servo period under that
/// force; `read_state` reports where it got to.
pub struct SimDevice {
    arm: SimArm,
    dt_s: f64,
    t_s: f64,
    info: DeviceInfo,
    hand_target: triple_buffer::Output<Option<DVec3>>,
    applied_target: Option<DVec3>,
}

/// The handle that moves a [`SimDevice`]'s hand from another thread (wait-free for the servo thread).
pub type HandTargetInput = triple_buffer::Input<Option<DVec3>>;

impl SimDevice {
    /// An arm built from `config`, at rest at `start_m`, stepped `dt_s` per force; and the input that sets
    /// its hand target.
    pub fn new(
        config: SimArmConfig,
        start_m: DVec3,
        dt_s: f64,
    ) -> Result<(SimDevice, HandTargetInput), SimError> {
        let arm = SimArm::new(config, start_m)?;
        // Check the tick length now: `step` would refuse it on every tick otherwise.
        arm.clone().step(0.0, dt_s, DVec3::ZERO)?;
        let (input, output) = triple_buffer::triple_buffer(&None);
        let info = DeviceInfo {
            model: "voxhap simulated arm".to_owned(),
            serial_number: "in-process".to_owned(),
            position_dof: 3,
            force_dof: 3,
            button_count: 0,
            workspace_min_m: DVec3::splat(-1.0),
            workspace_max_m: DVec3::splat(1.0),
            max_force_n: 10.0,
            max_stiffness_n_per_m: 5000.0,
            max_speed_m_per_s: crate::device::info::DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: true,
            state_rates_hz: Vec::new(),
        };
        Ok((
            SimDevice {
                arm,
                dt_s,
                t_s: 0.0,
                info,
                hand_target: output,
                applied_target: None,
            },
            input,
        ))
    }

    /// The hand target in force, if a client set one.
    pub fn hand_target_m(&self) -> Option<DVec3> {
        self.applied_target
    }
}

impl HapticDevice for SimDevice {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let target = *self.hand_target.read();
        if target != self.applied_target && self.arm.set_hand_target_m(target) {
            self.applied_target = target;
        }
        self.arm
            .step(self.t_s, self.dt_s, force_n)
            .map_err(|_| DeviceError::Protocol {
                what: "simulated arm refused its step",
            })?;
        self.t_s += self.dt_s;
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        Ok(DeviceState {
            position_m: self.arm.position_m(),
            velocity_m_per_s: self.arm.velocity_m_per_s(),
            buttons: 0,
            device_time_us: Some((self.t_s * 1e6) as u64),
            sequence: None,
            status: None,
        })
    }
}

/// An opened device spec: the servo's device, plus the hand-target input when it is the simulated arm.
pub struct OpenedDevice {
    pub device: Box<dyn ServoDevice>,
    pub hand_target: Option<HandTargetInput>,
}

fn boxed<D, F>(config: SupervisorConfig, opener: F) -> Result<Box<dyn ServoDevice>, OpenError>
where
    D: HapticDevice + Send + 'static,
    F: FnMut() -> Result<D, DeviceError> + Send + 'static,
{
    Ok(Box::new(Supervisor::new(config, opener)?))
}

fn reconnecting<D>(
    config: SupervisorConfig,
    opener: impl FnMut() -> Result<D, DeviceError> + Send + 'static,
) -> Result<Box<dyn ServoDevice>, OpenError>
where
    D: HapticDevice + Send + 'static,
{
    Ok(Box::new(Reconnecting::new(config, Box::new(opener))?))
}

fn path_str(path: &std::path::Path) -> Result<String, OpenError> {
    path.to_str()
        .map(str::to_owned)
        .ok_or_else(|| OpenError::Path(path.to_path_buf()))
}

/// Makes the supervised device for `spec`. Nothing is opened yet (call [`ServoDevice::connect`]); the
/// simulated arm uses `sim_arm` (its config and start point) stepped every `period_s`.
pub fn open_device(
    spec: &DeviceSpec,
    config: SupervisorConfig,
    sim_arm: (SimArmConfig, DVec3),
    period_s: f64,
) -> Result<OpenedDevice, OpenError> {
    let protocol = ProtocolConfig::for_period(Duration::from_secs_f64(period_s));
    let mut hand_target = None;
    let device = match spec {
        DeviceSpec::Sim => {
            let (device, input) = SimDevice::new(sim_arm.0, sim_arm.1, period_s)?;
            hand_target = Some(input);
            let mut slot = Some(device);
            // The simulated arm cannot be lost, so the opener is called once.
            boxed(config, move || {
                slot.take().ok_or(DeviceError::Config {
                    what: "the simulated arm was already opened".to_owned(),
                })
            })?
        }
        DeviceSpec::Mock(path) | DeviceSpec::Serial(path) => {
            let path = path_str(path)?;
            reconnecting(config, move || {
                let transport = SerialTransport::open(&path, 1_000_000)?;
                Ok(ProtocolDevice::new(SerialLink::new(transport), protocol))
            })?
        }
        DeviceSpec::Hid {
            vendor_id,
            product_id,
            serial,
        } => {
            let (vendor_id, product_id, serial) = (*vendor_id, *product_id, serial.clone());
            reconnecting(config, move || {
                let transport = match &serial {
                    Some(serial) => HidTransport::open_serial(vendor_id, product_id, serial)?,
                    None => HidTransport::open_vid_pid(vendor_id, product_id)?,
                };
                Ok(ProtocolDevice::new(HidLink::new(transport), protocol))
            })?
        }
        DeviceSpec::WoodenHaptics => reconnecting(config, move || {
            let transport =
                HidTransport::open_vid_pid(woodenhaptics::VENDOR_ID, woodenhaptics::PRODUCT_ID)?;
            WoodenHaptics::new(transport, WoodenHapticsConfig::default())
        })?,
        DeviceSpec::WoodenHapticsSerial(path) => {
            let path = path_str(path)?;
            reconnecting(config, move || {
                // USB CDC-ACM (Teensy) ignores the rate; the firmware calls Serial.begin(115200).
                let transport = SerialTransport::open(&path, 115_200)?;
                Ok(WoodenHapticsSerial::new(transport, WoodyConfig::default()))
            })?
        }
        DeviceSpec::Haply2Diy(path) => {
            let path = path_str(path)?;
            reconnecting(config, move || {
                let transport = SerialTransport::open(&path, 0)?;
                Ok(Haply2Diy::new(transport, Haply2DiyConfig::default()))
            })?
        }
        DeviceSpec::HaplyInverse(url) => {
            let mut driver_config = HaplyInverseConfig::default();
            driver_config.service.url = url.clone();
            reconnecting(config, move || Ok(HaplyInverse::new(driver_config.clone())))?
        }
        DeviceSpec::Falcon { select, firmware } => {
            let (select, firmware) = (select.clone(), firmware.clone());
            reconnecting(config, move || {
                let (path, serial) = crate::device::discovery::find_falcon(select.as_deref())?;
                let transport =
                    SerialTransport::open(&path, crate::device::drivers::falcon::NORMAL_BAUD)?;
                let mut falcon = Falcon::new(
                    transport,
                    FalconConfig {
                        firmware: firmware.clone(),
                        ..FalconConfig::default()
                    },
                );
                if let Some(serial) = serial {
                    falcon.set_serial_number(&serial);
                }
                Ok(falcon)
            })?
        }
        DeviceSpec::Replay(path) => {
            let trace = crate::record::read_trace(path).map_err(|e| OpenError::Replay {
                path: path.clone(),
                message: e.to_string(),
            })?;
            let replay = ReplayDevice::new(&trace, true).map_err(|e| OpenError::Replay {
                path: path.clone(),
                message: e.to_string(),
            })?;
            let mut slot = Some(replay);
            boxed(config, move || {
                slot.take().ok_or(DeviceError::Config {
                    what: "the replay device was already opened".to_owned(),
                })
            })?
        }
    };
    Ok(OpenedDevice {
        device,
        hand_target,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_specs_parse_and_print_back() {
        for text in [
            "sim",
            "mock:/dev/pts/3",
            "serial:/dev/ttyACM0",
            "hid:1234:0006",
            "hid:1234:0006:SN-1",
            "woodenhaptics-hid",
            "woodenhaptics:/dev/ttyACM2",
            "haply2diy:/dev/ttyACM1",
            "replay:trace.csv",
            "haply-inverse:ws://127.0.0.1:10001",
            "haply-inverse:ws://lab-pc:9000",
            "falcon",
            "falcon:A1B2C3",
            "falcon:/dev/ttyUSB0,firmware=/opt/novint/test_firmware.bin",
            "falcon,firmware=fw.bin",
        ] {
            let spec: DeviceSpec = text.parse().unwrap();
            assert_eq!(spec.to_string(), text);
        }
        assert_eq!(
            "hid:0x1234:6".parse::<DeviceSpec>().unwrap(),
            DeviceSpec::Hid {
                vendor_id: 0x1234,
                product_id: 6,
                serial: None
            }
        );
    }

    #[test]
    fn bad_device_specs_say_what_is_wrong() {
        for (text, problem) in [
            ("falconx", "unknown device kind"),
            ("falcon:SN,speed=3", "unknown falcon option"),
            ("mock:", "a path is needed"),
            ("serial", "a path is needed"),
            ("sim:x", "takes no argument"),
            ("hid:zz:0001", "vendor id \"zz\""),
            ("hid:1234", "product id \"\""),
            ("haply-inverse:localhost:10001", "must be ws://HOST:PORT"),
            ("woodenhaptics", "woodenhaptics-hid"),
        ] {
            let err = text.parse::<DeviceSpec>().unwrap_err().to_string();
            assert!(err.contains(problem), "{text}: {err}");
            assert!(err.contains("expected sim"), "{err}");
        }
    }
}
