//! The supervisor: the one object the servo loop talks to. It owns the device (in its [`Lifecycle`]), the
//! [`SafetyPipeline`], and a way to reopen the device, and turns every failure into a safe output and a report.
//!
//! Where it sits: on the servo thread. Each [`Supervisor::tick`] passes the rendered force through the safety
//! pipeline, writes it, and reads the state that answers it. A `Disconnected` error, or more than
//! `max_consecutive_timeouts` timeouts in a row, marks the link lost: the output is zero (the safety pipeline is
//! off), the event is reported, and every `reconnect_interval_us` the supervisor calls the opener again; when the
//! device is back it is opened and enabled, and forces ramp in again through the pipeline. Ticks without a fresh
//! state report the last known one as stale. Reconnection attempts open files and allocate; they happen at most
//! once per interval and only while the device is gone. The steady-state tick does not allocate.

use super::lifecycle::{Lifecycle, LifecycleError};
use super::safety::{SafetyConfig, SafetyConfigError, SafetyFlags, SafetyPipeline};
use super::{DeviceError, DeviceState, Error, ErrorKind, HapticDevice};
use glam::DVec3;

/// Settings of the supervisor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisorConfig {
    /// The safety pipeline's settings (its force limit is further lowered to the device's maximum).
    pub safety: SafetyConfig,
    /// Time between reopen attempts while the device is gone (µs).
    pub reconnect_interval_us: u64,
    /// Timeouts in a row that count as a lost link.
    pub max_consecutive_timeouts: u32,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        SupervisorConfig {
            safety: SafetyConfig::default(),
            reconnect_interval_us: 200_000,
            max_consecutive_timeouts: 20,
        }
    }
}

/// Something that happened on a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SupervisorEvent {
    /// The device was opened and enabled (first time or after a loss).
    Connected,
    /// The link was lost; the output is zero until the device is back.
    Disconnected(ErrorKind),
    /// A reopen attempt failed; the next one follows after the interval.
    ReconnectFailed(ErrorKind),
    /// A device error that did not lose the link (a fault, a rejected command).
    DeviceError(ErrorKind),
}

/// The result of one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickOutput {
    /// The newest state known (`None` before the first one).
    pub state: Option<DeviceState>,
    /// True if `state` did not come from this tick's exchange.
    pub stale: bool,
    /// The force sent this tick (zero when nothing was sent).
    pub sent_force_n: DVec3,
    /// What the safety pipeline did.
    pub flags: SafetyFlags,
    /// True while the device is connected and enabled.
    pub connected: bool,
    /// What happened, if anything.
    pub event: Option<SupervisorEvent>,
}

/// Counters of the supervisor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SupervisorCounters {
    /// Ticks run.
    pub ticks: u64,
    /// Links lost.
    pub disconnects: u64,
    /// Successful (re)connections.
    pub connects: u64,
    /// Failed reopen attempts.
    pub failed_reconnects: u64,
    /// Ticks without an answer in time.
    pub timeouts: u64,
    /// Other device errors.
    pub errors: u64,
}

/// Lifecycle, safety and reconnection around a device made by `opener`.
pub struct Supervisor<D: HapticDevice, F> {
    opener: F,
    device: Option<Lifecycle<D>>,
    safety: SafetyPipeline,
    config: SupervisorConfig,
    last_state: Option<DeviceState>,
    consecutive_timeouts: u32,
    next_reconnect_us: u64,
    counters: SupervisorCounters,
    /// False when another thread reconnects ([`Supervisor::attach`]); the tick then never calls the opener.
    auto_reconnect: bool,
    /// A device lost on a tick, kept for [`Supervisor::take_lost`] instead of being dropped here.
    lost: Option<Lifecycle<D>>,
}

impl<D, F> Supervisor<D, F>
where
    D: HapticDevice,
    F: FnMut() -> Result<D, DeviceError>,
{
    /// A supervisor with no device yet; the first tick (or [`Supervisor::connect`]) opens it.
    pub fn new(config: SupervisorConfig, opener: F) -> Result<Self, SafetyConfigError> {
        Ok(Supervisor {
            opener,
            device: None,
            safety: SafetyPipeline::new(config.safety)?,
            config,
            last_state: None,
            consecutive_timeouts: 0,
            next_reconnect_us: 0,
            counters: SupervisorCounters::default(),
            auto_reconnect: true,
            lost: None,
        })
    }

    /// Counters.
    pub fn counters(&self) -> SupervisorCounters {
        self.counters
    }

    /// The safety pipeline (its counters, its state).
    pub fn safety(&self) -> &SafetyPipeline {
        &self.safety
    }

    /// The device, while connected.
    pub fn device(&self) -> Option<&Lifecycle<D>> {
        self.device.as_ref()
    }

    /// True while the device is connected and enabled.
    pub fn is_connected(&self) -> bool {
        self.device.is_some()
    }

    /// Opens and enables the device now.
    pub fn connect(&mut self, now_us: u64) -> Result<(), ErrorKind> {
        let result = (|| {
            let device = (self.opener)().map_err(|error| error.kind())?;
            let mut device = Lifecycle::new(device);
            device.open().map_err(|error| error.kind())?;
            device.enable().map_err(|error| error.kind())?;
            Ok(device)
        })();
        match result {
            Ok(device) => {
                self.attach(device, now_us);
                Ok(())
            }
            Err(kind) => {
                self.next_reconnect_us = now_us.saturating_add(self.config.reconnect_interval_us);
                Err(kind)
            }
        }
    }

    /// Installs a device that was opened and enabled elsewhere (a reconnect thread, so the servo thread never
    /// blocks on a handshake); forces ramp in from here. Allocation-free.
    pub fn attach(&mut self, device: Lifecycle<D>, now_us: u64) {
        let limit = self
            .config
            .safety
            .max_force_n
            .min(device.info().max_force_n);
        self.safety.set_max_force_n(limit);
        self.safety.enable(now_us);
        self.device = Some(device);
        self.consecutive_timeouts = 0;
        self.counters.connects += 1;
    }

    /// With `false`, a tick without a device no longer calls the opener: another thread reopens the device and
    /// hands it over with [`Supervisor::attach`].
    pub fn set_auto_reconnect(&mut self, enabled: bool) {
        self.auto_reconnect = enabled;
    }

    /// The device lost on an earlier tick, if nobody took it yet (to close and drop it off the servo thread).
    /// Without auto-reconnect the lost device is kept for this; with it, it is dropped on the next reopen.
    pub fn take_lost(&mut self) -> Option<Lifecycle<D>> {
        self.lost.take()
    }

    /// Disables and closes the device (zero force first).
    pub fn stop(&mut self) {
        self.safety.disable();
        if let Some(mut device) = self.device.take() {
            let _ = device.close();
        }
    }

    fn lose(&mut self, kind: ErrorKind, now_us: u64) -> SupervisorEvent {
        if let Some(mut device) = self.device.take() {
            device.mark_lost();
            self.lost = Some(device);
        }
        self.safety.disconnect();
        self.counters.disconnects += 1;
        self.next_reconnect_us = now_us.saturating_add(self.config.reconnect_interval_us);
        SupervisorEvent::Disconnected(kind)
    }

    /// One servo tick: make `force_n` safe, send it, read the answer; handle losses and reconnection.
    pub fn tick(&mut self, force_n: DVec3, now_us: u64) -> TickOutput {
        self.counters.ticks += 1;
        let mut output = TickOutput {
            state: self.last_state,
            stale: true,
            sent_force_n: DVec3::ZERO,
            flags: SafetyFlags::OUTPUT_OFF,
            connected: false,
            event: None,
        };
        if self.device.is_none() {
            if !self.auto_reconnect || now_us < self.next_reconnect_us {
                return output;
            }
            self.lost = None;
            match self.connect(now_us) {
                Ok(()) => output.event = Some(SupervisorEvent::Connected),
                Err(kind) => {
                    self.counters.failed_reconnects += 1;
                    output.event = Some(SupervisorEvent::ReconnectFailed(kind));
                    return output;
                }
            }
        }
        let safe = self.safety.process(force_n, now_us);
        output.flags = safe.flags;
        let Some(device) = self.device.as_mut() else {
            return output;
        };
        let result = device
            .write_force(safe.force_n)
            .and_then(|()| device.read_state());
        output.sent_force_n = safe.force_n;
        match result {
            Ok(state) => {
                self.consecutive_timeouts = 0;
                self.last_state = Some(state);
                output.state = Some(state);
                output.stale = false;
                output.connected = true;
            }
            Err(error) => {
                let kind = error.kind();
                output.connected = true;
                match kind {
                    ErrorKind::Timeout => {
                        self.counters.timeouts += 1;
                        self.consecutive_timeouts += 1;
                        if self.consecutive_timeouts > self.config.max_consecutive_timeouts {
                            output.event = Some(self.lose(kind, now_us));
                            output.connected = false;
                        }
                    }
                    ErrorKind::Disconnected => {
                        output.event = Some(self.lose(kind, now_us));
                        output.connected = false;
                    }
                    _ => {
                        self.counters.errors += 1;
                        output.event = Some(SupervisorEvent::DeviceError(kind));
                        if matches!(error, LifecycleError::InvalidState { .. }) {
                            output.event = Some(self.lose(kind, now_us));
                            output.connected = false;
                        }
                    }
                }
            }
        }
        output
    }
}

impl<D: HapticDevice, F> Drop for Supervisor<D, F> {
    fn drop(&mut self) {
        if let Some(mut device) = self.device.take() {
            let _ = device.close();
        }
    }
}

impl<D: HapticDevice, F> std::fmt::Debug for Supervisor<D, F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Supervisor")
            .field("connected", &self.device.is_some())
            .field("config", &self.config)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}
