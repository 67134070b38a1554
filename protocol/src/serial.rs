//! Serial framing: a message becomes `COBS(type ‖ payload ‖ CRC-16 LE) ‖ 0x00`, and a byte stream becomes messages
//! again, with resynchronisation after garbage and a counter for every kind of dropped frame.
//!
//! Where it sits: a transport (UART, USB CDC, pseudo-terminal, in-memory pipe) hands raw bytes to
//! [`FrameDecoder::push`] or [`FrameDecoder::feed`], which yield messages for the device session
//! ([`crate::device`]) or the host ([`crate::host`]); replies go out through [`encode_frame`] into a caller buffer.
//! Nothing here allocates, blocks or reads a clock.
//!
//! Framing rules (SPEC.md, "Serial framing"): the CRC covers the type byte and the payload; COBS removes every
//! 0x00, so 0x00 appears on the wire only as the delimiter. A receiver that starts mid-frame or sees line noise loses
//! at most the frame in progress: the next 0x00 ends it (dropped, counted) and the following frame decodes. Empty
//! frames (0x00 0x00) are idle filler, not errors; senders may send a 0x00 before a frame to flush a peer's partial
//! frame.

use core::marker::PhantomData;

use crate::cobs::{self, max_encoded_len, Step, Unstuffer};

const _: () = assert!(
    MAX_FRAME_LEN < 254,
    "stuff_in_place_short needs frames under 254 bytes"
);
use crate::crc::crc16;
use crate::error::{EncodeError, FrameError, PayloadError, ReportError};
use crate::message::Message;
pub use crate::wire::MAX_FRAME_LEN;
use crate::wire::MAX_PAYLOAD_LEN;

/// Frame delimiter on the wire.
pub const DELIMITER: u8 = 0x00;
/// Largest stuffed frame (without the delimiter).
const MAX_STUFFED_LEN: usize = max_encoded_len(MAX_FRAME_LEN);
/// Largest frame on the wire: stuffed bytes plus the delimiter. An output buffer this big fits any message.
pub const MAX_WIRE_FRAME_LEN: usize = MAX_STUFFED_LEN + 1;

/// Encodes `message` as one serial frame, delimiter included, into `out`; returns the number of bytes written.
///
/// Refuses a message whose fields its decoder would reject (a NaN force, say) with [`EncodeError::Invalid`].
pub fn encode_frame<M: Message>(message: &M, out: &mut [u8]) -> Result<usize, EncodeError> {
    message.validate()?;
    // The whole wire frame is built on the stack, [first code][type][payload][CRC][0x00], and copied out at once
    // (see `cobs::stuff_in_place_short` for why the output is written by one copy).
    let mut wire = [0u8; MAX_WIRE_FRAME_LEN];
    wire[1] = message.message_type();
    let payload_len = match wire[2..].first_chunk_mut::<MAX_PAYLOAD_LEN>() {
        Some(payload) => message.write_payload(payload),
        None => unreachable!("MAX_WIRE_FRAME_LEN leaves room for the largest payload"),
    };
    let crc_at = 2 + payload_len;
    let crc = crc16(&wire[1..crc_at]);
    wire[crc_at..crc_at + 2].copy_from_slice(&crc.to_le_bytes());
    let frame_end = crc_at + 2;
    // COBS adds exactly one byte (the first code) to frames this short; then the delimiter.
    let needed = frame_end + 1;
    let Some(out) = out.get_mut(..needed) else {
        return Err(EncodeError::BufferTooSmall {
            needed,
            available: out.len(),
        });
    };
    wire[0] = cobs::stuff_in_place_short(&mut wire[1..frame_end]);
    wire[frame_end] = DELIMITER;
    out.copy_from_slice(&wire[..needed]);
    Ok(needed)
}

/// Checks the CRC of an unstuffed frame and parses its message.
fn parse_frame<M: Message>(raw: &[u8]) -> Result<M, FrameError> {
    let Some((body, crc_bytes)) = raw.split_last_chunk::<2>() else {
        return Err(FrameError::TooShort { len: raw.len() });
    };
    let Some((&message_type, payload)) = body.split_first() else {
        return Err(FrameError::TooShort { len: raw.len() });
    };
    let received = u16::from_le_bytes(*crc_bytes);
    let computed = crc16(body);
    if received != computed {
        return Err(FrameError::Crc { received, computed });
    }
    Ok(M::read_payload(message_type, payload)?)
}

/// Counts of what a decoder accepted and dropped. Counters wrap only after 2^64 events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DecoderStats {
    /// Messages decoded.
    pub frames_ok: u64,
    /// Frames with broken COBS stuffing.
    pub cobs_errors: u64,
    /// Frames shorter than type plus CRC.
    pub too_short: u64,
    /// Frames longer than any message (skipped to the next delimiter).
    pub oversize: u64,
    /// Frames whose CRC did not match.
    pub crc_errors: u64,
    /// Intact frames with an unknown type byte (perhaps from a newer minor version).
    pub unknown_type: u64,
    /// Intact frames or reports whose payload size does not match their type.
    pub bad_length: u64,
    /// Intact frames or reports with a forbidden value (NaN, infinity, out of range).
    pub invalid_value: u64,
    /// HID reports of the wrong size or report id.
    pub bad_reports: u64,
}

impl DecoderStats {
    /// Total frames and reports dropped, of every kind.
    pub fn dropped(&self) -> u64 {
        self.cobs_errors
            + self.too_short
            + self.oversize
            + self.crc_errors
            + self.unknown_type
            + self.bad_length
            + self.invalid_value
            + self.bad_reports
    }

    fn count_payload(&mut self, error: &PayloadError) {
        let counter = match error {
            PayloadError::UnknownType(_) => &mut self.unknown_type,
            PayloadError::BadLength { .. } => &mut self.bad_length,
            PayloadError::NonFinite { .. } | PayloadError::InvalidValue { .. } => {
                &mut self.invalid_value
            }
        };
        *counter = counter.wrapping_add(1);
    }

    /// Counts the outcome of one serial frame.
    pub fn count_frame<M>(&mut self, result: &Result<M, FrameError>) {
        let counter = match result {
            Ok(_) => &mut self.frames_ok,
            Err(FrameError::Cobs) => &mut self.cobs_errors,
            Err(FrameError::TooShort { .. }) => &mut self.too_short,
            Err(FrameError::Oversize) => &mut self.oversize,
            Err(FrameError::Crc { .. }) => &mut self.crc_errors,
            Err(FrameError::Payload(error)) => return self.count_payload(error),
        };
        *counter = counter.wrapping_add(1);
    }

    /// Counts the outcome of one HID report (for users of [`crate::hid::decode_report`]).
    pub fn count_report<M>(&mut self, result: &Result<M, ReportError>) {
        let counter = match result {
            Ok(_) => &mut self.frames_ok,
            Err(ReportError::BadLength { .. } | ReportError::WrongReportId { .. }) => {
                &mut self.bad_reports
            }
            Err(ReportError::Payload(error)) => return self.count_payload(error),
        };
        *counter = counter.wrapping_add(1);
    }
}

/// Streaming serial decoder for messages of type `M` ([`crate::HostToDevice`] on a device,
/// [`crate::DeviceToHost`] on a host). Holds one frame's worth of bytes (66 stuffed), allocates nothing.
#[derive(Debug, Clone)]
pub struct FrameDecoder<M> {
    unstuffer: Unstuffer<MAX_STUFFED_LEN>,
    stats: DecoderStats,
    message: PhantomData<fn() -> M>,
}

impl<M: Message> Default for FrameDecoder<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<M: Message> FrameDecoder<M> {
    /// A decoder waiting for the start of a frame.
    pub const fn new() -> Self {
        Self {
            unstuffer: Unstuffer::new(),
            stats: DecoderStats::EMPTY,
            message: PhantomData,
        }
    }

    /// Takes one byte. Returns `Some` when the byte was a delimiter that closed a non-empty frame: the message, or
    /// why the frame was dropped (already counted in [`Self::stats`]).
    #[inline]
    pub fn push(&mut self, byte: u8) -> Option<Result<M, FrameError>> {
        let step = self.unstuffer.push(byte);
        self.finish(step)
    }

    /// Turns a closing step into a counted result.
    fn finish(&mut self, step: Step) -> Option<Result<M, FrameError>> {
        let result = match step {
            Step::Continue | Step::Empty => return None,
            Step::Frame(len) => parse_frame(self.unstuffer.frame(len)),
            Step::Oversize => Err(FrameError::Oversize),
            Step::Malformed => Err(FrameError::Cobs),
        };
        self.stats.count_frame(&result);
        Some(result)
    }

    /// Iterates over the frames that `input` completes; bytes of an unfinished frame stay buffered for the next
    /// call. Dropping the iterator early leaves the unread bytes unread (they are not lost from `input`'s owner).
    pub fn feed<'d, 'i>(&'d mut self, input: &'i [u8]) -> Feed<'d, 'i, M> {
        Feed {
            decoder: self,
            input,
        }
    }

    /// What this decoder has accepted and dropped so far.
    pub fn stats(&self) -> &DecoderStats {
        &self.stats
    }

    /// Forgets a partial frame (after reopening a port, say); counters stay.
    pub fn reset(&mut self) {
        self.unstuffer.reset();
    }
}

impl DecoderStats {
    /// All counters zero.
    pub const EMPTY: DecoderStats = DecoderStats {
        frames_ok: 0,
        cobs_errors: 0,
        too_short: 0,
        oversize: 0,
        crc_errors: 0,
        unknown_type: 0,
        bad_length: 0,
        invalid_value: 0,
        bad_reports: 0,
    };
}

/// Iterator returned by [`FrameDecoder::feed`].
#[derive(Debug)]
pub struct Feed<'d, 'i, M> {
    decoder: &'d mut FrameDecoder<M>,
    input: &'i [u8],
}

impl<M> Feed<'_, '_, M> {
    /// Input bytes not yet pushed into the decoder.
    pub fn remaining(&self) -> &[u8] {
        self.input
    }
}

impl<M: Message> Iterator for Feed<'_, '_, M> {
    type Item = Result<M, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.input.is_empty() {
            let (consumed, step) = self.decoder.unstuffer.push_slice(self.input);
            self.input = &self.input[consumed..];
            if let Some(result) = self.decoder.finish(step) {
                return Some(result);
            }
        }
        None
    }
}

/// Outcome of [`decode_frame`] other than a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SliceError {
    /// No delimiter yet: read more bytes and call again with the longer slice.
    #[error("incomplete frame: no delimiter yet")]
    Incomplete,
    /// The first frame was dropped; skip `consumed` bytes and call again.
    #[error("invalid frame ({error}); skip {consumed} bytes")]
    Invalid {
        /// Bytes to discard from the front of the slice (up to and including the frame's delimiter).
        consumed: usize,
        /// Why the frame was dropped.
        error: FrameError,
    },
}

/// Decodes the first frame of a byte slice without keeping state between calls: `Ok((message, consumed))`, or
/// [`SliceError::Incomplete`] when no delimiter has arrived yet, or [`SliceError::Invalid`] with the bytes to skip.
///
/// Leading delimiters are skipped. If a run with no delimiter outgrows the longest frame, it is reported as
/// [`FrameError::Oversize`] with `consumed` = the whole slice (so a caller's buffer never fills with garbage). For a byte stream, prefer
/// [`FrameDecoder`], which does not rescan.
pub fn decode_frame<M: Message>(input: &[u8]) -> Result<(M, usize), SliceError> {
    let mut unstuffer = Unstuffer::<MAX_STUFFED_LEN>::new();
    let mut consumed = 0;
    while consumed < input.len() {
        let (used, step) = unstuffer.push_slice(&input[consumed..]);
        consumed += used;
        let error = match step {
            Step::Continue | Step::Empty => continue,
            Step::Frame(len) => match parse_frame(unstuffer.frame(len)) {
                Ok(message) => return Ok((message, consumed)),
                Err(error) => error,
            },
            Step::Oversize => FrameError::Oversize,
            Step::Malformed => FrameError::Cobs,
        };
        return Err(SliceError::Invalid { consumed, error });
    }
    if unstuffer.is_overflowing() {
        Err(SliceError::Invalid {
            consumed: input.len(),
            error: FrameError::Oversize,
        })
    } else {
        Err(SliceError::Incomplete)
    }
}
