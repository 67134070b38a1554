//! The reconnecting wrapper ([`Reconnecting`]): a supervised device whose port opens, handshakes and
//! reconnection run on a connector thread, so the servo thread never blocks on them; the servo thread and the
//! connector hand devices to each other through two SPSC rings.
//!
//! Invariants, for every driver:
//! - **Back-off.** After a failed open, or a link that was lost less than [`STABLE_LINK`] after it was handed
//!   to the servo thread, the next open waits `min(CAP, interval · 2^n) · j` (`n` such failures in a row,
//!   `interval` the supervisor's `reconnect_interval_us`, `CAP` = [`RECONNECT_BACKOFF_CAP`], `j` uniform in
//!   [0.75, 1] so that several hosts of one service do not retry in step). A link that lasted longer resets
//!   `n`: the first reopen after it is immediate.
//! - **Bounded stop.** The connector checks its stop flag at least every [`CONNECTOR_POLL`] when it is not
//!   inside a driver's open or close; [`ServoDevice::stop`] waits for it at most [`CONNECTOR_STOP_BOUND`],
//!   then leaves it to finish on its own (its driver's handshake deadline ends it; a device it opens after the
//!   stop is closed, never handed out).

use super::error::{ConnectError, OpenError};
use super::servo_device::{forward_to_wrapped, ServoDevice};
use crate::monitor::StopSlot;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use voxhap_device::supervisor::{Supervisor, SupervisorConfig, SupervisorOutput, TickInput};
use voxhap_device::Lifecycle;
use voxhap_device::{DeviceError, DeviceInfo, ErrorKind, HapticDevice};

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
/// Longest wait between two reopen attempts (module docs, "Back-off").
pub const RECONNECT_BACKOFF_CAP: Duration = Duration::from_secs(5);
/// A link lost sooner than this after it was handed out counts as a failed attempt for the back-off.
pub const STABLE_LINK: Duration = Duration::from_secs(5);
/// Longest [`ServoDevice::stop`] waits for the connector thread.
pub const CONNECTOR_STOP_BOUND: Duration = Duration::from_secs(1);
/// How often the connector looks at its rings and its stop flag.
pub const CONNECTOR_POLL: Duration = Duration::from_millis(2);

/// The reopen schedule (module docs, "Back-off").
#[derive(Debug, Clone)]
pub struct Backoff {
    interval: Duration,
    cap: Duration,
    failures: u32,
    random: u64,
}

impl Backoff {
    /// Waits start at `interval` and double up to `cap`; `seed` drives the jitter.
    pub fn new(interval: Duration, cap: Duration, seed: u64) -> Backoff {
        Backoff {
            interval,
            cap: cap.max(interval),
            failures: 0,
            // xorshift needs a non-zero state.
            random: seed | 1,
        }
    }

    /// The wait before the next attempt after one more failure (counted).
    pub fn next_delay(&mut self) -> Duration {
        let doubled = self
            .interval
            .saturating_mul(1u32 << self.failures.min(20))
            .min(self.cap);
        self.failures = self.failures.saturating_add(1);
        // xorshift64; 53 bits make a uniform fraction in [0, 1).
        self.random ^= self.random << 13;
        self.random ^= self.random >> 7;
        self.random ^= self.random << 17;
        let fraction = (self.random >> 11) as f64 / (1u64 << 53) as f64;
        doubled.mul_f64(1.0 - 0.25 * fraction)
    }

    /// A link lasted: the next attempt is immediate, then waits start from `interval` again.
    pub fn reset(&mut self) {
        self.failures = 0;
    }
}

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

    /// Stops the connector thread, waiting for it at most [`CONNECTOR_STOP_BOUND`] (module docs).
    fn stop_connector(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            // Past the bound the thread is left to end on its own: its driver's open has a deadline.
            let _ = crate::join::join_within(thread, CONNECTOR_STOP_BOUND);
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
fn install_stop(shared: &SharedStopSlot, handle: Option<Box<dyn voxhap_device::EmergencyStop>>) {
    if let Ok(slot) = shared.lock() {
        if let Some(slot) = slot.as_ref() {
            slot.install(handle);
        }
    }
}

impl<D: HapticDevice + Send> Connector<D> {
    fn stopping(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    fn run(mut self) {
        let mut ready: Option<Lifecycle<D>> = None;
        let mut last_keep_alive = Instant::now();
        let seed = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |t| t.as_nanos() as u64)
            ^ u64::from(std::process::id()).rotate_left(32);
        let mut backoff = Backoff::new(self.interval, RECONNECT_BACKOFF_CAP, seed);
        let mut next_attempt = Instant::now();
        // The device the session opened at start counts as handed out now.
        let mut handed_out_at = Some(Instant::now());
        while !self.stopping() {
            // Close dead devices first (zero and Disable once more): a serial port is opened exclusively, so
            // the old handle must go.
            while let Ok(mut dead) = self.lost.pop() {
                // The stop channel holds a second handle of the port: release it too, or the port stays
                // busy (serial ports are opened exclusively) and cannot be reopened.
                install_stop(&self.stop_slot, None);
                let _ = dead.close();
                // A link that did not last counts as a failed attempt.
                match handed_out_at.take() {
                    Some(at) if at.elapsed() >= STABLE_LINK => {
                        backoff.reset();
                        next_attempt = Instant::now();
                    }
                    _ => next_attempt = Instant::now() + backoff.next_delay(),
                }
            }
            if ready.is_none()
                && self.wanted.load(Ordering::Acquire)
                && Instant::now() >= next_attempt
            {
                match open_only(&self.opener) {
                    Ok(mut device) if self.stopping() => {
                        // Opened after the stop: never handed out.
                        let _ = device.close();
                        break;
                    }
                    Ok(device) => {
                        ready = Some(device);
                        last_keep_alive = Instant::now();
                    }
                    Err(_) => next_attempt = Instant::now() + backoff.next_delay(),
                }
            }
            if let Some(mut device) = ready.take() {
                if self.wanted.load(Ordering::Acquire) && self.opened.slots() > 0 {
                    install_stop(&self.stop_slot, device.emergency_stop());
                    match self.opened.push(device) {
                        Ok(()) => {
                            self.wanted.store(false, Ordering::Release);
                            handed_out_at = Some(Instant::now());
                        }
                        Err(rtrb::PushError::Full(device)) => ready = Some(device),
                    }
                } else {
                    if last_keep_alive.elapsed() >= KEEP_ALIVE_INTERVAL {
                        last_keep_alive = Instant::now();
                        if device.keep_alive().is_err() {
                            let _ = device.close();
                            next_attempt = Instant::now() + backoff.next_delay();
                            continue;
                        }
                    }
                    ready = Some(device);
                }
            }
            std::thread::sleep(CONNECTOR_POLL);
        }
        if let Some(mut device) = ready {
            let _ = device.close();
        }
        // Dead devices the servo thread handed over last are closed too.
        while let Ok(mut dead) = self.lost.pop() {
            let _ = dead.close();
        }
    }
}

impl<D: HapticDevice + Send + 'static> ServoDevice for Reconnecting<D> {
    fn exchange(&mut self, input: TickInput) -> SupervisorOutput {
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

    forward_to_wrapped!(supervisor);

    fn reported_force_n(&self) -> Option<glam::DVec3> {
        ServoDevice::reported_force_n(&self.supervisor)
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
        ServoDevice::info(&self.supervisor)
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
        ServoDevice::max_stiffness_n_per_m(&self.supervisor)
    }
}

impl<D: HapticDevice + Send + 'static> Drop for Reconnecting<D> {
    fn drop(&mut self) {
        self.stop_connector();
    }
}
