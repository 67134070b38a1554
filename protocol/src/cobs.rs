//! COBS (Consistent Overhead Byte Stuffing) for the serial link: removes every 0x00 from a frame so that 0x00 can
//! delimit frames, and a receiver that starts mid-stream or sees garbage resynchronises at the next 0x00.
//!
//! Where it sits: [`crate::serial`] stuffs `type ‖ payload ‖ crc` in place (`stuff_in_place_short`, same bytes as
//! [`encode`]) and appends the 0x00 delimiter; its `FrameDecoder` collects stuffed bytes in an `Unstuffer` and
//! unstuffs each frame in place when its delimiter arrives. Both directions avoid a data-dependent branch per byte
//! (see the notes on each function): where the zeros of a payload fall is unpredictable, and mispredicted branches
//! were the largest cost of the byte-at-a-time versions that these replace.
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
    if input.len() < 254 {
        return Some(encode_short(input, out));
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

/// [`encode`] for inputs shorter than 254 bytes (every frame of this protocol), where no block can reach the
/// 254-byte limit. The mirror image of [`Unstuffer`]'s in-place decoding: the stuffed frame is the input shifted
/// right by one, with a code byte at position 0 and wherever a zero stood, each code being the distance to the
/// next code slot (or to the end). So: one copy, then a bit mask of where the zeros are (see [`zero_mask`]) and one
/// loop iteration per zero to write the codes. Where the zeros fall is unpredictable, so a test-and-branch per byte
/// would mispredict at every zero, and that would be the expensive part.
fn encode_short(input: &[u8], out: &mut [u8]) -> usize {
    let end = input.len() + 1;
    out[1..end].copy_from_slice(input);
    let mut slot = 0usize;
    for (segment_index, segment) in input.chunks(64).enumerate() {
        let mut zeros = zero_mask(segment);
        while zeros != 0 {
            let next_slot = segment_index * 64 + zeros.trailing_zeros() as usize + 1;
            // next_slot - slot <= 254 for inputs shorter than 254 bytes.
            out[slot] = (next_slot - slot) as u8;
            slot = next_slot;
            zeros &= zeros - 1;
        }
    }
    out[slot] = (end - slot) as u8;
    end
}

/// Stuffs a short frame (under 254 bytes) that the caller owns: the zeros of `frame` are overwritten with their
/// codes, and the first code is returned; the stuffed frame is then `first code ‖ frame`. Used by the serial
/// encoder so that its output buffer is written by one plain copy: patching code bytes into the output instead
/// leaves byte-sized stores in flight that a reader of the fresh frame (the decoder, in a loopback) would load as
/// words, which stalls store forwarding.
pub(crate) fn stuff_in_place_short(frame: &mut [u8]) -> u8 {
    debug_assert!(frame.len() < 254);
    let end = frame.len() + 1;
    let mut first_code = 0u8;
    let mut slot = 0usize;
    for segment_index in 0..frame.len().div_ceil(64) {
        let segment_start = segment_index * 64;
        let segment = &frame[segment_start..frame.len().min(segment_start + 64)];
        let mut zeros = zero_mask(segment);
        while zeros != 0 {
            let next_slot = segment_start + zeros.trailing_zeros() as usize + 1;
            // next_slot - slot <= 254 for frames shorter than 254 bytes.
            let code = (next_slot - slot) as u8;
            match slot.checked_sub(1) {
                Some(at) => frame[at] = code,
                None => first_code = code,
            }
            slot = next_slot;
            zeros &= zeros - 1;
        }
    }
    let code = (end - slot) as u8;
    match slot.checked_sub(1) {
        Some(at) => frame[at] = code,
        None => first_code = code,
    }
    first_code
}

/// Bit `i` set where `segment[i] == 0`, for a segment of at most 64 bytes, eight bytes at a time without branches:
/// `((v & 0x7F..) + 0x7F..) | v` has the top bit of each byte set exactly when the byte is non-zero (no carry crosses
/// a byte), and multiplying the inverted top bits (moved to bit 0 of each byte) by 0x0102040810204080 gathers them
/// into the top byte, bit `k` for byte `k` (the partial products never overlap).
fn zero_mask(segment: &[u8]) -> u64 {
    const LOW7: u64 = 0x7F7F_7F7F_7F7F_7F7F;
    const GATHER: u64 = 0x0102_0408_1020_4080;
    let mut mask = 0u64;
    for (chunk_index, chunk) in segment.chunks(8).enumerate().take(8) {
        let word = match chunk.first_chunk::<8>() {
            Some(word) => *word,
            None => {
                let mut padded = [0xFFu8; 8]; // non-zero padding: never reported
                padded[..chunk.len()].copy_from_slice(chunk);
                padded
            }
        };
        let v = u64::from_le_bytes(word);
        let zero_tops = !(((v & LOW7) + LOW7) | v) & !LOW7;
        let bits = (zero_tops >> 7).wrapping_mul(GATHER) >> 56;
        mask |= bits << (chunk_index * 8);
    }
    mask
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

/// Index of the first zero byte, eight bytes at a time: in `v - 0x01..01`, a zero byte borrows and sets its top bit,
/// and `& !v` drops bytes whose top bit was already set; the lowest flagged byte is the first zero (a borrow can
/// only flag bytes above a true zero). Same answer as `position(|&b| b == 0)`, several times faster.
fn find_zero(bytes: &[u8]) -> Option<usize> {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const TOPS: u64 = 0x8080_8080_8080_8080;
    let mut chunks = bytes.chunks_exact(8);
    let mut offset = 0;
    for chunk in &mut chunks {
        if let Some(word) = chunk.first_chunk::<8>() {
            let v = u64::from_le_bytes(*word);
            let flags = v.wrapping_sub(ONES) & !v & TOPS;
            if flags != 0 {
                return Some(offset + (flags.trailing_zeros() / 8) as usize);
            }
        }
        offset += 8;
    }
    chunks
        .remainder()
        .iter()
        .position(|&b| b == 0)
        .map(|index| offset + index)
}

/// Streaming COBS decoder for short frames: holds up to `S` stuffed bytes (so frames of up to `S - 1` unstuffed
/// bytes; `S` <= 254, so that no block can reach the 254-byte limit) and allocates nothing.
///
/// It works in two phases, both without a branch per byte that depends on the data. While bytes arrive it only looks
/// for the delimiter (eight bytes at a time) and copies runs of stuffed bytes into its buffer. At the delimiter it
/// unstuffs in place: for a frame whose blocks are all shorter than 254 bytes, the unstuffed bytes are the stuffed
/// bytes shifted left by one, with a zero wherever a code byte stood. The copy already stores each byte one place
/// left, so only a walk along the chain of code bytes (each code is the distance to the next) remains, writing the
/// zeros; the frame is well formed exactly when the chain ends on the last byte. (A per-byte state machine was measured at 2-3 times slower, because where the zeros of a
/// payload fall is unpredictable and each block end was a mispredicted branch.)
#[derive(Debug, Clone)]
pub(crate) struct Unstuffer<const S: usize> {
    /// Stuffed bytes 1.. of the frame in progress, each stored one place left of its stuffed position, which is
    /// where its unstuffed byte belongs (so no shift is needed at the delimiter). The last slot is never used.
    buf: [u8; S],
    /// Stuffed byte 0, the first code.
    first_code: u8,
    /// Stuffed bytes of the frame in progress; `S + 1` once it overflowed (then it stays so until the delimiter).
    len: usize,
}

impl<const S: usize> Unstuffer<S> {
    pub(crate) const fn new() -> Self {
        const {
            assert!(
                S >= 2 && S <= 254,
                "Unstuffer handles stuffed frames of 2..=254 bytes"
            )
        };
        Self {
            buf: [0; S],
            first_code: 0,
            len: 0,
        }
    }

    /// The unstuffed bytes of the frame that the last [`Step::Frame`] reported.
    pub(crate) fn frame(&self, len: usize) -> &[u8] {
        &self.buf[..len.min(S)]
    }

    /// Forget any partial frame (the next byte starts a new frame).
    pub(crate) fn reset(&mut self) {
        self.len = 0;
    }

    /// True while the frame in progress has outgrown the buffer (it will be reported as oversize).
    pub(crate) fn is_overflowing(&self) -> bool {
        self.len > S
    }

    /// Pushes one byte.
    #[inline]
    pub(crate) fn push(&mut self, byte: u8) -> Step {
        self.push_slice(core::slice::from_ref(&byte)).1
    }

    /// Pushes bytes from `input` until one of them closes a frame (a delimiter) or the input runs out; returns how
    /// many bytes were consumed and the last step (`Continue` if the input ran out inside a frame).
    #[inline]
    pub(crate) fn push_slice(&mut self, input: &[u8]) -> (usize, Step) {
        match find_zero(input) {
            None => {
                self.append(input);
                (input.len(), Step::Continue)
            }
            Some(delimiter) => {
                self.append(&input[..delimiter]);
                let step = self.close();
                self.reset();
                (delimiter + 1, step)
            }
        }
    }

    fn append(&mut self, mut run: &[u8]) {
        if self.len == 0 {
            let Some((&first, rest)) = run.split_first() else {
                return;
            };
            self.first_code = first;
            self.len = 1;
            run = rest;
        }
        if self.len > S {
            return;
        }
        // Stuffed positions len.. go to buf[len - 1..]; at most S stuffed bytes in all.
        match self.buf[..S - 1].get_mut(self.len - 1..self.len - 1 + run.len()) {
            Some(slot) => {
                slot.copy_from_slice(run);
                self.len += run.len();
            }
            None => self.len = S + 1,
        }
    }

    /// Unstuffs the collected bytes in place at a delimiter.
    fn close(&mut self) -> Step {
        let len = self.len;
        if len == 0 {
            return Step::Empty;
        }
        if len > S {
            return Step::Oversize;
        }
        let mut code_at = usize::from(self.first_code);
        // The code byte at stuffed position p sits at p - 1, exactly where its implied zero belongs.
        while code_at < len {
            let next = code_at + usize::from(self.buf[code_at - 1]);
            self.buf[code_at - 1] = 0;
            code_at = next;
        }
        if code_at == len {
            Step::Frame(len - 1)
        } else {
            Step::Malformed
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

    fn unstuff<const S: usize>(stuffed: &[u8]) -> Result<Vec<u8>, Step> {
        let mut decoder = Unstuffer::<S>::new();
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
        assert_eq!(
            stuff(&[0x11, 0x22, 0x00, 0x33]),
            [0x03, 0x11, 0x22, 0x02, 0x33]
        );
        assert_eq!(
            stuff(&[0x11, 0x22, 0x33, 0x44]),
            [0x05, 0x11, 0x22, 0x33, 0x44]
        );
        assert_eq!(
            stuff(&[0x11, 0x00, 0x00, 0x00]),
            [0x02, 0x11, 0x01, 0x01, 0x01]
        );
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
        let mut decoder = Unstuffer::<17>::new();
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
        fn round_trip(input in proptest::collection::vec(any::<u8>(), 0..254)) {
            let stuffed = stuff(&input);
            prop_assert!(!stuffed.contains(&0));
            prop_assert!(stuffed.len() <= max_encoded_len(input.len()));
            prop_assert_eq!(unstuff::<254>(&stuffed), Ok(input));
        }

        #[test]
        fn short_encoder_matches_the_general_one(input in proptest::collection::vec(
            prop_oneof![Just(0u8), any::<u8>()], 0..254)) {
            let mut general = vec![0u8; max_encoded_len(input.len())];
            // The general loop, as `encode` runs it for long inputs.
            let mut code_index = 0;
            let mut write = 1;
            let mut code: u8 = 1;
            for &byte in &input {
                if byte == 0 {
                    general[code_index] = code;
                    code_index = write;
                    write += 1;
                    code = 1;
                } else {
                    general[write] = byte;
                    write += 1;
                    code += 1;
                }
            }
            general[code_index] = code;
            general.truncate(write);
            prop_assert_eq!(stuff(&input), general);
        }

        #[test]
        fn long_inputs_round_trip_through_the_general_encoder(input in proptest::collection::vec(
            prop_oneof![Just(0u8), 1u8..=255], 254..700)) {
            // Decode with the reference rules (the streaming decoder is for short frames only).
            let stuffed = stuff(&input);
            prop_assert!(!stuffed.contains(&0));
            let mut decoded = Vec::new();
            let mut at = 0;
            while at < stuffed.len() {
                let code = usize::from(stuffed[at]);
                decoded.extend_from_slice(&stuffed[at + 1..at + code]);
                at += code;
                if code < 0xFF && at < stuffed.len() {
                    decoded.push(0);
                }
            }
            prop_assert_eq!(decoded, input);
        }

        #[test]
        fn oversize_is_reported_not_truncated(input in proptest::collection::vec(any::<u8>(), 16..100)) {
            prop_assert_eq!(unstuff::<16>(&stuff(&input)), Err(Step::Oversize));
        }

        #[test]
        fn in_place_stuffing_matches_encode(input in proptest::collection::vec(
            prop_oneof![Just(0u8), any::<u8>()], 0..254)) {
            let mut frame = input.clone();
            let first_code = stuff_in_place_short(&mut frame);
            let mut stuffed = vec![first_code];
            stuffed.extend_from_slice(&frame);
            prop_assert_eq!(stuffed, stuff(&input));
        }

        #[test]
        fn zero_mask_marks_exactly_the_zeros(bytes in proptest::collection::vec(
            prop_oneof![Just(0u8), Just(1u8), Just(0x80u8), Just(0x7Fu8), Just(0xFFu8), any::<u8>()], 0..=64)) {
            let expected = bytes.iter().enumerate().fold(0u64, |m, (i, &b)| m | (u64::from(b == 0) << i));
            prop_assert_eq!(zero_mask(&bytes), expected);
        }

        #[test]
        fn find_zero_matches_position(bytes in proptest::collection::vec(
            prop_oneof![Just(0u8), Just(1u8), Just(0x80u8), Just(0xFFu8), any::<u8>()], 0..100)) {
            prop_assert_eq!(find_zero(&bytes), bytes.iter().position(|&b| b == 0));
        }

        #[test]
        fn push_slice_matches_push(bytes in proptest::collection::vec(
            prop_oneof![Just(0u8), 1u8..6, any::<u8>()], 0..300)) {
            let mut bytewise = Unstuffer::<16>::new();
            let mut expected = Vec::new();
            for &byte in &bytes {
                match bytewise.push(byte) {
                    Step::Continue => {}
                    Step::Frame(len) => expected.push(Ok(bytewise.frame(len).to_vec())),
                    step => expected.push(Err(step)),
                }
            }
            let mut sliced = Unstuffer::<16>::new();
            let mut got = Vec::new();
            let mut rest = &bytes[..];
            while !rest.is_empty() {
                let (consumed, step) = sliced.push_slice(rest);
                prop_assert!(consumed > 0);
                rest = &rest[consumed..];
                match step {
                    Step::Continue => prop_assert!(rest.is_empty()),
                    Step::Frame(len) => got.push(Ok(sliced.frame(len).to_vec())),
                    step => got.push(Err(step)),
                }
            }
            prop_assert_eq!(got, expected);
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut decoder = Unstuffer::<16>::new();
            for byte in bytes {
                if let Step::Frame(len) = decoder.push(byte) {
                    prop_assert!(len < 16);
                }
            }
        }
    }
}
