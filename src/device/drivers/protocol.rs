//! The driver for voxhap's own device protocol (protocol/SPEC.md), over serial ([`SerialLink`]) or USB HID
//! ([`HidLink`]).
//!
//! Where it sits: under the lifecycle wrapper, on a transport. It wraps the protocol crate's sans-IO
//! [`HostSession`]: open sends a flush byte and Hello and waits for DeviceInfo (then one zero SetForce in
//! lockstep, so the host sees the handle before enabling); enable sends Enable with the device watchdog timeout;
//! every `write_force` sends a SetForce, and `read_state` waits for the State that echoes it (lockstep). Older or
//! duplicate States are skipped, Fault messages are remembered and reported, a Rejected message becomes an error.
//! Per tick nothing allocates: frames are built on the stack and decoded by the crate's fixed-size decoder.

use crate::device::transport::{ByteTransport, ReportTransport};
use crate::device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;
use std::time::{Duration, Instant};
use voxhap_protocol::hid::REPORT_LEN;
use voxhap_protocol::{
    decode_report, encode_frame, encode_report, DecoderStats, DeviceToHost, ForceFlags,
    FrameDecoder, HostEvent, HostSession, HostToDevice, MAX_WIRE_FRAME_LEN, PROTOCOL_VERSION,
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

/// Settings of the protocol driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProtocolConfig {
    /// How long open waits for DeviceInfo.
    pub open_timeout: Duration,
    /// How long `read_state` waits for the State answering the last SetForce.
    pub state_timeout: Duration,
    /// The device's own force watchdog, sent with Enable (µs, 1 000 ..= 1 000 000).
    pub device_watchdog_us: u32,
}

impl Default for ProtocolConfig {
    fn default() -> Self {
        ProtocolConfig {
            open_timeout: Duration::from_millis(500),
            state_timeout: Duration::from_millis(5),
            device_watchdog_us: 50_000,
        }
    }
}

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
        state_rates_hz: info.supported_rates.iter_hz().collect(),
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
        }
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

    /// Classifies one message; faults are remembered, rejections become errors.
    fn handle(&mut self, message: &DeviceToHost) -> Result<HostEvent, DeviceError> {
        let event = self.host.on_message(message);
        match event {
            HostEvent::Fault(fault) => {
                self.counters.faults += 1;
                self.last_fault = Some(fault);
            }
            HostEvent::Rejected(rejected) => {
                return Err(DeviceError::Rejected {
                    message_type: rejected.message_type,
                    reason: rejected.reason.0,
                })
            }
            HostEvent::State { lost, .. } => self.counters.states_lost += u64::from(lost),
            _ => {}
        }
        Ok(event)
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
        self.link.flush()?;
        let hello = self.host.hello();
        self.link.send(&hello)?;
        let deadline = Instant::now() + self.config.open_timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let Some(message) = self.link.receive(remaining)? else {
                return Err(DeviceError::Timeout {
                    waited_us: duration_us(self.config.open_timeout),
                    waiting_for: "device info after hello",
                });
            };
            match self.host.on_message(&message) {
                HostEvent::Connected(info) => {
                    self.info = convert_info(&info);
                    break;
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
        // One zero force in lockstep: the device answers with a State, so the host sees the handle before enabling.
        self.send_force(DVec3::ZERO)?;
        self.read_state().map(|_| ())
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

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let deadline = Instant::now() + self.config.state_timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let Some(message) = self.link.receive(remaining)? else {
                self.counters.timeouts += 1;
                return Err(DeviceError::Timeout {
                    waited_us: duration_us(self.config.state_timeout),
                    waiting_for: "the state answering the last force",
                });
            };
            if let HostEvent::State { state, .. } = self.handle(&message)? {
                let sample = DeviceState {
                    position_m: to_dvec3(state.position_m),
                    velocity_m_per_s: to_dvec3(state.velocity_m_per_s),
                    buttons: state.buttons,
                    device_time_us: Some(state.device_time_us),
                };
                self.last_state = Some(sample);
                // Lockstep: the State answering the newest SetForce ends the wait; older ones are late.
                if state
                    .last_force_sequence
                    .wrapping_sub(self.last_sent_sequence)
                    == 0
                {
                    return Ok(sample);
                }
                self.counters.late_states += 1;
            }
        }
    }
}
