//! The sizes and report ids both framings share: the largest payload, the largest serial frame, the HID report
//! length and the HID report id of each direction.
//!
//! Where it sits: at the bottom of the crate, used by [`crate::message`], [`crate::serial`], [`crate::hid`] and
//! [`crate::error`]; it depends on nothing, so those modules do not depend on each other for a constant. The
//! framing modules re-export these under their own paths (`hid::REPORT_LEN`, `serial::MAX_FRAME_LEN`).

/// Largest payload of any message: it fills a 64-byte HID report after the report id and type bytes.
pub const MAX_PAYLOAD_LEN: usize = 62;

/// Largest unstuffed serial frame: type byte, largest payload, CRC.
pub const MAX_FRAME_LEN: usize = 1 + MAX_PAYLOAD_LEN + 2;

/// Size of every HID report, report id included (one full-speed interrupt packet).
pub const REPORT_LEN: usize = 64;
/// Report id of host-to-device (output) HID reports.
pub const HOST_TO_DEVICE_REPORT_ID: u8 = 0x01;
/// Report id of device-to-host (input) HID reports.
pub const DEVICE_TO_HOST_REPORT_ID: u8 = 0x02;
