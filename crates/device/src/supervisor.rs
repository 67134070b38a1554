//! The supervisor: the one object the servo loop talks to. It owns the device (in its [`Lifecycle`]), the
//! safety pipeline (the input checks of `plausibility` and the output limits of `safety`), the link's health,
//! and the device's drive state, and turns every failure into a zero output and a report.
//!
//! Where it sits: on the servo thread. Each [`Supervisor::tick`] decides what may be sent, sends it, reads the
//! state that answers it, checks that state, and moves the drive state machine (docs/design.md, "The safety
//! pipeline": the device's own status is the truth):
//!
//! ```text
//!  attach ──> Starting ──(servo on time for `steady_ticks_before_enable` ticks)──> Enabled ──┐
//!                ^                                                                   │    │
//!                │          device watchdog tripped, monitor stop, device dropped out│    │ fault that needs a
//!                │                                                                   v    │ person, or Enable
//!                └──────(link healthy for `healthy_ticks_before_reenable`)── Recovering  │ refused: FAULTED
//!                                                                                 ^       v
//!                                       operator's clear_fault (ClearFault sent) ─┴── Faulted
//!  Enable refused for another reason (invalid argument) ──> Refused (stays off; clear_fault retries)
//! ```
//!
//! - Force leaves the host only in `Enabled`, and only while the device's own status (where it reports one)
//!   says enabled; otherwise every write is an explicit zero and the tick is flagged `DEVICE_NOT_ENABLED`.
//! - Every fault and refusal is reported once, as a [`SupervisorEvent`]. A fault that needs a person is never
//!   cleared here: only [`Supervisor::request_clear_fault`] (the operator's `clear_fault`) sends ClearFault.
//! - **Link health.** The link is dropped after `max_consecutive_errors` failed exchanges in a row (timeouts,
//!   corrupted frames, anything but a hang-up, which drops it at once), after `link_timeout_us` without a
//!   valid state, or after a run of implausible positions. Before it is dropped the host writes zero and
//!   Disable if the port still takes writes; the dead device is handed out ([`Supervisor::take_lost`]) to be
//!   closed and reopened off the servo thread. A state older than `stale_state_ticks` periods, counted from
//!   the force it answers ([`HapticDevice::state_age_ticks`]), gives no force: zero is sent (`STALE_STATE`).
//! - **When a state was taken** ([`SampleTime`]): no earlier than the tick that sent the force it answers (its
//!   age, counted back over the forces written on this link), no later than when `read_state` returned on the
//!   caller's clock ([`TickClock`]: monotonic, the tick's clock plus the tick's real time so far; virtual, the
//!   tick's clock). A state late in its tick or handed out again is then not refused as a jump for the host's
//!   own delay. [`Supervisor::restart_clock`] forgets the history when the servo loop's clock starts over.
//! - **Pose verdict.** After checking each state, the supervisor tells the driver whether its position was
//!   accepted ([`HapticDevice::input_checked`]), so a driver that converts force with a pose it read itself
//!   never converts with a rejected one.
//! - **Steady before enabling.** `Starting` (and `Recovering`) count on-time ticks that end with a state
//!   within that staleness bound; a reply that came a tick or two late keeps the count, a gap that would zero
//!   the force or a late servo tick restarts it.
//! - **Degrees of freedom** (SPEC 6.8, `device::dof`). For a 1- or 2-DOF device the components it does not use
//!   are set to 0 in every sample before the input checks, and in every force before the safety pipeline (so
//!   the clamp, engage rule and slew limit see what is sent) and again after it (exactly +0.0 on the wire).
//! - A device that sends more messages than its protocol answers with reports
//!   [`DeviceEvent::Surplus`]: counted (`device_surplus`) and reported; force is not affected (the
//!   driver renders from the newest and reports an honest age, which the staleness bound above covers).
//! - A stall monitor on another thread may have stopped the device while the servo thread was stalled
//!   ([`Supervisor::set_stall_flag`]); the next tick sees the flag and goes through `Recovering`.
//!
//! Reconnection attempts open files and allocate; with auto-reconnect they happen here at most once per
//! interval and only while the device is gone (tests); `servo::device::Reconnecting` moves them to a connector
//! thread. The steady-state tick does not allocate.

use super::dof::UsedAxes;
use super::lifecycle::{Lifecycle, LifecycleError, LifecycleState};
use super::plausibility::{InputCounters, InputGuard, SampleTime, WriteTimes};
use super::safety::{EngagementState, SafeForce, SafetyFlags, SafetyPipeline};
use super::{DeviceError, DeviceEvent, DeviceState, DeviceStatus, Error, ErrorKind, HapticDevice};
use crate::info::{FAULT_WATCHDOG_EXPIRED, MESSAGE_TYPE_ENABLE, REJECT_FAULTED, REJECT_NO_SESSION};
use glam::DVec3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

pub use crate::supervisor_config::{
    SupervisorConfig, SupervisorConfigError, CONNECT_TIMEOUT_RANGE_US,
};
pub use crate::supervisor_tick::{
    EventList, LossReason, OutputState, SupervisorCounters, SupervisorEvent, SupervisorOutput,
    TickClock, TickInput,
};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Drive {
    Starting {
        steady_ticks: u32,
    },
    Enabled {
        at_tick: u64,
    },
    Recovering {
        healthy_ticks: u32,
        not_before_us: u64,
    },
    Faulted,
    Refused,
}

/// What [`Supervisor::request_clear_fault`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClearFaultOutcome {
    /// ClearFault will be sent on the next tick, then the device is enabled again once the link is healthy.
    Requested,
    /// There is no fault to clear.
    NothingToClear,
    /// No device is connected.
    NoDevice,
}

/// Lifecycle, safety, link health and reconnection around a device made by `opener`.
pub struct Supervisor<D: HapticDevice, F> {
    opener: F,
    device: Option<Lifecycle<D>>,
    safety: SafetyPipeline,
    input: InputGuard,
    config: SupervisorConfig,
    last_state: Option<DeviceState>,
    drive: Drive,
    consecutive_errors: u32,
    ticks_since_fresh: u32,
    last_fresh_us: u64,
    last_status: Option<DeviceStatus>,
    /// Fault bits of the device's fault events since the last clear: a driver whose device reports faults
    /// only as events (the Haply Inverse Service's safety events) has no status word to carry them.
    event_faults: u16,
    clear_requested: bool,
    next_reconnect_us: u64,
    counters: SupervisorCounters,
    /// False when another thread reconnects ([`Supervisor::attach`]); the tick then never calls the opener.
    auto_reconnect: bool,
    /// A device lost on a tick, kept for [`Supervisor::take_lost`] instead of being dropped here.
    lost: Option<Lifecycle<D>>,
    stall_flag: Option<Arc<AtomicBool>>,
    /// The components of position and velocity the device senses; the others are set to 0 before the input
    /// checks (SPEC 6.8: "ignored by the host"; `device::dof`).
    position_axes: UsedAxes,
    /// The components of force the device renders; the others are set to 0 before the safety pipeline, so that
    /// its clamp, engage rule and slew limit act on what is sent, and after it (SPEC 6.8; `device::dof`).
    force_axes: UsedAxes,
    /// The surplus total the current link's driver last reported.
    surplus_on_link: u64,
    /// When this link's forces went out: the input checks time each state from the one it answers.
    write_times: WriteTimes,
}

impl<D, F> Supervisor<D, F>
where
    D: HapticDevice,
    F: FnMut() -> Result<D, DeviceError>,
{
    /// A supervisor with no device yet; the first tick (or [`Supervisor::connect`]) opens it.
    pub fn new(config: SupervisorConfig, opener: F) -> Result<Self, SupervisorConfigError> {
        config.validate()?;
        Ok(Supervisor {
            opener,
            device: None,
            safety: SafetyPipeline::new(config.safety).map_err(SupervisorConfigError::Safety)?,
            input: InputGuard::new(config.input).map_err(SupervisorConfigError::Input)?,
            config,
            last_state: None,
            drive: Drive::Starting { steady_ticks: 0 },
            consecutive_errors: 0,
            ticks_since_fresh: 0,
            last_fresh_us: 0,
            last_status: None,
            event_faults: 0,
            clear_requested: false,
            next_reconnect_us: 0,
            counters: SupervisorCounters::default(),
            auto_reconnect: true,
            lost: None,
            stall_flag: None,
            position_axes: UsedAxes::ALL,
            force_axes: UsedAxes::ALL,
            surplus_on_link: 0,
            write_times: WriteTimes::new(0),
        })
    }

    /// Counters.
    pub fn counters(&self) -> SupervisorCounters {
        self.counters
    }

    /// The input checks' counters.
    pub fn input_counters(&self) -> InputCounters {
        self.input.counters()
    }

    /// The output limits (their counters, their state).
    pub fn safety(&self) -> &SafetyPipeline {
        &self.safety
    }

    /// The device, while connected.
    pub fn device(&self) -> Option<&Lifecycle<D>> {
        self.device.as_ref()
    }

    /// The connected device's link latency ([`crate::latency`]), `None` when none is connected or its driver
    /// does not know it.
    pub fn link_latency(&self) -> Option<crate::latency::LinkLatency> {
        self.device()
            .and_then(|device| device.device().link_latency())
    }

    /// The round trips the connected device's driver timed on every tick since it opened
    /// ([`crate::latency::LinkDelaySeen`]), `None` when none is connected or its driver times none.
    pub fn link_delay_seen(&self) -> Option<crate::latency::LinkDelaySeen> {
        self.device()
            .and_then(|device| device.device().link_delay_seen())
    }

    /// True while a device is connected.
    pub fn is_connected(&self) -> bool {
        self.device.is_some()
    }

    /// Age (servo periods) of the newest state the next force is rendered from, counted from the force it
    /// answers: what the staleness bound (`stale_state_ticks`) is compared with.
    pub fn state_age_ticks(&self) -> u32 {
        self.ticks_since_fresh
    }

    /// Where the output stands.
    pub fn output_state(&self) -> OutputState {
        if self.device.is_none() {
            return OutputState::Disconnected;
        }
        match self.drive {
            Drive::Starting { .. } => OutputState::Starting,
            Drive::Recovering { .. } => OutputState::Recovering,
            Drive::Faulted => OutputState::Faulted,
            Drive::Refused => OutputState::EnableRefused,
            Drive::Enabled { .. } => {
                if self.ticks_since_fresh > self.config.stale_state_ticks {
                    return OutputState::StaleState;
                }
                match self.safety.engagement() {
                    EngagementState::Off => OutputState::Starting,
                    EngagementState::WaitingToEngage => OutputState::WaitingToEngage,
                    EngagementState::Ramping => OutputState::RampingIn,
                    EngagementState::Engaged => OutputState::Engaged,
                }
            }
        }
    }

    /// The servo period (µs): sets the slew limit's largest rise per tick.
    pub fn set_period_us(&mut self, period_us: u64) {
        self.safety.set_period_us(period_us);
    }

    /// A flag the stall monitor sets after it stopped the device from another thread; the next tick takes
    /// the device through `Recovering`.
    pub fn set_stall_flag(&mut self, flag: Arc<AtomicBool>) {
        self.stall_flag = Some(flag);
    }

    /// Opens the device now (it is enabled once the servo loop runs steadily).
    pub fn connect(&mut self, now_us: u64) -> Result<(), ErrorKind> {
        let result = (|| {
            let device = (self.opener)().map_err(|error| error.kind())?;
            let mut device = Lifecycle::new(device);
            device.open().map_err(|error| error.kind())?;
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

    /// Installs a device that was opened elsewhere (a connector thread, so the servo thread never blocks on a
    /// handshake); it is enabled once the servo loop has run on time for a while, and forces ramp in from
    /// there. A device handed over already enabled is disabled first. Allocation-free.
    pub fn attach(&mut self, mut device: Lifecycle<D>, now_us: u64) {
        if device.state() == LifecycleState::Enabled {
            let _ = device.disable();
        }
        let limit = self
            .config
            .safety
            .max_force_n
            .min(device.info().max_force_n);
        self.safety.set_max_force_n(limit);
        self.safety.disable();
        self.input.attach(device.info());
        self.position_axes = device.info().position_axes();
        self.force_axes = device.info().force_axes();
        self.device = Some(device);
        // A fault the device reported by event (an e-brake, a stall) outlives its link: a dropped link and its
        // reconnect keep the drive faulted until the operator clears it, whichever device reports it.
        self.drive = if self.event_faults != 0 {
            Drive::Faulted
        } else {
            Drive::Starting { steady_ticks: 0 }
        };
        self.last_state = None;
        self.last_status = None;
        self.consecutive_errors = 0;
        self.ticks_since_fresh = 0;
        self.last_fresh_us = now_us;
        self.clear_requested = false;
        self.surplus_on_link = 0;
        self.write_times = WriteTimes::new(now_us);
        self.counters.connects += 1;
    }

    /// The caller's clock starts over at `now_us` after a set-up it did not see (the servo loop's start): the input
    /// checks forget the last reading and the link's times restart, so a handle moved meanwhile is not refused.
    pub fn restart_clock(&mut self, now_us: u64) {
        self.input.reset();
        self.write_times = WriteTimes::new(now_us);
        self.last_fresh_us = now_us;
    }

    /// With `false`, a tick without a device no longer calls the opener: another thread reopens the device and
    /// hands it over with [`Supervisor::attach`].
    pub fn set_auto_reconnect(&mut self, enabled: bool) {
        self.auto_reconnect = enabled;
    }

    /// The device lost on an earlier tick, if nobody took it yet (to close and drop it off the servo thread).
    pub fn take_lost(&mut self) -> Option<Lifecycle<D>> {
        self.lost.take()
    }

    /// The operator's `clear_fault`: ClearFault goes out on the next tick.
    pub fn request_clear_fault(&mut self) -> ClearFaultOutcome {
        if self.device.is_none() {
            return ClearFaultOutcome::NoDevice;
        }
        match self.drive {
            Drive::Faulted | Drive::Refused => {
                self.clear_requested = true;
                ClearFaultOutcome::Requested
            }
            _ => ClearFaultOutcome::NothingToClear,
        }
    }

    /// Zero force, Disable, close.
    pub fn stop(&mut self) {
        self.safety.disable();
        if let Some(mut device) = self.device.take() {
            let _ = device.close();
        }
    }

    fn lose(
        &mut self,
        kind: ErrorKind,
        reason: LossReason,
        now_us: u64,
        out: &mut SupervisorOutput,
    ) {
        if let Some(mut device) = self.device.take() {
            // Zero and Disable while the port may still take them; the close happens off this thread.
            match device.state() {
                LifecycleState::Enabled => {
                    let _ = device.disable();
                }
                LifecycleState::Open => {
                    let _ = device.write_zero();
                }
                LifecycleState::Closed => {}
            }
            device.mark_lost();
            self.lost = Some(device);
        }
        self.safety.disconnect();
        self.counters.disconnects += 1;
        self.next_reconnect_us = now_us.saturating_add(self.config.reconnect_interval_us);
        self.last_state = None;
        out.connected = false;
        out.state = None;
        out.report(
            &mut self.counters,
            SupervisorEvent::Disconnected { kind, reason },
        );
    }

    /// Takes the device out of Enabled (zero and Disable) into `drive`.
    fn fall_back(&mut self, drive: Drive) {
        if let Some(device) = self.device.as_mut() {
            if device.state() == LifecycleState::Enabled {
                let _ = device.disable();
            }
        }
        self.safety.disable();
        self.drive = drive;
    }

    fn recovering(&self, now_us: u64, delay_us: u64) -> Drive {
        Drive::Recovering {
            healthy_ticks: 0,
            not_before_us: now_us.saturating_add(delay_us),
        }
    }

    fn on_event(&mut self, event: DeviceEvent, now_us: u64, out: &mut SupervisorOutput) {
        out.report(&mut self.counters, SupervisorEvent::Device(event));
        match event {
            DeviceEvent::Fault {
                code,
                active_faults,
            } => self.on_fault(code, active_faults, now_us),
            DeviceEvent::Rejected {
                message_type,
                reason,
            } => self.on_rejected(message_type, reason, now_us, out),
            DeviceEvent::Surplus { total } => {
                // `total` counts from the driver's open; the counter sums over links.
                let new = total.saturating_sub(self.surplus_on_link);
                self.surplus_on_link = total;
                self.counters.device_surplus = self.counters.device_surplus.saturating_add(new);
            }
        }
    }

    /// A Fault event: the device's watchdog expiring (which does not latch) falls back to Recovering with no
    /// wait, unless the drive is Faulted or Refused; any other fault latches Faulted.
    fn on_fault(&mut self, code: u8, active_faults: u16, now_us: u64) {
        self.counters.faults += 1;
        if code == FAULT_WATCHDOG_EXPIRED {
            self.counters.device_watchdog_trips += 1;
            if !matches!(self.drive, Drive::Faulted | Drive::Refused) {
                self.fall_back(self.recovering(now_us, 0));
            }
        } else {
            self.event_faults |= active_faults;
            self.fall_back(Drive::Faulted);
        }
    }

    /// A Rejected event: "no session" loses the link; an Enable refused as faulted falls back to Faulted, for
    /// any other reason to Refused; any other rejected message is only counted.
    fn on_rejected(
        &mut self,
        message_type: u8,
        reason: u8,
        now_us: u64,
        out: &mut SupervisorOutput,
    ) {
        self.counters.rejections += 1;
        if reason == REJECT_NO_SESSION {
            self.lose(ErrorKind::Protocol, LossReason::SessionLost, now_us, out);
        } else if message_type == MESSAGE_TYPE_ENABLE {
            if reason == REJECT_FAULTED {
                self.fall_back(Drive::Faulted);
            } else {
                self.fall_back(Drive::Refused);
            }
        }
    }

    fn observe_status(&mut self, status: DeviceStatus, now_us: u64, out: &mut SupervisorOutput) {
        self.last_status = Some(status);
        out.active_faults = status.active_faults | self.event_faults;
        if status.faulted && !matches!(self.drive, Drive::Faulted) {
            // A latched fault (perhaps from before this session, or its Fault frame was lost).
            self.counters.faults += 1;
            out.report(
                &mut self.counters,
                SupervisorEvent::Device(DeviceEvent::Fault {
                    code: lowest_fault_code(status.active_faults),
                    active_faults: status.active_faults,
                }),
            );
            self.fall_back(Drive::Faulted);
            return;
        }
        if let Drive::Enabled { at_tick } = self.drive {
            let believed = self.counters.ticks.saturating_sub(at_tick)
                > u64::from(self.config.enable_grace_ticks);
            if !status.enabled && believed {
                out.report(&mut self.counters, SupervisorEvent::DroppedOut);
                let delay = if status.watchdog_tripped {
                    0
                } else {
                    self.config.reenable_interval_us
                };
                self.fall_back(self.recovering(now_us, delay));
            }
        }
    }

    fn enable_now(&mut self, now_us: u64, out: &mut SupervisorOutput) {
        let Some(device) = self.device.as_mut() else {
            return;
        };
        match device.enable() {
            Ok(()) => {
                self.safety.enable(now_us);
                self.drive = Drive::Enabled {
                    at_tick: self.counters.ticks,
                };
                self.counters.enables += 1;
                out.report(&mut self.counters, SupervisorEvent::Enabled);
            }
            Err(error) => {
                self.counters.errors += 1;
                out.report(
                    &mut self.counters,
                    SupervisorEvent::DeviceError(error.kind()),
                );
                self.drive = self.recovering(now_us, self.config.reenable_interval_us);
            }
        }
    }

    /// `usable`: this tick ended with a state within the staleness bound (force may be computed from it).
    fn advance_drive(&mut self, input: &TickInput, usable: bool, out: &mut SupervisorOutput) {
        let steady = usable && input.on_time;
        match self.drive {
            Drive::Starting { steady_ticks } => {
                let steady_ticks = if steady { steady_ticks + 1 } else { 0 };
                self.drive = Drive::Starting { steady_ticks };
                if steady_ticks >= self.config.steady_ticks_before_enable {
                    self.enable_now(input.now_us, out);
                }
            }
            Drive::Recovering {
                healthy_ticks,
                not_before_us,
            } => {
                let healthy_ticks = if steady { healthy_ticks + 1 } else { 0 };
                self.drive = Drive::Recovering {
                    healthy_ticks,
                    not_before_us,
                };
                if healthy_ticks >= self.config.healthy_ticks_before_reenable
                    && input.now_us >= not_before_us
                {
                    self.enable_now(input.now_us, out);
                }
            }
            Drive::Faulted | Drive::Refused => {
                if std::mem::take(&mut self.clear_requested) {
                    if let Some(device) = self.device.as_mut() {
                        match device.clear_fault() {
                            Ok(()) => {
                                self.event_faults = 0;
                                out.report(&mut self.counters, SupervisorEvent::FaultCleared);
                                self.drive = self.recovering(input.now_us, 0);
                            }
                            Err(error) => {
                                self.counters.errors += 1;
                                out.report(
                                    &mut self.counters,
                                    SupervisorEvent::DeviceError(error.kind()),
                                );
                            }
                        }
                    }
                }
            }
            Drive::Enabled { .. } => {}
        }
    }

    /// One servo tick: decide what may be sent, send it, read and check the answer, handle the device's
    /// events and status, move the drive state, and handle losses and reconnection.
    pub fn tick(&mut self, input: TickInput) -> SupervisorOutput {
        let now_us = input.now_us;
        // The states this tick reads are timed from here (module docs).
        let entered = Instant::now();
        self.counters.ticks += 1;
        let mut out = SupervisorOutput::idle(self.last_state);
        if let Some(flag) = &self.stall_flag {
            if flag.swap(false, Ordering::AcqRel) && self.device.is_some() {
                self.counters.stall_stops += 1;
                out.report(&mut self.counters, SupervisorEvent::StallStop);
                if matches!(self.drive, Drive::Enabled { .. }) {
                    self.fall_back(self.recovering(now_us, 0));
                }
            }
        }
        if self.device.is_none() {
            if !self.auto_reconnect || now_us < self.next_reconnect_us {
                return out;
            }
            self.lost = None;
            match self.connect(now_us) {
                Ok(()) => out.report(&mut self.counters, SupervisorEvent::Connected),
                Err(kind) => {
                    self.counters.failed_reconnects += 1;
                    out.report(&mut self.counters, SupervisorEvent::ReconnectFailed(kind));
                    return out;
                }
            }
        }

        // What may be sent.
        let accepting = matches!(self.drive, Drive::Enabled { .. })
            && self
                .device
                .as_ref()
                .is_some_and(|d| d.state() == LifecycleState::Enabled);
        let stale = self.ticks_since_fresh > self.config.stale_state_ticks;
        let safe = if accepting {
            // Only what the device renders goes through the limits: a 2-DOF device's clamp, engage rule and
            // slew limit are about its x and y (SPEC 6.8, 7.1).
            let rendered_n = self.force_axes.keep(input.force_n);
            let mut safe = self
                .safety
                .process(rendered_n, now_us, input.force_valid && !stale);
            if stale {
                safe.force_n = DVec3::ZERO;
                safe.flags |= SafetyFlags::STALE_STATE;
                self.safety.note_zero_output();
                self.counters.stale_ticks += 1;
            }
            safe
        } else {
            self.safety.note_zero_output();
            self.counters.not_enabled_ticks += 1;
            let mut flags = SafetyFlags::DEVICE_NOT_ENABLED;
            if matches!(self.drive, Drive::Faulted) {
                flags |= SafetyFlags::DEVICE_FAULTED;
            }
            SafeForce {
                force_n: DVec3::ZERO,
                flags,
            }
        };
        let mut safe = safe;
        // Unused components go out as exactly +0.0 (the limits only scale, but a -0.0 must not reach the wire).
        safe.force_n = self.force_axes.keep(safe.force_n);
        out.flags = safe.flags;
        out.sent_force_n = safe.force_n;
        out.connected = true;
        out.active_faults = self.last_status.map_or(0, |s| s.active_faults) | self.event_faults;

        // The exchange.
        let Some(device) = self.device.as_mut() else {
            return out;
        };
        // A capable device renders the tick's local model itself (SPEC section 10), with its own clamp, ramps and
        // slew limit and the host's force limit, whenever the host would send a force computed from a fresh,
        // valid sample; otherwise the set-force (zero, or the pipeline's force) takes it back to that path.
        let local = input.local.filter(|_| {
            accepting
                && input.force_valid
                && !stale
                && self.force_axes == UsedAxes::ALL
                && device.device().local_model_capable()
        });
        let written = match (&local, accepting) {
            (Some(model), _) => {
                let limit_n = self.safety.config().max_force_n;
                device.write_local_model(model, limit_n, safe.force_n)
            }
            (None, true) => device.write_force(safe.force_n),
            (None, false) => device.write_zero(),
        };
        if written.is_ok() {
            self.write_times.wrote(now_us);
        }
        let result = written.and_then(|()| device.read_state());
        let elapsed_us = match input.clock {
            TickClock::Monotonic => {
                u64::try_from(entered.elapsed().as_micros()).unwrap_or(u64::MAX)
            }
            TickClock::Virtual => 0,
        };
        if local.is_some() {
            // What the device applied, as it last reported it (zero before its first report).
            out.local = device.device().local_report();
            out.sent_force_n = out.local.map_or(DVec3::ZERO, |r| r.force_n);
        }
        let state_age_ticks = device.device().state_age_ticks();
        let mut fresh = false;
        match result {
            Ok(mut raw) => {
                self.consecutive_errors = 0;
                // Components the device does not sense are ignored, whatever it reported there (SPEC 6.8).
                raw.position_m = self.position_axes.keep(raw.position_m);
                raw.velocity_m_per_s = self.position_axes.keep(raw.velocity_m_per_s);
                let time = SampleTime {
                    taken_after_us: self.write_times.taken_after_us(state_age_ticks),
                    received_by_us: now_us.saturating_add(elapsed_us),
                };
                let verdict = self.input.check(raw, time);
                // The driver converts the next force with this pose only if the checks accepted it.
                device.input_checked(verdict.usable && !verdict.position_rejected);
                if verdict.position_rejected {
                    out.flags |= SafetyFlags::POSITION_REJECTED;
                }
                if verdict.velocity_replaced {
                    out.flags |= SafetyFlags::VELOCITY_REPLACED;
                }
                if verdict.velocity_estimated {
                    out.flags |= SafetyFlags::VELOCITY_ESTIMATED;
                }
                if verdict.link_broken {
                    self.lose(
                        ErrorKind::Protocol,
                        LossReason::ImplausiblePositions,
                        now_us,
                        &mut out,
                    );
                    out.output_state = self.output_state();
                    return out;
                }
                if verdict.usable {
                    self.last_state = Some(verdict.state);
                    out.state = Some(verdict.state);
                    out.stale = verdict.position_rejected;
                }
                fresh = verdict.usable && !verdict.position_rejected;
                if let Some(status) = raw.status {
                    self.observe_status(status, now_us, &mut out);
                }
            }
            Err(error) => {
                let kind = error.kind();
                match kind {
                    ErrorKind::Disconnected => {
                        self.lose(kind, LossReason::HungUp, now_us, &mut out);
                    }
                    _ if matches!(error, LifecycleError::InvalidState { .. }) => {
                        self.lose(kind, LossReason::RepeatedErrors, now_us, &mut out);
                    }
                    _ => {
                        if kind == ErrorKind::Timeout {
                            self.counters.timeouts += 1;
                        } else {
                            self.counters.errors += 1;
                        }
                        self.consecutive_errors += 1;
                        if self.consecutive_errors >= self.config.max_consecutive_errors {
                            self.lose(kind, LossReason::RepeatedErrors, now_us, &mut out);
                        }
                    }
                }
            }
        }
        if fresh {
            // A driver that handed out an earlier answer says how old it is: the staleness bound counts from
            // the force the state answers, not from when it arrived.
            self.ticks_since_fresh = state_age_ticks;
            self.last_fresh_us = now_us;
        } else {
            self.ticks_since_fresh = self.ticks_since_fresh.saturating_add(1);
        }
        if self.device.is_some()
            && now_us.saturating_sub(self.last_fresh_us) > self.config.link_timeout_us
        {
            self.lose(
                ErrorKind::Timeout,
                LossReason::NoValidState,
                now_us,
                &mut out,
            );
        }
        // Faults and refusals the driver heard while reading.
        while let Some(event) = self.device.as_mut().and_then(|d| d.take_event()) {
            self.on_event(event, now_us, &mut out);
        }
        if self.device.is_some() {
            // A state that came a tick or two late (within the staleness bound) keeps the link steady; a gap
            // that would zero the force does not (docs/safety.md).
            let usable = self.last_state.is_some()
                && self.ticks_since_fresh <= self.config.stale_state_ticks;
            self.advance_drive(&input, usable, &mut out);
        }
        out.output_state = self.output_state();
        out
    }
}

/// The lowest fault code set in a latched fault set (0xFF when none is).
fn lowest_fault_code(active_faults: u16) -> u8 {
    if active_faults == 0 {
        0xFF
    } else {
        active_faults.trailing_zeros() as u8
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
            .field("drive", &self.drive)
            .field("config", &self.config)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
#[path = "supervisor_tests.rs"]
mod tests;
