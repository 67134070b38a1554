//! The driver for voxhap's own device protocol (protocol/SPEC.md), over serial ([`SerialLink`]) or USB HID
//! ([`HidLink`]).
//!
//! Where it sits: under the lifecycle wrapper, on a transport. It wraps the protocol crate's sans-IO
//! [`HostSession`]:
//!
//! - **open** discards stale input, sends a flush byte and Hello, and waits `hello_timeout` (100 ms) for
//!   DeviceInfo; no answer, or an answer that does not decode (bad CRC), means another Hello, up to
//!   `hello_attempts` (5) in all. A device of another major version is refused with both versions named. Then
//!   one zero SetForce in lockstep, so the host sees the handle before enabling.
//! - **enable** sends Enable with the device watchdog timeout and returns at once: a refusal comes back as a
//!   [`DeviceEvent::Rejected`], and the status bits of the next State say whether the device really is enabled.
//! - every **write_force** sends one SetForce; **read_state** returns the newest State that arrived, waiting at
//!   most `state_timeout` (half a servo period) for the one that echoes the last SetForce. Older or duplicate
//!   States are skipped; when no State came but frames were dropped (CRC, COBS, length), the error is a
//!   protocol error rather than a timeout, so the supervisor counts a corrupted link as such.
//! - Fault and Rejected messages are queued as [`DeviceEvent`]s (8 at most, the oldest kept) for the supervisor.
//! - **emergency_stop** (serial only) pre-encodes a delimiter, a zero SetForce (sequence 0) and a Disable and
//!   writes them on a second handle of the port, for the stall monitor.
//!
//! Per tick nothing allocates: frames are built on the stack and decoded by the crate's fixed-size decoder.

use crate::device::info::DEFAULT_MAX_SPEED_M_PER_S;
use crate::device::transport::{ByteTransport, ReportTransport};
use crate::device::{
    DeviceError, DeviceEvent, DeviceInfo, DeviceState, DeviceStatus, EmergencyStop, HapticDevice,
};
use glam::DVec3;
use std::time::{Duration, Instant};
use voxhap_protocol::hid::REPORT_LEN;
use voxhap_protocol::{
    decode_report, encode_frame, encode_report, DecoderStats, DeviceToHost, ForceFlags,
    FrameDecoder, HostEvent, HostSession, HostToDevice, SetForce, StatusFlags, MAX_WIRE_FRAME_LEN,
    PROTOCOL_VERSION,
};

/// Moves protocol messages over some transport.
pub trait MessageLink {
    /// Sends one message.
    fn send(&mut self, message: &HostToDevice) -> Result<(), DeviceError>;

    /// The next valid message, waiting at most `timeout`; `Ok(None)` when none arrived. Dropped frames are
    /// counted in [`MessageLink::stats`].
    fn receive(&mut self, timeout: Duration) -> Result<Option<DeviceToHost>, DeviceError>;

    /// Sent when a link (re)opens: forget any partial frame on both sides.
    fn flush(&mut self) -> Result<(), DeviceError>;

    /// What the decoder accepted and dropped.
    fn stats(&self) -> DecoderStats;

    /// Throws away what the device sent before now (stale replies of an earlier session).
    fn discard_input(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    /// A stop channel on a second handle of the link (see [`ProtocolDevice`]'s `emergency_stop`).
    fn emergency_stop(&self) -> Option<Box<dyn EmergencyStop>> {
        None
    }
}

/// The stall monitor's stop for a serial link: fixed bytes on a second handle of the port.
struct SerialStop {
    writer: Box<dyn std::io::Write + Send>,
    bytes: [u8; 2 * MAX_WIRE_FRAME_LEN + 1],
    len: usize,
}

impl EmergencyStop for SerialStop {
    fn stop(&mut self) -> Result<(), DeviceError> {
        self.writer
            .write_all(&self.bytes[..self.len])
            .and_then(|()| self.writer.flush())
            .map_err(|error| DeviceError::from_io(&error, "writing the emergency stop"))
    }
}

fn serial_stop(writer: Box<dyn std::io::Write + Send>) -> Option<Box<dyn EmergencyStop>> {
    let mut bytes = [0u8; 2 * MAX_WIRE_FRAME_LEN + 1];
    // A delimiter first: it ends any frame the stalled servo thread left half-written.
    let mut len = 1;
    let zero = HostToDevice::SetForce(SetForce {
        sequence: 0,
        force_n: [0.0; 3],
        flags: ForceFlags::EMPTY,
    });
    for message in [zero, HostToDevice::Disable] {
        len += encode_frame(&message, &mut bytes[len..]).ok()?;
    }
    Some(Box::new(SerialStop { writer, bytes, len }))
}

fn encode_error(_: voxhap_protocol::EncodeError) -> DeviceError {
    DeviceError::InvalidData {
        what: "refusing to send a message with a non-finite or out-of-range field",
    }
}

/// Serial framing (COBS, CRC-16, 0x00 delimiter) over a byte stream.
#[derive(Debug)]
pub struct SerialLink<T> {
    transport: T,
    decoder: FrameDecoder<DeviceToHost>,
    buffer: [u8; 512],
    start: usize,
    end: usize,
}

impl<T: ByteTransport> SerialLink<T> {
    /// Frames messages over `transport`.
    pub fn new(transport: T) -> Self {
        SerialLink {
            transport,
            decoder: FrameDecoder::new(),
            buffer: [0; 512],
            start: 0,
            end: 0,
        }
    }

    /// The transport (to check a scripted double with `done()`).
    pub fn transport(&self) -> &T {
        &self.transport
    }
}

impl<T: ByteTransport> MessageLink for SerialLink<T> {
    fn send(&mut self, message: &HostToDevice) -> Result<(), DeviceError> {
        let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
        let len = encode_frame(message, &mut frame).map_err(encode_error)?;
        self.transport.write_all(&frame[..len])
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<DeviceToHost>, DeviceError> {
        let deadline = Instant::now() + timeout;
        loop {
            while self.start < self.end {
                let byte = self.buffer[self.start];
                self.start += 1;
                if let Some(Ok(message)) = self.decoder.push(byte) {
                    return Ok(Some(message));
                }
            }
            let remaining = deadline.saturating_duration_since(Instant::now());
            let n = self.transport.read(&mut self.buffer, remaining)?;
            self.start = 0;
            self.end = n;
            if n == 0 {
                return Ok(None);
            }
        }
    }

    fn flush(&mut self) -> Result<(), DeviceError> {
        self.decoder.reset();
        self.start = 0;
        self.end = 0;
        self.transport
            .write_all(&[voxhap_protocol::serial::DELIMITER])
    }

    fn stats(&self) -> DecoderStats {
        *self.decoder.stats()
    }

    fn discard_input(&mut self) -> Result<(), DeviceError> {
        self.transport.discard_input()
    }

    fn emergency_stop(&self) -> Option<Box<dyn EmergencyStop>> {
        serial_stop(self.transport.try_clone_writer()?)
    }
}

/// One message per 64-byte HID report.
#[derive(Debug)]
pub struct HidLink<T> {
    transport: T,
    stats: DecoderStats,
}

impl<T: ReportTransport> HidLink<T> {
    /// Sends messages as reports over `transport`.
    pub fn new(transport: T) -> Self {
        HidLink {
            transport,
            stats: DecoderStats::default(),
        }
    }

    /// The transport (to check a scripted double with `done()`).
    pub fn transport(&self) -> &T {
        &self.transport
    }
}

impl<T: ReportTransport> MessageLink for HidLink<T> {
    fn send(&mut self, message: &HostToDevice) -> Result<(), DeviceError> {
        let mut report = [0u8; REPORT_LEN];
        encode_report(message, &mut report).map_err(encode_error)?;
        self.transport.write_report(&report)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<DeviceToHost>, DeviceError> {
        let deadline = Instant::now() + timeout;
        loop {
            let mut report = [0u8; REPORT_LEN + 1];
            let remaining = deadline.saturating_duration_since(Instant::now());
            let n = self.transport.read_report(&mut report, remaining)?;
            if n == 0 {
                return Ok(None);
            }
            let result = decode_report::<DeviceToHost>(&report[..n]);
            self.stats.count_report(&result);
            if let Ok(message) = result {
                return Ok(Some(message));
            }
        }
    }

    fn flush(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    fn stats(&self) -> DecoderStats {
        self.stats
    }
}

/// Settings of the protocol driver (defaults: protocol/SPEC.md, "Host behaviour a firmware can rely on").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProtocolConfig {
    /// How long open waits for DeviceInfo after each Hello.
    pub hello_timeout: Duration,
    /// How many Hellos open sends before giving up.
    pub hello_attempts: u32,
    /// How long `read_state` waits for the State answering the last SetForce; at most a servo period, so
    /// device I/O never holds up the servo thread for longer (`open_device` sets half a period).
    pub state_timeout: Duration,
    /// The device's own force watchdog, sent with Enable (µs, 1 000 ..= 1 000 000).
    pub device_watchdog_us: u32,
}

impl Default for ProtocolConfig {
    fn default() -> Self {
        ProtocolConfig {
            hello_timeout: Duration::from_millis(100),
            hello_attempts: 5,
            state_timeout: Duration::from_micros(500),
            device_watchdog_us: 50_000,
        }
    }
}

impl ProtocolConfig {
    /// The defaults for a servo loop of `period`: States are waited for at most half a period.
    pub fn for_period(period: Duration) -> ProtocolConfig {
        ProtocolConfig {
            state_timeout: (period / 2).max(Duration::from_micros(50)),
            ..ProtocolConfig::default()
        }
    }
}

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
}

fn placeholder_info() -> DeviceInfo {
    DeviceInfo {
        model: String::from("voxhap protocol device (not open)"),
        serial_number: String::new(),
        position_dof: 0,
        force_dof: 0,
        button_count: 0,
        workspace_min_m: DVec3::ZERO,
        workspace_max_m: DVec3::ZERO,
        max_force_n: 0.0,
        max_stiffness_n_per_m: 0.0,
        max_speed_m_per_s: DEFAULT_MAX_SPEED_M_PER_S,
        reports_velocity: true,
        state_rates_hz: Vec::new(),
    }
}

fn to_dvec3(v: [f32; 3]) -> DVec3 {
    DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
}

fn convert_info(info: &voxhap_protocol::DeviceInfo) -> DeviceInfo {
    DeviceInfo {
        model: info.model.as_str().to_string(),
        serial_number: info.serial_number.as_str().to_string(),
        position_dof: info.position_dof,
        force_dof: info.force_dof,
        button_count: info.button_count,
        workspace_min_m: to_dvec3(info.workspace_min_m),
        workspace_max_m: to_dvec3(info.workspace_max_m),
        max_force_n: f64::from(info.max_force_n),
        max_stiffness_n_per_m: f64::from(info.max_stiffness_n_per_m),
        max_speed_m_per_s: DEFAULT_MAX_SPEED_M_PER_S,
        reports_velocity: true,
        state_rates_hz: info.supported_rates.iter_hz().collect(),
    }
}

fn convert_status(status: StatusFlags, active_faults: u16) -> DeviceStatus {
    DeviceStatus {
        enabled: status.contains(StatusFlags::ENABLED),
        faulted: status.contains(StatusFlags::FAULTED),
        watchdog_tripped: status.contains(StatusFlags::WATCHDOG_TRIPPED),
        force_clamped: status.contains(StatusFlags::FORCE_CLAMPED),
        active_faults,
    }
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
        }
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
            HostEvent::State { lost, .. } => self.counters.states_lost += u64::from(lost),
            _ => {}
        }
        Ok(event)
    }

    /// Sends Hello and waits for DeviceInfo once; `Ok(false)` when nothing usable came in time.
    fn hello_once(&mut self) -> Result<bool, DeviceError> {
        let hello = self.host.hello();
        self.counters.hellos += 1;
        self.link.send(&hello)?;
        let deadline = Instant::now() + self.config.hello_timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(false);
            }
            let Some(message) = self.link.receive(remaining)? else {
                return Ok(false);
            };
            match self.host.on_message(&message) {
                HostEvent::Connected(info) => {
                    self.info = convert_info(&info);
                    return Ok(true);
                }
                HostEvent::Incompatible(info) => {
                    return Err(DeviceError::Incompatible {
                        device_major: info.version.major,
                        device_minor: info.version.minor,
                        host_major: PROTOCOL_VERSION.major,
                        host_minor: PROTOCOL_VERSION.minor,
                    })
                }
                // Leftovers of an earlier session: ignore.
                _ => {}
            }
        }
    }

    fn send_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let force = [force_n.x as f32, force_n.y as f32, force_n.z as f32];
        if force.iter().any(|f| !f.is_finite()) {
            return Err(DeviceError::InvalidData {
                what: "force is not finite (the safety pipeline should have zeroed it)",
            });
        }
        let message = self.host.set_force(force, ForceFlags::EMPTY);
        if let HostToDevice::SetForce(set_force) = message {
            self.last_sent_sequence = set_force.sequence;
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

    fn open(&mut self) -> Result<(), DeviceError> {
        self.link.discard_input()?;
        self.link.flush()?;
        let mut connected = false;
        for _ in 0..self.config.hello_attempts.max(1) {
            if self.hello_once()? {
                connected = true;
                break;
            }
        }
        if !connected {
            return Err(DeviceError::NoAnswer {
                waiting_for: "device info after hello",
                attempts: self.config.hello_attempts.max(1),
                each_us: duration_us(self.config.hello_timeout),
            });
        }
        // One zero force in lockstep: the device answers with a State, so the host sees the handle before
        // enabling. Open runs off the servo thread, so it may wait for a few periods here.
        for attempt in 0..20 {
            self.send_force(DVec3::ZERO)?;
            match self.read_state() {
                Ok(_) => return Ok(()),
                // A lost or corrupted reply on a noisy link: ask again (open may take a few periods).
                Err(error)
                    if attempt < 19
                        && matches!(
                            error,
                            DeviceError::Timeout { .. } | DeviceError::Protocol { .. }
                        ) => {}
                Err(error) => return Err(error),
            }
        }
        Ok(())
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

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
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
                let sample = DeviceState {
                    position_m: to_dvec3(state.position_m),
                    velocity_m_per_s: to_dvec3(state.velocity_m_per_s),
                    buttons: state.buttons,
                    device_time_us: Some(state.device_time_us),
                    sequence: Some(state.sequence),
                    status: Some(convert_status(state.status, state.faults.0)),
                };
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
