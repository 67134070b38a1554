//! The driver for voxhap's own device protocol (protocol/SPEC.md), over serial ([`SerialLink`]) or USB HID
//! ([`HidLink`]).
//!
//! Where it sits: under the lifecycle wrapper, on a transport. It wraps the protocol crate's sans-IO
//! [`HostSession`]:
//!
//! - **open** discards stale input, sends a flush byte, then Hello followed at once by a Heartbeat whose counter
//!   is a nonce of this open (the handshake's session id, see below). It waits for DeviceInfo for at most
//!   `connect_timeout` (3 s by default): Hello is sent again when nothing usable came, after 100 ms, then after
//!   waits that double up to 1 s (`hello_timeout` is the first wait), so a device that answers late (a
//!   bootloader, a USB-serial adapter's latency timer, a loaded host) is still heard and a silent port costs a
//!   handful of Hellos, not a flood. A device of another major version is refused with both versions named.
//!   Then one zero SetForce in lockstep (sent again every `hello_timeout`), so the host sees the handle before
//!   enabling. Both share one overall deadline: open gives up `connect_timeout` after it started, however the
//!   device answers (late, corrupted, a byte at a time). Neither wait is the servo's per-tick budget.
//! - **Which DeviceInfo counts.** DeviceInfo echoes nothing, so a late reply to a Hello of an earlier open (on
//!   an earlier handle of the same port, or from an earlier process) cannot be told from a fresh one by itself.
//!   The Heartbeat after each Hello can: the device answers in order, so a HeartbeatReply carrying one of this
//!   open's nonces, with `SESSION_OPEN` set, comes after the DeviceInfo answering the Hello sent just before it.
//!   The handshake takes the DeviceInfo that came last before such a reply (any other HeartbeatReply in between
//!   clears it), and every State after that reply answers a SetForce of this open. Nonces come from a process-wide
//!   counter started from the clock, so neither an earlier attempt nor an earlier process shares them.
//! - **enable** sends Enable with the device watchdog timeout and returns at once: a refusal comes back as a
//!   [`DeviceEvent::Rejected`], and the status bits of the next State say whether the device really is enabled.
//! - every **write_force** sends one SetForce; **read_state** returns the newest State that arrived, waiting at
//!   most `state_timeout` (half a servo period) for the one that echoes the last SetForce. Older or duplicate
//!   States are skipped; when no State came but frames were dropped (CRC, COBS, length), the error is a
//!   protocol error rather than a timeout, so the supervisor counts a corrupted link as such.
//! - **write_local_model** (a device of version 1.1 or later that set `LOCAL_MODEL` in the HeartbeatReply
//!   confirming the handshake, SPEC section 10.1; a 1.0 device, or a 1.1 one without the bit, gets SetForce)
//!   sends the tick's primitives as one LocalModel in the set-force sequence, so the same lockstep State
//!   answers it; the LocalStates that follow are kept for [`HapticDevice::local_report`]. A model
//!   the wire cannot carry goes out as the set-force it replaces.
//! - **State rate** (SPEC section 10.4): with a capable device on a link that cannot carry a State and a
//!   LocalState every servo period (a serial port counts as a UART at its baud rate, 10 bits a byte; HID as one
//!   report per 1 ms frame), open sends SetStateRate with the device's highest rate of 500 Hz or less that the
//!   link carries ([`super::protocol_rate`]), or uses SetForce only when there is none. Then `read_state`
//!   returns the newest streamed State, and the last one again (with its age in ticks) on ticks without one.
//! - Fault and Rejected messages are queued as [`DeviceEvent`]s (8 at most, the oldest kept) for the supervisor.
//! - **emergency_stop** (serial only) pre-encodes a delimiter, a zero SetForce (sequence 0) and a Disable and
//!   writes them on a second handle of the port, for the stall monitor.
//! - **Link latency.** The driver measures it rather than declaring a constant (protocol/SPEC.md section 7:
//!   the State's echo of the last SetForce "gives the round-trip time"): open times the first State's round
//!   trip and then `latency_probes` more zero forces in lockstep (64 for a servo loop,
//!   [`ProtocolConfig::for_period`]), each waiting at most `hello_timeout` for the State echoing it, fewer
//!   when open's deadline comes or three in a row go unanswered (a lost answer never fails open). It
//!   declares the 95th percentile, at most the median plus one servo period, rounded up to 0.1 ms, as the
//!   worst case ([`HapticDevice::link_latency`]; the method, the cap and why no wire time is added:
//!   `protocol_latency.rs`). Each open measures again. After open, every SetForce and LocalModel the servo
//!   writes is timed to the first State echoing it, in a fixed histogram ([`HapticDevice::link_delay_seen`]:
//!   the median and the longest round trip since the open, in seconds and servo ticks).
//!
//! Per tick nothing allocates: frames are built on the stack and decoded by the crate's fixed-size decoder.

#[path = "protocol_config.rs"]
mod config;
#[path = "protocol_convert.rs"]
mod convert;
#[path = "protocol_latency.rs"]
pub mod latency;

pub use super::protocol_link::{HidLink, MessageLink, SerialLink};
use super::protocol_rate::LocalStateRate;
use crate::local_offer::{LocalOffer, LocalReport};
use crate::{DeviceError, DeviceEvent, DeviceInfo, DeviceState, EmergencyStop, HapticDevice};
pub use config::{
    ProtocolConfig, DEFAULT_CONNECT_TIMEOUT, DEFAULT_LATENCY_PROBES, MAX_LATENCY_PROBES,
};
use convert::{convert_info, convert_state, placeholder_info, to_dvec3};
use glam::DVec3;
use latency::{LiveRoundTrips, RoundTrips};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};
use voxhap_protocol::{
    local_model_negotiated, DecoderStats, DeviceToHost, ForceFlags, Heartbeat, HostEvent,
    HostSession, HostToDevice, LocalState, StatusFlags, PROTOCOL_VERSION,
};

/// The next handshake nonce (a Heartbeat counter, SPEC section 3.1: "any value; echoed"). A process-wide
/// counter, started from the clock and the process id the first time, so that a reply to another open's Hello
/// (an earlier attempt, an earlier process) carries a nonce this open never sent.
fn take_nonces(count: u32) -> u32 {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let mut current = NEXT.load(Ordering::Relaxed);
    if current == 0 {
        let clock = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| {
                d.subsec_nanos() ^ (d.as_secs() as u32).rotate_left(16)
            });
        let seed = (clock ^ std::process::id().rotate_left(7)).max(1);
        current = match NEXT.compare_exchange(0, seed, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => seed,
            Err(existing) => existing,
        };
    }
    loop {
        let next = current.wrapping_add(count).max(1);
        match NEXT.compare_exchange_weak(current, next, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return current,
            Err(existing) => current = existing,
        }
    }
}

/// At most this many Hellos per open (a `connect_timeout` of 10 minutes needs 600 at the 1 s cap).
const MAX_HELLOS: u32 = 1024;

/// At most this many device events wait for the supervisor; further ones replace the newest.
const EVENT_QUEUE: usize = 8;

/// Counters of the protocol driver beyond the decoder's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ProtocolCounters {
    /// States skipped because they answered an older SetForce.
    pub late_states: u64,
    /// State frames missing from the device's sequence.
    pub states_lost: u64,
    /// Fault messages received.
    pub faults: u64,
    /// Times `read_state` found no answer in time.
    pub timeouts: u64,
    /// Hellos sent by open (more than one means retries).
    pub hellos: u64,
    /// Rejected messages received.
    pub rejections: u64,
}

/// A device speaking voxhap's protocol.
#[derive(Debug)]
pub struct ProtocolDevice<L> {
    link: L,
    config: ProtocolConfig,
    host: HostSession,
    info: DeviceInfo,
    last_sent_sequence: u32,
    last_state: Option<DeviceState>,
    last_fault: Option<voxhap_protocol::Fault>,
    counters: ProtocolCounters,
    events: [Option<DeviceEvent>; EVENT_QUEUE],
    event_head: usize,
    event_len: usize,
    /// The first handshake nonce, when a test fixes it (`None`: drawn per open, [`take_nonces`]).
    handshake_nonce: Option<u32>,
    /// The device set `LOCAL_MODEL` in the HeartbeatReply that confirmed this open's handshake.
    local_capable: bool,
    /// The newest LocalState since the last open.
    last_local: Option<LocalState>,
    /// The State rate this open set (SetStateRate), Hz; 0: lockstep.
    state_rate_hz: u16,
    /// Servo ticks since the State `read_state` last returned arrived (streaming only; 0 in lockstep).
    state_age_ticks: u32,
    /// While `open` runs: when it gives up, `connect_timeout` after it started (the handshake and the first
    /// State share it, however the device trickles its bytes).
    open_deadline: Option<Instant>,
    /// The round trips of zero forces timed while `open` runs (module docs, "Link latency").
    round_trips: RoundTrips,
    /// The link latency the last open measured.
    measured_latency: Option<crate::latency::LinkLatency>,
    /// The round trip of every force the servo sent since the last open (module docs, "Link latency").
    live: LiveRoundTrips,
}

impl<L: MessageLink> ProtocolDevice<L> {
    /// A driver on `link`, not yet open.
    pub fn new(link: L, config: ProtocolConfig) -> Self {
        ProtocolDevice {
            link,
            config,
            host: HostSession::new(),
            info: placeholder_info(),
            last_sent_sequence: 0,
            last_state: None,
            last_fault: None,
            counters: ProtocolCounters::default(),
            events: [None; EVENT_QUEUE],
            event_head: 0,
            event_len: 0,
            handshake_nonce: None,
            local_capable: false,
            last_local: None,
            state_rate_hz: 0,
            state_age_ticks: 0,
            open_deadline: None,
            round_trips: RoundTrips::default(),
            measured_latency: None,
            live: LiveRoundTrips::default(),
        }
    }

    /// Fixes the handshake's first Heartbeat counter (then +1 per Hello), so that a scripted test can spell
    /// the bytes; by default each open draws fresh nonces that no other open uses.
    pub fn with_handshake_nonce(mut self, first: u32) -> Self {
        self.handshake_nonce = Some(first);
        self
    }

    fn push_event(&mut self, event: DeviceEvent) {
        if self.event_len == EVENT_QUEUE {
            // Full: the newest slot is overwritten, so the first faults of a burst are the ones reported.
            let newest = (self.event_head + EVENT_QUEUE - 1) % EVENT_QUEUE;
            self.events[newest] = Some(event);
            return;
        }
        self.events[(self.event_head + self.event_len) % EVENT_QUEUE] = Some(event);
        self.event_len += 1;
    }

    /// The link (its transport, its decoder counters).
    pub fn link(&self) -> &L {
        &self.link
    }

    /// Decoder counters (CRC errors, dropped frames).
    pub fn decoder_stats(&self) -> DecoderStats {
        self.link.stats()
    }

    /// Driver counters.
    pub fn counters(&self) -> ProtocolCounters {
        self.counters
    }

    /// The last Fault message the device sent, if any.
    pub fn last_fault(&self) -> Option<voxhap_protocol::Fault> {
        self.last_fault
    }

    /// Set-forces the device has not acknowledged yet.
    pub fn forces_in_flight(&self) -> u32 {
        self.host.forces_in_flight()
    }

    /// Waits at most `timeout` for one message from the device and classifies it (for idle times: faults, late
    /// states). `Ok(None)` when nothing came.
    pub fn poll_event(&mut self, timeout: Duration) -> Result<Option<HostEvent>, DeviceError> {
        match self.link.receive(timeout)? {
            None => Ok(None),
            Some(message) => self.handle(&message).map(Some),
        }
    }

    /// Sends a Heartbeat and waits for its reply (device time and status bits).
    pub fn heartbeat(
        &mut self,
        timeout: Duration,
    ) -> Result<voxhap_protocol::HeartbeatReply, DeviceError> {
        let message = self.host.heartbeat();
        let HostToDevice::Heartbeat(sent) = message else {
            return Err(DeviceError::Protocol {
                what: "host session built no heartbeat",
            });
        };
        self.link.send(&message)?;
        let deadline = Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            match self.link.receive(remaining)? {
                None => {
                    return Err(DeviceError::Timeout {
                        waited_us: duration_us(timeout),
                        waiting_for: "a heartbeat reply",
                    })
                }
                Some(message) => {
                    if let HostEvent::Heartbeat(reply) = self.handle(&message)? {
                        if reply.counter == sent.counter {
                            return Ok(reply);
                        }
                    }
                }
            }
        }
    }

    /// Classifies one message; faults and rejections are queued as events for the supervisor.
    fn handle(&mut self, message: &DeviceToHost) -> Result<HostEvent, DeviceError> {
        let event = self.host.on_message(message);
        match event {
            HostEvent::Fault(fault) => {
                self.counters.faults += 1;
                self.last_fault = Some(fault);
                self.push_event(DeviceEvent::Fault {
                    code: fault.code.0,
                    active_faults: fault.active_faults.0,
                });
            }
            HostEvent::Rejected(rejected) => {
                self.counters.rejections += 1;
                self.push_event(DeviceEvent::Rejected {
                    message_type: rejected.message_type,
                    reason: rejected.reason.0,
                });
            }
            HostEvent::State { state, lost } => {
                self.counters.states_lost += u64::from(lost);
                if self.open_deadline.is_some() {
                    self.round_trips
                        .answered(state.last_force_sequence, Instant::now());
                } else {
                    self.live
                        .answered(state.last_force_sequence, Instant::now());
                }
            }
            HostEvent::LocalState(local) => self.last_local = Some(local),
            _ => {}
        }
        Ok(event)
    }

    /// Hello (with its nonce Heartbeat) until a DeviceInfo is confirmed by a HeartbeatReply carrying one of
    /// this open's nonces, or `connect_timeout` has passed (module header: which DeviceInfo counts).
    fn handshake(&mut self) -> Result<(), DeviceError> {
        let base = self
            .handshake_nonce
            .unwrap_or_else(|| take_nonces(MAX_HELLOS));
        // The last DeviceInfo since the last HeartbeatReply.
        let mut candidate: Option<voxhap_protocol::DeviceInfo> = None;
        self.ask_until_answered(
            self.config.hello_waits().take(MAX_HELLOS as usize),
            |this, before| {
                let hello = this.host.hello();
                this.counters.hellos += 1;
                this.link.send(&hello)?;
                this.link.send(&HostToDevice::Heartbeat(Heartbeat {
                    counter: base.wrapping_add(before),
                }))
            },
            |this, sent, message| {
                match message {
                    DeviceToHost::DeviceInfo(info) => match this.host.on_message(&message) {
                        HostEvent::Incompatible(_) => {
                            return Err(DeviceError::Incompatible {
                                device_major: info.version.major,
                                device_minor: info.version.minor,
                                host_major: PROTOCOL_VERSION.major,
                                host_minor: PROTOCOL_VERSION.minor,
                            })
                        }
                        _ => candidate = Some(info),
                    },
                    DeviceToHost::Heartbeat(reply) => {
                        let ours = reply.counter.wrapping_sub(base) < sent;
                        let open = reply.status.contains(StatusFlags::SESSION_OPEN);
                        match candidate.take() {
                            Some(info) if ours && open => {
                                this.info = convert_info(&info);
                                // SPEC 10.1: version 1.1 or later and LOCAL_MODEL; a 1.0 device
                                // (bit 6 reserved there) keeps SetForce whatever it sets.
                                this.local_capable =
                                    local_model_negotiated(info.version, reply.status);
                                this.last_local = None;
                                return Ok(Some(()));
                            }
                            // A reply to another open's heartbeat, or one that says no session: the
                            // DeviceInfo before it is not the answer to a Hello of ours.
                            _ => {}
                        }
                    }
                    // States, faults and refusals of an earlier session: the session is not ours yet.
                    _ => {}
                }
                Ok(None)
            },
            ("DeviceInfo answering Hello", "Hellos"),
        )
    }

    /// Sends a request with `send` (told how many went before it), then hands each message that comes within
    /// the next of `waits` to `take` (told how many went out) until it accepts one; again, until it does or
    /// the waits or open's deadline run out: then [`DeviceError::NoAnswer`] naming `what` (what was waited
    /// for, what the requests were).
    fn ask_until_answered(
        &mut self,
        waits: impl Iterator<Item = Duration>,
        mut send: impl FnMut(&mut Self, u32) -> Result<(), DeviceError>,
        mut take: impl FnMut(&mut Self, u32, DeviceToHost) -> Result<Option<()>, DeviceError>,
        what: (&'static str, &'static str),
    ) -> Result<(), DeviceError> {
        let started = Instant::now();
        let mut sent: u32 = 0;
        for wait in waits {
            if self.open_time_is_up() {
                break;
            }
            send(self, sent)?;
            sent += 1;
            let answered = self.receive_for(wait, |this, message| take(this, sent, message))?;
            if answered.is_some() {
                return Ok(());
            }
        }
        Err(DeviceError::NoAnswer {
            waiting_for: what.0,
            attempts: sent,
            sent: what.1,
            waited_us: duration_us(started.elapsed()),
        })
    }

    /// Receives for `wait` (a transport timeout, `Ok(None)`, also ends it), handing each message to `take`
    /// until it returns something: that, or `None` when the time is up. The handshake and the first State
    /// both wait this way, one slot per message they sent.
    fn receive_for<T>(
        &mut self,
        wait: Duration,
        mut take: impl FnMut(&mut Self, DeviceToHost) -> Result<Option<T>, DeviceError>,
    ) -> Result<Option<T>, DeviceError> {
        let mut deadline = Instant::now() + wait;
        if let Some(open_deadline) = self.open_deadline {
            deadline = deadline.min(open_deadline);
        }
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let Some(message) = self.link.receive(remaining)? else {
                return Ok(None);
            };
            if let Some(taken) = take(self, message)? {
                return Ok(Some(taken));
            }
            if remaining.is_zero() {
                return Ok(None);
            }
        }
    }

    /// One zero force in lockstep, sent again every `hello_timeout`, until a State answers (every State after
    /// the handshake's confirming HeartbeatReply answers a force of this open), for at most `connect_timeout`.
    fn first_state(&mut self) -> Result<(), DeviceError> {
        let slots = (self.config.connect_timeout.as_micros()
            / self
                .config
                .hello_timeout
                .max(Duration::from_millis(1))
                .as_micros())
        .clamp(1, u128::from(MAX_HELLOS)) as usize;
        self.ask_until_answered(
            std::iter::repeat_n(self.config.hello_timeout, slots),
            |this, _| this.send_force(DVec3::ZERO),
            |this, _, message| {
                let HostEvent::State { state, .. } = this.handle(&message)? else {
                    return Ok(None);
                };
                this.last_state = Some(convert_state(&state));
                Ok(Some(()))
            },
            (
                "State answering a zero force after DeviceInfo",
                "zero forces",
            ),
        )
    }

    fn open_within_deadline(&mut self) -> Result<(), DeviceError> {
        self.link.discard_input()?;
        self.link.flush()?;
        self.state_rate_hz = 0;
        self.state_age_ticks = 0;
        self.round_trips.clear();
        self.live.clear();
        self.measured_latency = None;
        self.handshake()?;
        self.choose_state_rate()?;
        // One zero force in lockstep: the device answers with a State, so the host sees the handle before
        // enabling. Open runs off the servo thread, so it waits with the handshake's patience, not a tick's.
        self.first_state()?;
        self.measure_latency()?;
        self.measured_latency = self.round_trips.latency(self.config.period);
        Ok(())
    }

    /// `latency_probes` zero forces after the first State, each waiting at most `hello_timeout` for the State
    /// echoing it (module docs, "Link latency"); fewer when open's deadline comes or three in a row go
    /// unanswered. An unanswered probe is no error: only the link failing is.
    fn measure_latency(&mut self) -> Result<(), DeviceError> {
        let mut unanswered = 0;
        for _ in 0..self.config.latency_probes.min(MAX_LATENCY_PROBES) {
            if unanswered >= 3 || self.open_time_is_up() {
                break;
            }
            self.send_force(DVec3::ZERO)?;
            let answered = self.receive_for(self.config.hello_timeout, |this, message| {
                let HostEvent::State { state, .. } = this.handle(&message)? else {
                    return Ok(None);
                };
                this.last_state = Some(convert_state(&state));
                Ok((state.last_force_sequence == this.last_sent_sequence).then_some(()))
            })?;
            unanswered = if answered.is_some() {
                0
            } else {
                unanswered + 1
            };
        }
        Ok(())
    }

    /// The round trips the last open timed (module docs, "Link latency"), in the order they came.
    #[cfg(any(test, feature = "test-support"))]
    pub fn round_trips(&self) -> &[Duration] {
        self.round_trips.samples()
    }

    /// SPEC section 10.4: a capable device on a link that cannot carry a State and a LocalState every servo
    /// period streams State at the highest of its rates (500 Hz at most) that the link carries; when it has
    /// none, or the link cannot carry a LocalModel a period, this open uses SetForce only.
    fn choose_state_rate(&mut self) -> Result<(), DeviceError> {
        if !self.local_capable {
            return Ok(());
        }
        let rates = voxhap_protocol::RateSet(
            self.host
                .device_info()
                .map_or(0, |info| info.supported_rates.0),
        );
        match self
            .link
            .budget()
            .local_state_rate(self.config.period, rates)
        {
            LocalStateRate::Lockstep => Ok(()),
            LocalStateRate::Stream(hz) => {
                self.state_rate_hz = hz;
                let message = self.host.set_state_rate(hz);
                self.link.send(&message)
            }
            LocalStateRate::Unusable => {
                self.local_capable = false;
                Ok(())
            }
        }
    }

    /// The State rate this open set, Hz (0: lockstep, the default; SPEC section 10.4 for the rest).
    pub fn state_rate_hz(&self) -> u16 {
        self.state_rate_hz
    }

    /// `read_state` while the device streams State slower than the servo ticks: the newest State that came,
    /// without waiting while the last one is younger than a stream period; else a wait of at most
    /// `state_timeout` for the next. A tick without a new State gets the last one again, aged by the ticks since
    /// it came ([`HapticDevice::state_age_ticks`]: the supervisor's staleness bound counts it), until it is a
    /// whole stream period old.
    fn read_streamed_state(&mut self) -> Result<DeviceState, DeviceError> {
        // Servo ticks per stream period, rounded up (500 Hz at 1 kHz: 2), in whole microseconds.
        let period_us = self.config.period.as_micros().max(1);
        let stream_us = 1_000_000 / u128::from(self.state_rate_hz);
        let ticks_per_state = u32::try_from(stream_us.div_ceil(period_us))
            .unwrap_or(u32::MAX)
            .max(1);
        let next_age = self.state_age_ticks.saturating_add(1);
        let mut wait = if self.last_state.is_some() && next_age < ticks_per_state {
            Duration::ZERO
        } else {
            self.config.state_timeout
        };
        let deadline = Instant::now() + wait;
        let mut newest: Option<DeviceState> = None;
        while let Some(message) = self.link.receive(wait)? {
            if let HostEvent::State { state, .. } = self.handle(&message)? {
                newest = Some(convert_state(&state));
                wait = Duration::ZERO;
            } else if newest.is_none() {
                wait = deadline.saturating_duration_since(Instant::now());
            }
        }
        if let Some(sample) = newest {
            self.last_state = Some(sample);
            self.state_age_ticks = 0;
            return Ok(sample);
        }
        match self.last_state {
            Some(sample) if next_age <= ticks_per_state => {
                self.state_age_ticks = next_age;
                Ok(sample)
            }
            _ => {
                self.counters.timeouts += 1;
                Err(DeviceError::Timeout {
                    waited_us: duration_us(self.config.state_timeout),
                    waiting_for: "a streamed state",
                })
            }
        }
    }

    /// True once `open`'s overall deadline has passed.
    fn open_time_is_up(&self) -> bool {
        self.open_deadline
            .is_some_and(|deadline| Instant::now() >= deadline)
    }

    fn send_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let force = [force_n.x as f32, force_n.y as f32, force_n.z as f32];
        // Checked after the conversion: a finite f64 beyond f32's range becomes infinite.
        DeviceError::check_finite_force(force.map(f64::from))?;
        let message = self.host.set_force(force, ForceFlags::EMPTY);
        if let HostToDevice::SetForce(set_force) = message {
            self.last_sent_sequence = set_force.sequence;
            if self.open_deadline.is_some() {
                self.round_trips.sent(set_force.sequence, Instant::now());
            } else {
                self.live.sent(set_force.sequence, Instant::now());
            }
        }
        self.link.send(&message)
    }
}

fn duration_us(duration: Duration) -> u64 {
    u64::try_from(duration.as_micros()).unwrap_or(u64::MAX)
}

impl<L: MessageLink> HapticDevice for ProtocolDevice<L> {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Bounded as a whole by `connect_timeout` (plus the last write's own bound).
    fn open(&mut self) -> Result<(), DeviceError> {
        self.open_deadline = Some(Instant::now() + self.config.connect_timeout);
        let opened = self.open_within_deadline();
        self.open_deadline = None;
        opened
    }

    fn enable(&mut self) -> Result<(), DeviceError> {
        let message = self.host.enable(self.config.device_watchdog_us);
        self.link.send(&message)
    }

    fn disable(&mut self) -> Result<(), DeviceError> {
        self.link.send(&HostToDevice::Disable)
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.send_force(force_n)
    }

    fn take_event(&mut self) -> Option<DeviceEvent> {
        if self.event_len == 0 {
            return None;
        }
        let event = self.events[self.event_head].take();
        self.event_head = (self.event_head + 1) % EVENT_QUEUE;
        self.event_len -= 1;
        event
    }

    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.link.send(&HostToDevice::ClearFault)
    }

    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        let message = self.host.heartbeat();
        self.link.send(&message)?;
        // Drain what came meanwhile (heartbeat replies, faults) without waiting.
        while let Some(message) = self.link.receive(Duration::ZERO)? {
            self.handle(&message)?;
        }
        Ok(())
    }

    fn emergency_stop(&self) -> Option<Box<dyn EmergencyStop>> {
        self.link.emergency_stop()
    }

    /// Measured at the last open (module docs, "Link latency"); `None` before the first.
    fn link_latency(&self) -> Option<crate::latency::LinkLatency> {
        self.measured_latency
    }

    /// Timed on every tick since the last open (module docs, "Link latency").
    fn link_delay_seen(&self) -> Option<crate::latency::LinkDelaySeen> {
        self.live.seen()
    }

    fn local_model_capable(&self) -> bool {
        self.local_capable
    }

    fn write_local_model(
        &mut self,
        model: &LocalOffer,
        force_limit_n: f64,
        fallback_force_n: DVec3,
    ) -> Result<(), DeviceError> {
        let params = model.params(force_limit_n, self.info.max_force_n);
        match self.host.local_model(&params, model.primitives()) {
            Ok(message) => {
                if let HostToDevice::LocalModel(sent) = &message {
                    self.last_sent_sequence = sent.sequence;
                    self.live.sent(sent.sequence, Instant::now());
                }
                self.link.send(&message)
            }
            // A stiffness below 1 N/m, a non-finite value: the set-force path instead.
            Err(_) => self.send_force(fallback_force_n),
        }
    }

    fn local_report(&self) -> Option<LocalReport> {
        self.last_local.map(|l| LocalReport {
            proxy_m: to_dvec3(l.proxy_m),
            force_n: to_dvec3(l.force_n),
            bound_m: f64::from(l.bound_m),
            peak_force_n: f64::from(l.peak_force_n),
            model_sequence: l.model_sequence,
            model_age_us: l.model_age_us,
            status: l.status.0,
        })
    }

    fn state_age_ticks(&self) -> u32 {
        self.state_age_ticks
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        if self.state_rate_hz > 0 {
            return self.read_streamed_state();
        }
        let deadline = Instant::now() + self.config.state_timeout;
        let dropped_before = self.link.stats().dropped();
        let mut newest: Option<DeviceState> = None;
        loop {
            // Wait only while nothing new came; once a State is in hand, take what is already there.
            let remaining = if newest.is_some() {
                Duration::ZERO
            } else {
                deadline.saturating_duration_since(Instant::now())
            };
            let Some(message) = self.link.receive(remaining)? else {
                break;
            };
            if let HostEvent::State { state, .. } = self.handle(&message)? {
                let sample = convert_state(&state);
                self.last_state = Some(sample);
                newest = Some(sample);
                // Lockstep: the State answering the newest SetForce ends the wait; older ones are late.
                if state
                    .last_force_sequence
                    .wrapping_sub(self.last_sent_sequence)
                    == 0
                {
                    break;
                }
                self.counters.late_states += 1;
                if Instant::now() >= deadline {
                    break;
                }
            }
        }
        if let Some(sample) = newest {
            return Ok(sample);
        }
        if self.link.stats().dropped() > dropped_before {
            return Err(DeviceError::Protocol {
                what: "frames from the device were dropped (CRC, framing or length) and no state arrived",
            });
        }
        self.counters.timeouts += 1;
        Err(DeviceError::Timeout {
            waited_us: duration_us(self.config.state_timeout),
            waiting_for: "the state answering the last force",
        })
    }
}

#[cfg(test)]
#[path = "protocol_tests.rs"]
mod tests;
