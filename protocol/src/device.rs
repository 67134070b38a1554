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
use crate::message::{
    message_type, DeviceInfo, DeviceToHost, Fault, HeartbeatReply, HostToDevice, Rejected,
    SetForce, State,
};

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
        }
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
            if let HostToDevice::SetForce(_) = message {
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

/// Square root for positive finite `x` without `std` (core has no `sqrt` on stable): a bit-level first guess
/// (halved exponent, error below 6 %), then Newton steps `y <- (y + x/y)/2`, each of which squares the relative error;
/// five reach f64 precision.
fn sqrt(x: f64) -> f64 {
    if x <= 0.0 || !x.is_finite() {
        return x.max(0.0);
    }
    let mut y = f64::from_bits((x.to_bits() >> 1) + 0x1FF8_0000_0000_0000);
    for _ in 0..5 {
        y = 0.5 * (y + x / y);
    }
    y
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
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
