//! Error types of the codec, one enum per layer: payload (field layout and values), serial frame (COBS, CRC,
//! size), HID report (length, report id) and encoding (caller buffer). All are `Copy`, allocation-free and carry
//! enough detail to log what was wrong; decoders also count each kind (see [`crate::serial::DecoderStats`]).

/// A payload that does not match the layout of its message type, or holds a value the protocol forbids.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PayloadError {
    /// The message type byte names no message this side understands.
    #[error("unknown message type 0x{0:02x}")]
    UnknownType(u8),
    /// The payload is not exactly the size of its message type's layout.
    #[error(
        "message type 0x{message_type:02x} needs a {expected}-byte payload, got {actual} bytes"
    )]
    BadLength {
        /// The message type byte.
        message_type: u8,
        /// Payload size of this type's layout.
        expected: usize,
        /// Payload size received.
        actual: usize,
    },
    /// A float field is NaN or infinite.
    #[error("message type 0x{message_type:02x}: field `{field}` is not a finite number")]
    NonFinite {
        /// The message type byte.
        message_type: u8,
        /// Name of the offending field.
        field: &'static str,
    },
    /// A field holds a value outside its documented range.
    #[error("message type 0x{message_type:02x}: field `{field}` is out of range")]
    InvalidValue {
        /// The message type byte.
        message_type: u8,
        /// Name of the offending field.
        field: &'static str,
    },
}

/// A serial frame (the bytes between two 0x00 delimiters) that was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The COBS stuffing is broken: a delimiter arrived where a code byte promised more data.
    #[error("broken COBS stuffing (a delimiter arrived inside a block)")]
    Cobs,
    /// The unstuffed frame is shorter than a type byte and a CRC.
    #[error("frame of {len} bytes is shorter than the 3-byte minimum (type and CRC)")]
    TooShort {
        /// Unstuffed length received.
        len: usize,
    },
    /// The frame is longer than the largest message this protocol defines; its bytes were skipped.
    #[error("frame longer than the {max}-byte maximum; skipped to the next delimiter", max = crate::wire::MAX_FRAME_LEN)]
    Oversize,
    /// The CRC in the frame does not match the CRC of its contents.
    #[error("CRC mismatch: frame says 0x{received:04x}, contents give 0x{computed:04x}")]
    Crc {
        /// CRC carried by the frame.
        received: u16,
        /// CRC computed over the received type and payload.
        computed: u16,
    },
    /// The frame is intact but its payload is not a valid message.
    #[error(transparent)]
    Payload(#[from] PayloadError),
}

/// A HID report that does not hold a valid message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReportError {
    /// The report is longer than 64 bytes, or too short to hold its message.
    #[error("HID report of {len} bytes cannot hold a message (reports are 64 bytes)")]
    BadLength {
        /// Report length received.
        len: usize,
    },
    /// Byte 0 is not this direction's report id.
    #[error("HID report id {actual} where {expected} was expected")]
    WrongReportId {
        /// The report id of this direction.
        expected: u8,
        /// The report id received.
        actual: u8,
    },
    /// The report's message is not valid.
    #[error(transparent)]
    Payload(#[from] PayloadError),
}

/// A message that could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The caller's buffer is too small.
    #[error("output buffer of {available} bytes is too small, {needed} needed")]
    BufferTooSmall {
        /// Bytes the encoding needs.
        needed: usize,
        /// Bytes the buffer has.
        available: usize,
    },
    /// The message holds a value the decoder would reject (a NaN, an out-of-range field), so it is not sent.
    #[error("refusing to encode an invalid message: {0}")]
    Invalid(#[from] PayloadError),
}
