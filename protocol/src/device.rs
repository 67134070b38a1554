//! The device side of the protocol as a sans-IO state machine: firmware and voxhap's simulated arm both run this,
//! so the watchdog and the state rules are written once.
//!
//! Where it sits: the firmware's receive path decodes bytes into [`HostToDevice`] messages and hands them to
//! [`DeviceSession::on_message`]; its control loop calls [`DeviceSession::poll`] every cycle with the current time
//! and the sensed handle state, applies the force it returns, and sends whatever [`DeviceSession::poll_transmit`]
//! yields. Time is always passed in (microseconds since the device started); nothing here reads a clock, blocks,
//! allocates or does I/O, so every method is safe to call from an interrupt-driven 1 kHz (or faster) loop.
//!
//! States (SPEC.md, "Device state machine"): a session is closed until a hello with the same major version;
//! the drive is `Idle` (zero force), `Enabled` (applying set-force) or `Faulted` (zero force, latched until
//! clear-fault). The watchdog: while enabled, if no set-force arrives for the configured timeout (default 50 ms),
//! the next poll drops to zero force, goes to `Idle`, sets `WATCHDOG_TRIPPED` and queues a fault report. The host
//! must enable again, so a stalled host that wakes up never resumes with a stale force.

use crate::fields::{FaultCode, FaultFlags, ForceFlags, RejectReason, StatusFlags};
use crate::local::{LocalModel, LocalState, LocalStatus};
use crate::message::{
    message_type, DeviceInfo, DeviceToHost, Fault, HeartbeatReply, HostToDevice, Rejected,
    SetForce, State,
};
use crate::num::sqrt;

/// Watchdog timeout when enable asks for 0 (the default), microseconds.
pub const DEFAULT_WATCHDOG_TIMEOUT_US: u32 = 50_000;
/// Shortest watchdog timeout a device accepts, microseconds.
pub const MIN_WATCHDOG_TIMEOUT_US: u32 = 1_000;
/// Longest watchdog timeout a device accepts, microseconds.
pub const MAX_WATCHDOG_TIMEOUT_US: u32 = 1_000_000;
/// Messages a session queues before [`DeviceSession::poll_transmit`] drains them; more are dropped and counted.
pub const OUTBOX_CAPACITY: usize = 8;

/// Whether the device applies forces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DriveState {
    /// Zero force; set-force messages are answered (lockstep) but not applied.
    Idle,
    /// Set-force messages are applied; the watchdog runs.
    Enabled,
    /// Zero force until clear-fault.
    Faulted,
}

/// What the device senses this cycle, in the device frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DeviceSample {
    /// Handle position, metres.
    pub position_m: [f32; 3],
    /// Handle velocity, metres per second.
    pub velocity_m_per_s: [f32; 3],
    /// Button `n` pressed = bit `n`.
    pub buttons: u16,
}

/// Counters of a device session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeviceStats {
    /// Set-force messages not applied (not enabled, or a non-finite force from a caller that skipped the codec).
    pub forces_ignored: u64,
    /// Times the watchdog dropped the device to zero force.
    pub watchdog_trips: u64,
    /// State messages queued.
    pub states_queued: u64,
    /// Outgoing messages dropped because the outbox was full.
    pub outbox_overflows: u64,
    /// Local models dropped because this device was built without the capability (as an unknown type).
    pub local_models_ignored: u64,
}

/// One cycle of the device's local loop, as the loop reports it to the session ([`DeviceSession::record_local_tick`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LocalTick {
    /// Sequence of the model in use (0: none).
    pub model_sequence: u32,
    /// Microseconds since that model was received.
    pub model_age_us: u32,
    /// The device-side proxy, metres.
    pub proxy_m: [f32; 3],
    /// The force applied this cycle, newtons.
    pub force_n: [f32; 3],
    /// The solve's certified bound, metres.
    pub bound_m: f32,
    /// What the loop did this cycle.
    pub status: LocalStatus,
}

/// The local ticks since the last LocalState: the latest, and the worst over all of them.
#[derive(Debug, Clone, Copy, Default)]
struct LocalReport {
    last: LocalTick,
    worst_bound_m: f32,
    peak_force_n: f32,
    events: LocalStatus,
    solves: u16,
}

/// A fixed ring of outgoing messages.
#[derive(Debug, Clone)]
struct Outbox {
    slots: [Option<DeviceToHost>; OUTBOX_CAPACITY],
    head: usize,
    len: usize,
}

impl Outbox {
    const fn new() -> Self {
        Self {
            slots: [None; OUTBOX_CAPACITY],
            head: 0,
            len: 0,
        }
    }

    fn push(&mut self, message: DeviceToHost) -> bool {
        if self.len == OUTBOX_CAPACITY {
            return false;
        }
        self.slots[(self.head + self.len) % OUTBOX_CAPACITY] = Some(message);
        self.len += 1;
        true
    }

    fn pop(&mut self) -> Option<DeviceToHost> {
        if self.len == 0 {
            return None;
        }
        let message = self.slots[self.head].take();
        self.head = (self.head + 1) % OUTBOX_CAPACITY;
        self.len -= 1;
        message
    }
}

/// Device-side protocol state: session, drive state, watchdog, state-frame schedule and outgoing queue.
#[derive(Debug, Clone)]
pub struct DeviceSession {
    info: DeviceInfo,
    session_open: bool,
    drive: DriveState,
    watchdog_timeout_us: u32,
    last_force_us: u64,
    force_n: [f32; 3],
    force_clamped: bool,
    watchdog_tripped: bool,
    faults: FaultFlags,
    last_force_sequence: u32,
    state_sequence: u32,
    /// 0 = lockstep.
    state_rate_hz: u16,
    next_state_us: u64,
    state_requested: bool,
    outbox: Outbox,
    stats: DeviceStats,
    /// Built with the local-model capability (SPEC section 10).
    local_capable: bool,
    /// The local model in use and when it arrived (µs); only while Enabled and in local mode.
    local: Option<(LocalModel, u64)>,
    report: LocalReport,
}

impl DeviceSession {
    /// A powered-up device: session closed, idle, zero force. `info` is what hello answers with; its maximum force
    /// and supported rates are enforced here.
    pub fn new(info: DeviceInfo) -> Self {
        Self {
            info,
            session_open: false,
            drive: DriveState::Idle,
            watchdog_timeout_us: DEFAULT_WATCHDOG_TIMEOUT_US,
            last_force_us: 0,
            force_n: [0.0; 3],
            force_clamped: false,
            watchdog_tripped: false,
            faults: FaultFlags::EMPTY,
            last_force_sequence: 0,
            state_sequence: 0,
            state_rate_hz: 0,
            next_state_us: 0,
            state_requested: false,
            outbox: Outbox::new(),
            stats: DeviceStats::default(),
            local_capable: false,
            local: None,
            report: LocalReport {
                last: LocalTick {
                    model_sequence: 0,
                    model_age_us: 0,
                    proxy_m: [0.0; 3],
                    force_n: [0.0; 3],
                    bound_m: 0.0,
                    status: LocalStatus::EMPTY,
                },
                worst_bound_m: 0.0,
                peak_force_n: 0.0,
                events: LocalStatus::EMPTY,
                solves: 0,
            },
        }
    }

    /// A powered-up device with the local-model capability (SPEC section 10): it sets
    /// [`StatusFlags::LOCAL_MODEL`], takes LocalModel messages, and sends a LocalState after each State once its
    /// local loop ran ([`Self::record_local_tick`]).
    pub fn with_local_model(info: DeviceInfo) -> Self {
        Self {
            local_capable: true,
            ..Self::new(info)
        }
    }

    /// True if built with [`Self::with_local_model`].
    pub fn has_local_model_capability(&self) -> bool {
        self.local_capable
    }

    /// The local model to render and the device time it arrived (µs): `Some` only while Enabled and the last
    /// force command was a LocalModel. Call [`Self::poll`] first so that the watchdog has run.
    pub fn local_model(&self) -> Option<(&LocalModel, u64)> {
        match (&self.local, self.drive) {
            (Some((model, at)), DriveState::Enabled) => Some((model, *at)),
            _ => None,
        }
    }

    /// Records one cycle of the local loop; the next State is followed by a LocalState summarising the cycles
    /// since the previous one (the latest cycle, the largest bound and force, the events, the count).
    pub fn record_local_tick(&mut self, tick: &LocalTick) {
        let r = &mut self.report;
        let force = tick.force_n.iter().map(|f| f * f).sum::<f32>();
        let force = if force.is_finite() {
            crate::num::sqrt(f64::from(force)) as f32
        } else {
            f32::MAX
        };
        r.peak_force_n = if r.solves == 0 {
            force
        } else {
            r.peak_force_n.max(force)
        };
        let bound = if tick.bound_m.is_finite() {
            tick.bound_m.max(0.0)
        } else {
            f32::MAX
        };
        r.worst_bound_m = if r.solves == 0 {
            bound
        } else {
            r.worst_bound_m.max(bound)
        };
        r.events = if r.solves == 0 {
            tick.status
        } else {
            r.events | tick.status
        };
        r.solves = r.solves.saturating_add(1);
        r.last = *tick;
    }

    fn local_state(&mut self) -> Option<LocalState> {
        if !self.local_capable || self.report.solves == 0 {
            return None;
        }
        let r = core::mem::take(&mut self.report);
        let finite = |v: [f32; 3]| v.map(|c| if c.is_finite() { c } else { 0.0 });
        // Events over the interval; the state bits (active, expired, engaging, truncated) of the latest cycle.
        let state_bits = LocalStatus::ACTIVE.0
            | LocalStatus::EXPIRED.0
            | LocalStatus::ENGAGING.0
            | LocalStatus::TRUNCATED.0;
        let status = LocalStatus((r.events.0 & !state_bits) | (r.last.status.0 & state_bits));
        Some(LocalState {
            state_sequence: self.state_sequence,
            model_sequence: r.last.model_sequence,
            model_age_us: r.last.model_age_us,
            proxy_m: finite(r.last.proxy_m),
            force_n: finite(r.last.force_n),
            bound_m: if r.last.bound_m.is_finite() {
                r.last.bound_m.max(0.0)
            } else {
                f32::MAX
            },
            worst_bound_m: r.worst_bound_m,
            peak_force_n: r.peak_force_n,
            status,
            solves: r.solves,
        })
    }

    /// The device description sent in answer to hello.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Current drive state.
    pub fn drive_state(&self) -> DriveState {
        self.drive
    }

    /// True once a compatible hello opened the session.
    pub fn is_session_open(&self) -> bool {
        self.session_open
    }

    /// The watchdog timeout in force, microseconds.
    pub fn watchdog_timeout_us(&self) -> u32 {
        self.watchdog_timeout_us
    }

    /// The state rate in force, hertz (0 = lockstep).
    pub fn state_rate_hz(&self) -> u16 {
        self.state_rate_hz
    }

    /// Counters.
    pub fn stats(&self) -> &DeviceStats {
        &self.stats
    }

    /// Status bits as reported in state and heartbeat messages.
    pub fn status(&self) -> StatusFlags {
        StatusFlags::EMPTY
            .with(StatusFlags::SESSION_OPEN, self.session_open)
            .with(StatusFlags::ENABLED, self.drive == DriveState::Enabled)
            .with(StatusFlags::FAULTED, self.drive == DriveState::Faulted)
            .with(StatusFlags::WATCHDOG_TRIPPED, self.watchdog_tripped)
            // "The force being applied was scaled down": nothing is applied outside Enabled (SPEC section 6).
            .with(
                StatusFlags::FORCE_CLAMPED,
                self.force_clamped && self.drive == DriveState::Enabled,
            )
            .with(StatusFlags::LOCKSTEP, self.state_rate_hz == 0)
            .with(StatusFlags::LOCAL_MODEL, self.local_capable)
    }

    /// Latched faults.
    pub fn faults(&self) -> FaultFlags {
        self.faults
    }

    /// The force to apply now, newtons: the last set-force (clamped to the maximum) while enabled, else zero.
    /// Call [`Self::poll`] first so that the watchdog has run for the current time.
    pub fn force_n(&self) -> [f32; 3] {
        if self.drive == DriveState::Enabled {
            self.force_n
        } else {
            [0.0; 3]
        }
    }

    fn send(&mut self, message: DeviceToHost) {
        if !self.outbox.push(message) {
            self.stats.outbox_overflows = self.stats.outbox_overflows.wrapping_add(1);
        }
    }

    fn reject(&mut self, message_type: u8, reason: RejectReason) {
        self.send(DeviceToHost::Rejected(Rejected {
            message_type,
            reason,
        }));
    }

    fn go_idle(&mut self) {
        if self.drive == DriveState::Enabled {
            self.drive = DriveState::Idle;
        }
        self.force_n = [0.0; 3];
        self.local = None;
    }

    /// Handles one message from the host, received at `now_us`. Replies are queued for [`Self::poll_transmit`].
    pub fn on_message(&mut self, message: &HostToDevice, now_us: u64) {
        match *message {
            HostToDevice::Hello(hello) => {
                self.send(DeviceToHost::DeviceInfo(self.info));
                // A hello always starts over: a host that restarted must enable again.
                self.go_idle();
                self.state_rate_hz = 0;
                self.watchdog_timeout_us = DEFAULT_WATCHDOG_TIMEOUT_US;
                self.session_open = hello.version.is_compatible_with(self.info.version);
                if !self.session_open {
                    self.reject(message_type::HELLO, RejectReason::VERSION_MISMATCH);
                }
                return;
            }
            HostToDevice::Heartbeat(heartbeat) => {
                let reply = HeartbeatReply {
                    counter: heartbeat.counter,
                    device_time_us: now_us,
                    status: self.status(),
                };
                self.send(DeviceToHost::Heartbeat(reply));
                return;
            }
            _ => {}
        }
        if !self.session_open {
            // Set-force arrives at the servo rate: count it rather than answer each one.
            if let HostToDevice::SetForce(_) | HostToDevice::LocalModel(_) = message {
                self.stats.forces_ignored = self.stats.forces_ignored.wrapping_add(1);
            } else {
                self.reject(
                    crate::Message::message_type(message),
                    RejectReason::NO_SESSION,
                );
            }
            return;
        }
        match *message {
            HostToDevice::Hello(_) | HostToDevice::Heartbeat(_) => {}
            HostToDevice::Enable(enable) => self.enable(enable.watchdog_timeout_us, now_us),
            HostToDevice::Disable => self.go_idle(),
            HostToDevice::SetForce(set_force) => self.set_force(&set_force, now_us),
            HostToDevice::LocalModel(model) => self.local_model_message(&model, now_us),
            HostToDevice::ClearFault => {
                if self.drive == DriveState::Faulted {
                    self.faults = FaultFlags::EMPTY;
                    self.drive = DriveState::Idle;
                }
            }
            HostToDevice::SetStateRate(rate) => {
                let rate_hz = rate.state_rate_hz;
                if rate_hz == 0 || self.info.supported_rates.contains_hz(rate_hz) {
                    self.state_rate_hz = rate_hz;
                    self.next_state_us = now_us;
                } else {
                    self.reject(message_type::SET_STATE_RATE, RejectReason::INVALID_ARGUMENT);
                }
            }
        }
    }

    fn enable(&mut self, requested_timeout_us: u32, now_us: u64) {
        if self.drive == DriveState::Faulted {
            return self.reject(message_type::ENABLE, RejectReason::FAULTED);
        }
        let timeout_us = match requested_timeout_us {
            0 => DEFAULT_WATCHDOG_TIMEOUT_US,
            t if (MIN_WATCHDOG_TIMEOUT_US..=MAX_WATCHDOG_TIMEOUT_US).contains(&t) => t,
            _ => return self.reject(message_type::ENABLE, RejectReason::INVALID_ARGUMENT),
        };
        self.drive = DriveState::Enabled;
        self.watchdog_timeout_us = timeout_us;
        self.last_force_us = now_us;
        self.force_n = [0.0; 3];
        self.force_clamped = false;
        self.watchdog_tripped = false;
        self.local = None;
    }

    fn local_model_message(&mut self, model: &LocalModel, now_us: u64) {
        if !self.local_capable {
            // A device without the capability drops the type unread (SPEC section 10.1).
            self.stats.local_models_ignored = self.stats.local_models_ignored.wrapping_add(1);
            return;
        }
        self.last_force_sequence = model.sequence;
        if self.state_rate_hz == 0 {
            self.state_requested = true;
        }
        if self.drive != DriveState::Enabled {
            self.stats.forces_ignored = self.stats.forces_ignored.wrapping_add(1);
            return;
        }
        self.local = Some((*model, now_us));
        self.force_n = [0.0; 3];
        self.force_clamped = false;
        self.last_force_us = now_us;
    }

    fn set_force(&mut self, set_force: &SetForce, now_us: u64) {
        self.last_force_sequence = set_force.sequence;
        if self.state_rate_hz == 0 || set_force.flags.contains(ForceFlags::REQUEST_STATE) {
            self.state_requested = true;
        }
        let finite = set_force.force_n.iter().all(|f| f.is_finite());
        if self.drive != DriveState::Enabled || !finite {
            self.stats.forces_ignored = self.stats.forces_ignored.wrapping_add(1);
            return;
        }
        let (force_n, clamped) = clamp_magnitude(set_force.force_n, self.info.max_force_n);
        self.local = None;
        self.force_n = force_n;
        self.force_clamped = clamped;
        self.last_force_us = now_us;
    }

    /// Reports a fault the firmware detected (emergency stop, over-current, ...). A latching code drops to zero
    /// force and stays `Faulted` until clear-fault; [`FaultCode::WATCHDOG_EXPIRED`] only drops to idle. Codes above
    /// 15 are reported as [`FaultCode::INTERNAL`].
    pub fn raise_fault(&mut self, code: FaultCode, now_us: u64) {
        let code = if code.0 > FaultCode::MAX {
            FaultCode::INTERNAL
        } else {
            code
        };
        if code.is_latching() {
            self.faults = self.faults | FaultFlags::of(code);
            self.drive = DriveState::Faulted;
            self.force_n = [0.0; 3];
            self.local = None;
        } else {
            self.watchdog_tripped = true;
            self.go_idle();
        }
        let fault = Fault {
            code,
            active_faults: self.faults,
            device_time_us: now_us,
        };
        self.send(DeviceToHost::Fault(fault));
    }

    /// Runs one control cycle at `now_us` with what the device senses: runs the watchdog, queues a state frame
    /// when one is due, and returns the force to apply, newtons (zero unless enabled).
    ///
    /// A non-finite position or velocity raises [`FaultCode::ENCODER`] instead of being sent.
    pub fn poll(&mut self, now_us: u64, sample: &DeviceSample) -> [f32; 3] {
        if self.drive == DriveState::Enabled
            && now_us.saturating_sub(self.last_force_us) > u64::from(self.watchdog_timeout_us)
        {
            self.stats.watchdog_trips = self.stats.watchdog_trips.wrapping_add(1);
            self.raise_fault(FaultCode::WATCHDOG_EXPIRED, now_us);
        }
        let sample_finite = sample
            .position_m
            .iter()
            .chain(&sample.velocity_m_per_s)
            .all(|v| v.is_finite());
        if !sample_finite {
            if !self.faults.contains(FaultFlags::of(FaultCode::ENCODER)) {
                self.raise_fault(FaultCode::ENCODER, now_us);
            }
        } else if self.session_open && self.state_due(now_us) {
            self.state_sequence = self.state_sequence.wrapping_add(1);
            let state = State {
                sequence: self.state_sequence,
                device_time_us: now_us,
                position_m: sample.position_m,
                velocity_m_per_s: sample.velocity_m_per_s,
                last_force_sequence: self.last_force_sequence,
                buttons: sample.buttons,
                status: self.status(),
                faults: self.faults,
            };
            self.stats.states_queued = self.stats.states_queued.wrapping_add(1);
            self.send(DeviceToHost::State(state));
            if let Some(local) = self.local_state() {
                self.send(DeviceToHost::LocalState(local));
            }
        }
        self.force_n()
    }

    /// True if a state frame goes out this cycle; advances the streaming schedule without catch-up bursts.
    fn state_due(&mut self, now_us: u64) -> bool {
        let mut due = core::mem::take(&mut self.state_requested);
        if self.state_rate_hz != 0 && now_us >= self.next_state_us {
            let period_us = 1_000_000 / u64::from(self.state_rate_hz);
            self.next_state_us = if now_us - self.next_state_us >= period_us {
                now_us + period_us // fell behind: skip, never burst
            } else {
                self.next_state_us + period_us
            };
            due = true;
        }
        due
    }

    /// The next message to send, oldest first, or `None` when nothing is queued.
    pub fn poll_transmit(&mut self) -> Option<DeviceToHost> {
        self.outbox.pop()
    }
}

/// Scales `force_n` down to magnitude `max_n` if it is longer, keeping its direction.
fn clamp_magnitude(force_n: [f32; 3], max_n: f32) -> ([f32; 3], bool) {
    let norm_sq: f32 = force_n.iter().map(|f| f * f).sum();
    if norm_sq <= max_n * max_n {
        return (force_n, false);
    }
    // Scale in f64 so that forces near f32::MAX (whose square overflows f32) still clamp exactly.
    let norm = sqrt(
        force_n
            .iter()
            .map(|&f| f64::from(f) * f64::from(f))
            .sum::<f64>(),
    );
    let scale = f64::from(max_n) / norm;
    (force_n.map(|f| (f64::from(f) * scale) as f32), true)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::num::sqrt;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn sqrt_matches_std(x in 1e-300f64..1e300) {
            let ours = sqrt(x);
            let reference = std::primitive::f64::sqrt(x);
            prop_assert!((ours - reference).abs() <= reference * 1e-15, "{ours} vs {reference}");
        }

        #[test]
        fn clamp_keeps_direction_and_bounds_magnitude(
            force_n in proptest::array::uniform3(-1e30f32..1e30),
            max_n in 0.0f32..100.0,
        ) {
            let (clamped, was_clamped) = clamp_magnitude(force_n, max_n);
            let norm = |v: [f32; 3]| v.iter().map(|&f| f64::from(f) * f64::from(f)).sum::<f64>().sqrt();
            prop_assert!(norm(clamped) <= f64::from(max_n) * (1.0 + 1e-6) + 1e-30);
            if was_clamped {
                // Same direction: the cross product vanishes relative to the magnitudes.
                let (a, b) = (force_n.map(f64::from), clamped.map(f64::from));
                let cross = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
                prop_assert!(norm(cross.map(|c| c as f32)) <= 1e-5 * norm(force_n) * f64::from(max_n) + 1e-30);
            } else {
                prop_assert_eq!(clamped, force_n);
            }
        }
    }

    #[test]
    fn sqrt_edge_cases() {
        assert_eq!(sqrt(0.0), 0.0);
        assert_eq!(sqrt(4.0), 2.0);
        assert_eq!(sqrt(-1.0), 0.0);
    }
}
