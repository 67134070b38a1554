//! COBS (Consistent Overhead Byte Stuffing) for the serial link: removes every 0x00 from a frame so that 0x00 can
//! delimit frames, and a receiver that starts mid-stream or sees garbage resynchronises at the next 0x00.
//!
//! Where it sits: [`crate::serial`] stuffs `type ‖ payload ‖ crc` with [`encode`] and appends the 0x00 delimiter;
//! its `FrameDecoder` unstuffs byte by byte with [`Unstuffer`] as bytes arrive, so no second pass is needed.
//!
//! The scheme (Cheshire and Baker, 1999): the data is cut at every zero into blocks; each block is sent as a code
//! byte `n` (1..=255) followed by `n - 1` non-zero data bytes. A code below 0xFF means "a zero followed this block"
//! (except after the last block, where the zero is implied by the end of the frame); 0xFF means "254 data bytes and
//! no zero" (long runs). Overhead is at most one byte per 254 plus one, so a frame of `n` bytes stuffs to at most
//! [`max_encoded_len`]`(n)` bytes.

/// Largest stuffed size of `raw_len` unstuffed bytes (without the delimiter).
pub const fn max_encoded_len(raw_len: usize) -> usize {
    raw_len + raw_len / 254 + 1
}

/// Stuff `input` into `out` and return the stuffed length, or `None` if `out` is shorter than
/// [`max_encoded_len`]`(input.len())`. The output contains no 0x00; the caller appends the delimiter.
pub fn encode(input: &[u8], out: &mut [u8]) -> Option<usize> {
    if out.len() < max_encoded_len(input.len()) {
        return None;
    }
    let mut code_index = 0;
    let mut write = 1;
    let mut code: u8 = 1;
    for &byte in input {
        if byte == 0 {
            out[code_index] = code;
            code_index = write;
            write += 1;
            code = 1;
        } else {
            out[write] = byte;
            write += 1;
            code += 1;
            if code == 0xFF {
                out[code_index] = code;
                code_index = write;
                write += 1;
                code = 1;
            }
        }
    }
    out[code_index] = code;
    Some(write)
}

/// What one pushed byte did to the [`Unstuffer`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Step {
    /// Inside a frame; nothing to report yet.
    Continue,
    /// A delimiter with no bytes since the previous one (idle line or a sync byte). Not an error.
    Empty,
    /// A delimiter closed a well-formed frame of this many unstuffed bytes, now at the start of the buffer.
    Frame(usize),
    /// A delimiter closed a frame whose unstuffed bytes did not fit the buffer; the frame was dropped.
    Oversize,
    /// A delimiter arrived inside a block (the code byte promised more data): garbage or a lost byte.
    Malformed,
}

/// Streaming COBS decoder with a fixed buffer of `N` unstuffed bytes. No allocation.
#[derive(Debug, Clone)]
pub(crate) struct Unstuffer<const N: usize> {
    buf: [u8; N],
    len: usize,
    /// Data bytes still expected in the current block.
    remaining: u8,
    /// The previous block had a code below 0xFF: if another block follows, a zero goes first.
    pending_zero: bool,
    /// At least one byte arrived since the last delimiter.
    started: bool,
    /// The unstuffed frame outgrew the buffer; bytes are skipped until the delimiter.
    overflow: bool,
}

impl<const N: usize> Unstuffer<N> {
    pub(crate) const fn new() -> Self {
        Self { buf: [0; N], len: 0, remaining: 0, pending_zero: false, started: false, overflow: false }
    }

    /// The unstuffed bytes of the frame that the last [`Step::Frame`] reported.
    pub(crate) fn frame(&self, len: usize) -> &[u8] {
        &self.buf[..len.min(N)]
    }

    /// Forget any partial frame (the next byte starts a new frame).
    pub(crate) fn reset(&mut self) {
        self.len = 0;
        self.remaining = 0;
        self.pending_zero = false;
        self.started = false;
        self.overflow = false;
    }

    #[inline]
    pub(crate) fn push(&mut self, byte: u8) -> Step {
        if byte == 0 {
            let step = if !self.started {
                Step::Empty
            } else if self.overflow {
                Step::Oversize
            } else if self.remaining != 0 {
                Step::Malformed
            } else {
                Step::Frame(self.len)
            };
            self.reset();
            return step;
        }
        self.started = true;
        if self.overflow {
            return Step::Continue;
        }
        if self.remaining == 0 {
            if self.pending_zero {
                self.put(0);
            }
            self.remaining = byte - 1;
            self.pending_zero = byte != 0xFF;
        } else {
            self.put(byte);
            self.remaining -= 1;
        }
        Step::Continue
    }

    #[inline]
    fn put(&mut self, byte: u8) {
        if self.len < N {
            self.buf[self.len] = byte;
            self.len += 1;
        } else {
            self.overflow = true;
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use proptest::prelude::*;
    use std::vec;
    use std::vec::Vec;

    fn stuff(input: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8; max_encoded_len(input.len())];
        let len = encode(input, &mut out).expect("buffer sized by max_encoded_len");
        out.truncate(len);
        out
    }

    fn unstuff<const N: usize>(stuffed: &[u8]) -> Result<Vec<u8>, Step> {
        let mut decoder = Unstuffer::<N>::new();
        for &byte in stuffed {
            assert_eq!(decoder.push(byte), Step::Continue);
        }
        match decoder.push(0) {
            Step::Frame(len) => Ok(decoder.frame(len).to_vec()),
            other => Err(other),
        }
    }

    #[test]
    fn known_examples_from_the_cobs_paper() {
        // Examples as listed on the Wikipedia COBS page.
        assert_eq!(stuff(&[0x00]), [0x01, 0x01]);
        assert_eq!(stuff(&[0x00, 0x00]), [0x01, 0x01, 0x01]);
        assert_eq!(stuff(&[0x00, 0x11, 0x00]), [0x01, 0x02, 0x11, 0x01]);
        assert_eq!(stuff(&[0x11, 0x22, 0x00, 0x33]), [0x03, 0x11, 0x22, 0x02, 0x33]);
        assert_eq!(stuff(&[0x11, 0x22, 0x33, 0x44]), [0x05, 0x11, 0x22, 0x33, 0x44]);
        assert_eq!(stuff(&[0x11, 0x00, 0x00, 0x00]), [0x02, 0x11, 0x01, 0x01, 0x01]);
        let run: Vec<u8> = (1..=254).collect();
        let mut expected = vec![0xFF];
        expected.extend_from_slice(&run);
        expected.push(0x01);
        assert_eq!(stuff(&run), expected);
    }

    #[test]
    fn too_small_output_is_refused() {
        let mut out = [0u8; 3];
        assert_eq!(encode(&[1, 2, 3], &mut out), None);
    }

    #[test]
    fn delimiter_inside_a_block_is_malformed() {
        let mut decoder = Unstuffer::<16>::new();
        assert_eq!(decoder.push(0x05), Step::Continue);
        assert_eq!(decoder.push(0x11), Step::Continue);
        assert_eq!(decoder.push(0x00), Step::Malformed);
        // And the next frame decodes cleanly.
        for &byte in &[0x02, 0x11, 0x01] {
            assert_eq!(decoder.push(byte), Step::Continue);
        }
        assert_eq!(decoder.push(0x00), Step::Frame(2));
        assert_eq!(decoder.frame(2), &[0x11, 0x00]);
    }

    #[test]
    fn repeated_delimiters_are_empty_frames() {
        let mut decoder = Unstuffer::<4>::new();
        assert_eq!(decoder.push(0), Step::Empty);
        assert_eq!(decoder.push(0), Step::Empty);
    }

    proptest! {
        #[test]
        fn round_trip(input in proptest::collection::vec(any::<u8>(), 0..600)) {
            let stuffed = stuff(&input);
            prop_assert!(!stuffed.contains(&0));
            prop_assert!(stuffed.len() <= max_encoded_len(input.len()));
            prop_assert_eq!(unstuff::<600>(&stuffed), Ok(input));
        }

        #[test]
        fn oversize_is_reported_not_truncated(input in proptest::collection::vec(any::<u8>(), 17..100)) {
            prop_assert_eq!(unstuff::<16>(&stuff(&input)), Err(Step::Oversize));
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut decoder = Unstuffer::<16>::new();
            for byte in bytes {
                if let Step::Frame(len) = decoder.push(byte) {
                    prop_assert!(len <= 16);
                }
            }
        }
    }
}
