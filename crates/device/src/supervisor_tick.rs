//! What passes between the servo loop and the supervisor each tick: [`TickInput`] in, [`SupervisorOutput`] out with
//! its [`SupervisorEvent`]s (a fixed-size [`EventList`], so a tick does not allocate), and the running
//! [`SupervisorCounters`].

use crate::local_offer::{LocalOffer, LocalReport};
use crate::safety::SafetyFlags;
use crate::{DeviceEvent, DeviceState, ErrorKind};
use glam::DVec3;

/// What kind of clock a tick's `now_us` is read from, which decides when the supervisor says a reading was
/// handed over (the late end of its [`SampleTime`](crate::plausibility::SampleTime)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TickClock {
    /// The host's monotonic clock (a servo loop in real time): time passes during the exchange, and a reading
    /// was handed over at `now_us` plus the time the tick had taken when `read_state` returned.
    Monotonic,
    /// A clock that stands still during a tick (a simulated clock, or a test's `tick × period`): a reading was
    /// handed over at `now_us`, however long the exchange took in real time.
    Virtual,
}

/// What the servo loop hands the supervisor each tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickInput {
    /// The force the scene rendered (N, device frame), before any safety stage.
    pub force_n: DVec3,
    /// The servo clock (µs).
    pub now_us: u64,
    /// What `now_us` is read from.
    pub clock: TickClock,
    /// This tick started on time (the servo loop runs steadily): required before enabling.
    pub on_time: bool,
    /// `force_n` was computed from a fresh, plausible device sample (a tick without one renders zero, which
    /// must not count as "small" for the engage rule).
    pub force_valid: bool,
    /// The tick's local model, for a device with the local-model capability (SPEC section 10): a capable
    /// driver sends it instead of `force_n` while the force would be valid and sent. `None`: set-force only.
    pub local: Option<LocalOffer>,
}

impl TickInput {
    /// An on-time tick whose force came from a valid sample, on a [`TickClock::Virtual`] clock (tests and
    /// simple callers; a caller on the host's clock sets `clock: TickClock::Monotonic`).
    pub fn at(force_n: DVec3, now_us: u64) -> TickInput {
        TickInput {
            force_n,
            now_us,
            clock: TickClock::Virtual,
            on_time: true,
            force_valid: true,
            local: None,
        }
    }
}

/// Why the link was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LossReason {
    /// The device went away (hang-up, unplugged).
    HungUp,
    /// Too many failed exchanges in a row.
    RepeatedErrors,
    /// No valid state for longer than the link timeout.
    NoValidState,
    /// A run of implausible positions.
    ImplausiblePositions,
    /// The device has no session any more (it restarted): a new handshake is needed.
    SessionLost,
}

impl LossReason {
    /// For people.
    pub fn describe(self) -> &'static str {
        match self {
            LossReason::HungUp => "the device went away",
            LossReason::RepeatedErrors => "too many failed exchanges in a row",
            LossReason::NoValidState => "no valid state within the link timeout",
            LossReason::ImplausiblePositions => "a run of implausible positions",
            LossReason::SessionLost => "the device lost its session (did it restart?)",
        }
    }
}

/// Something that happened on a tick, reported once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SupervisorEvent {
    /// The device was opened (first time or after a loss); it is enabled once the servo runs steadily.
    Connected,
    /// Enable was sent (the device may still refuse it).
    Enabled,
    /// The link was lost; the output is zero until the device is back.
    Disconnected {
        /// The last error's kind.
        kind: ErrorKind,
        /// Why the link was dropped.
        reason: LossReason,
    },
    /// A reopen attempt failed; the next one follows after the interval.
    ReconnectFailed(ErrorKind),
    /// A device error that did not lose the link.
    DeviceError(ErrorKind),
    /// What the device told the host, passed on as it came ([`DeviceEvent`]): a fault (code 0: its watchdog,
    /// re-enabled automatically; others need a person; a latched fault its status showed is reported the same
    /// way), a refused command, or messages it sent beyond what the host asked for.
    Device(DeviceEvent),
    /// The device's status said it was not enabled although the host had enabled it.
    DroppedOut,
    /// The stall monitor stopped the device while the servo thread was stalled.
    StallStop,
    /// The operator cleared the faults (ClearFault sent); the device is enabled again once the link is healthy.
    FaultCleared,
}

pub use voxhap_core::status::OutputState;

/// A few events, inline (a tick reports at most a handful; more are dropped and counted).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EventList {
    events: [Option<SupervisorEvent>; 4],
    len: usize,
}

impl EventList {
    pub(crate) fn push(&mut self, event: SupervisorEvent) -> bool {
        match self.events.get_mut(self.len) {
            Some(slot) => {
                *slot = Some(event);
                self.len += 1;
                true
            }
            None => false,
        }
    }

    /// The events, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = SupervisorEvent> + '_ {
        self.events[..self.len].iter().flatten().copied()
    }

    /// True when nothing happened.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The first event, if any.
    pub fn first(&self) -> Option<SupervisorEvent> {
        self.events[0]
    }
}

/// The result of one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisorOutput {
    /// The newest plausible state known (`None` before the first one, and after a reconnect until the first).
    pub state: Option<DeviceState>,
    /// True if `state` did not come from this tick's exchange (or its position was held).
    pub stale: bool,
    /// The force sent this tick (zero when nothing was sent).
    pub sent_force_n: DVec3,
    /// What the safety stages did.
    pub flags: SafetyFlags,
    /// True while the device is connected.
    pub connected: bool,
    /// Where the output stands after this tick.
    pub output_state: OutputState,
    /// The device's latched faults as last reported (0 when none or unknown).
    pub active_faults: u16,
    /// What happened.
    pub events: EventList,
    /// The device rendered this tick's local model itself (SPEC section 10): `sent_force_n` is then the force it
    /// last reported applying, and `local` its last report.
    pub local: Option<LocalReport>,
}

impl SupervisorOutput {
    pub(crate) fn idle(state: Option<DeviceState>) -> SupervisorOutput {
        SupervisorOutput {
            state,
            stale: true,
            sent_force_n: DVec3::ZERO,
            flags: SafetyFlags::OUTPUT_OFF,
            connected: false,
            output_state: OutputState::Disconnected,
            active_faults: 0,
            events: EventList::default(),
            local: None,
        }
    }

    /// Adds a `Connected` event (for a device attached by another thread).
    pub fn report_connected(&mut self) {
        let _ = self.events.push(SupervisorEvent::Connected);
    }

    pub(crate) fn report(&mut self, counters: &mut SupervisorCounters, event: SupervisorEvent) {
        if !self.events.push(event) {
            counters.events_dropped += 1;
        }
    }
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
    /// Other failed exchanges (corrupted frames, driver errors).
    pub errors: u64,
    /// Faults the device reported (its watchdog included).
    pub faults: u64,
    /// Device watchdog trips among them.
    pub device_watchdog_trips: u64,
    /// Commands the device refused.
    pub rejections: u64,
    /// Enables sent.
    pub enables: u64,
    /// Ticks on which the device was not accepting force (zero sent).
    pub not_enabled_ticks: u64,
    /// Ticks on which zero was sent because the state was stale.
    pub stale_ticks: u64,
    /// Stops by the stall monitor.
    pub stall_stops: u64,
    /// Events that did not fit in a tick's list.
    pub events_dropped: u64,
    /// Surplus messages devices sent (more than asked for), as their drivers last reported, summed over links.
    pub device_surplus: u64,
}
