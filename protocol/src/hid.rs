//! USB HID transport: one message per fixed 64-byte report, `[report id][type][payload][zero padding]`, with the
//! same payload layouts as the serial frames and no CRC (USB checks every packet) and no stuffing.
//!
//! Where it sits: a HID transport (hidapi on the host, the USB stack on the device) moves whole reports;
//! [`encode_report`] fills one, [`decode_report`] parses one. Report id 1 carries host-to-device messages (HID
//! output reports), report id 2 device-to-host messages (input reports); [`REPORT_DESCRIPTOR`] declares both.

use crate::error::{EncodeError, PayloadError, ReportError};
use crate::message::Message;
use crate::wire::MAX_PAYLOAD_LEN;
pub use crate::wire::{DEVICE_TO_HOST_REPORT_ID, HOST_TO_DEVICE_REPORT_ID, REPORT_LEN};

/// A vendor-defined HID report descriptor declaring input report 2 and output report 1, 63 data bytes each.
/// Firmware can return it as is.
pub const REPORT_DESCRIPTOR: [u8; 29] = [
    0x06, 0x00, 0xFF, // Usage Page (Vendor Defined 0xFF00)
    0x09, 0x01, //       Usage (0x01)
    0xA1, 0x01, //       Collection (Application)
    0x15, 0x00, //         Logical Minimum (0)
    0x26, 0xFF, 0x00, //   Logical Maximum (255)
    0x75, 0x08, //         Report Size (8 bits)
    0x95, 0x3F, //         Report Count (63)
    0x85, 0x02, //         Report ID (2): device to host
    0x09, 0x02, //         Usage (0x02)
    0x81, 0x02, //         Input (Data, Variable, Absolute)
    0x85, 0x01, //         Report ID (1): host to device
    0x09, 0x03, //         Usage (0x03)
    0x91, 0x02, //         Output (Data, Variable, Absolute)
    0xC0, //             End Collection
];

/// Fills `out` with the report for `message` (zero padded) and returns [`REPORT_LEN`].
///
/// Refuses a message whose fields its decoder would reject with [`EncodeError::Invalid`].
pub fn encode_report<M: Message>(
    message: &M,
    out: &mut [u8; REPORT_LEN],
) -> Result<usize, EncodeError> {
    message.validate()?;
    *out = [0; REPORT_LEN];
    out[0] = M::HID_REPORT_ID;
    out[1] = message.message_type();
    match out[2..].first_chunk_mut::<MAX_PAYLOAD_LEN>() {
        Some(payload) => message.write_payload(payload),
        None => unreachable!("a report holds the largest payload"),
    };
    Ok(REPORT_LEN)
}

/// Parses one report. Accepts reports shorter than 64 bytes when they still hold the whole payload (some stacks
/// strip trailing padding); padding bytes are ignored.
pub fn decode_report<M: Message>(report: &[u8]) -> Result<M, ReportError> {
    let len = report.len();
    let Some((&[report_id, message_type], rest)) = report.split_first_chunk::<2>() else {
        return Err(ReportError::BadLength { len });
    };
    if len > REPORT_LEN {
        return Err(ReportError::BadLength { len });
    }
    if report_id != M::HID_REPORT_ID {
        return Err(ReportError::WrongReportId {
            expected: M::HID_REPORT_ID,
            actual: report_id,
        });
    }
    let payload_len = M::payload_len(message_type).ok_or(ReportError::Payload(
        PayloadError::UnknownType(message_type),
    ))?;
    let payload = rest
        .get(..payload_len)
        .ok_or(ReportError::BadLength { len })?;
    Ok(M::read_payload(message_type, payload)?)
}
