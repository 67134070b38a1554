//! The links voxhap's protocol driver ([`super::protocol`]) talks through: [`MessageLink`] moves whole protocol
//! messages, framed (COBS and CRC) on a byte stream by [`SerialLink`] or one per report on USB HID by
//! [`HidLink`]. A serial link also gives the stall monitor its emergency stop: a second handle of the port with
//! a zero SetForce and a Disable encoded in advance.

use super::protocol_rate::LinkBudget;
use crate::transport::{ByteTransport, ReportTransport};
use crate::{DeviceError, EmergencyStop};
use std::time::{Duration, Instant};
use voxhap_protocol::hid::REPORT_LEN;
use voxhap_protocol::{
    decode_report, encode_frame, encode_report, DecoderStats, DeviceToHost, ForceFlags,
    FrameDecoder, HostToDevice, SetForce, MAX_WIRE_FRAME_LEN,
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

    /// What the link carries each second, for the State rate of a local-model session (SPEC section 10.4).
    fn budget(&self) -> LinkBudget {
        LinkBudget::Unlimited
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

/// The host's serial rate (SPEC section 4.1), bits per second.
pub const DEFAULT_BAUD: u32 = 1_000_000;

/// Serial framing (COBS, CRC-16, 0x00 delimiter) over a byte stream.
#[derive(Debug)]
pub struct SerialLink<T> {
    transport: T,
    baud: u32,
    decoder: FrameDecoder<DeviceToHost>,
    buffer: [u8; 512],
    start: usize,
    end: usize,
}

impl<T: ByteTransport> SerialLink<T> {
    /// Frames messages over `transport`, a port opened at the host's default rate, [`DEFAULT_BAUD`].
    pub fn new(transport: T) -> Self {
        Self::with_baud(transport, DEFAULT_BAUD)
    }

    /// Frames messages over `transport`, a port opened at `baud` (what the link carries: [`LinkBudget`]).
    pub fn with_baud(transport: T, baud: u32) -> Self {
        SerialLink {
            transport,
            baud,
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

    fn budget(&self) -> LinkBudget {
        LinkBudget::SerialBaud(self.baud)
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

    fn budget(&self) -> LinkBudget {
        LinkBudget::HidFullSpeed
    }

    fn flush(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    fn stats(&self) -> DecoderStats {
        self.stats
    }
}
