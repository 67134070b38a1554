//! The Falcon's 16-byte frames as a protocol core with no I/O: encoding host frames, decoding device frames, and
//! [`FrameAssembler`], which turns the bytes a port delivers into whole frames, resynchronising on malformed
//! ones. The driver ([`super::falcon`]) owns the port and the clock; this module only sees bytes.
//!
//! Source: libnifalcon src/firmware/FalconFirmwareNovintSDK.cpp:40-97 (frame layout: `<`, three 16-bit values
//! as four nibbles each, least significant first, every nibble plus 0x41, a control/status byte plus 0x41, a
//! spare 0x41, `>`), include/falcon/core/FalconFirmware.h:68-70 (LED bits),
//! include/falcon/firmware/FalconFirmwareNovintSDK.h:29-34 (16 bytes answer 16 bytes; frames start with `<`,
//! end with `>`, and their bytes run from 0x41 to 0x50) and :63-70 (the device's frame).
//!
//! libnifalcon checks only the `<` and `>` of each 16 bytes and, on a malformed frame, steps 16 bytes on
//! (FalconFirmwareNovintSDK.cpp:43, :67-70, :126-132): after one stray byte it never finds a frame again. Here a
//! malformed run is skipped to the next `<`, and the twelve value bytes must also be nibbles plus 0x41 (0x41 to
//! 0x50, as :87-96 encodes them and the header says), so junk that happens to hold a `<` and a `>` sixteen
//! bytes apart is rarely taken for a frame. The status byte (homing bits in 0x10-0x40, FalconFirmwareNovintSDK.h
//! :72-80) and the unknown byte 14 are not checked: the status byte runs past 0x50.

/// Frame length both ways.
pub const FRAME_LEN: usize = 16;
/// Green LED bit.
pub const LED_GREEN: u8 = 0x2;
/// Blue LED bit.
pub const LED_BLUE: u8 = 0x4;
/// Red LED bit.
pub const LED_RED: u8 = 0x8;
/// Homing-mode request bit of the control byte.
pub const HOMING_MODE: u8 = 0x1;
/// All three motors homed.
pub const ALL_HOMED: u8 = 0x7;

/// Encodes a host frame: three motor commands, LED bits and the homing-mode request.
pub fn encode_command(motor: [i16; 3], leds: u8, homing_mode: bool) -> [u8; FRAME_LEN] {
    let mut out = [0u8; FRAME_LEN];
    out[0] = b'<';
    out[15] = b'>';
    for (i, value) in motor.iter().enumerate() {
        let v = *value as u16;
        for nibble in 0..4 {
            out[1 + 4 * i + nibble] = ((v >> (4 * nibble)) & 0xf) as u8;
        }
    }
    out[13] = leds & (LED_GREEN | LED_BLUE | LED_RED);
    if homing_mode {
        out[13] |= HOMING_MODE;
    }
    for byte in &mut out[1..15] {
        *byte += 0x41;
    }
    out
}

/// One decoded device frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FalconReply {
    /// Encoder counts of motors 1-3.
    pub encoders: [i16; 3],
    /// Homing bits of motors 1-3 (bit 0 = motor 1).
    pub homing: u8,
    /// Grip bits.
    pub grip: u8,
}

/// Decodes a device frame; `None` unless it is `<`…`>` (libnifalcon drops such frames as malformed) with its
/// twelve value bytes in 0x41..=0x50 (module docs).
pub fn decode_reply(frame: &[u8; FRAME_LEN]) -> Option<FalconReply> {
    if frame[0] != b'<' || frame[15] != b'>' {
        return None;
    }
    if frame[1..13].iter().any(|b| !(0x41..=0x50).contains(b)) {
        return None;
    }
    let mut encoders = [0i16; 3];
    for (i, encoder) in encoders.iter_mut().enumerate() {
        let mut v = 0u16;
        for nibble in 0..4 {
            v |= u16::from(frame[1 + 4 * i + nibble].wrapping_sub(0x41) & 0xf) << (4 * nibble);
        }
        *encoder = v as i16;
    }
    let status = frame[13].wrapping_sub(0x41);
    Some(FalconReply {
        encoders,
        homing: (status >> 4) & 7,
        grip: status & 0x0f,
    })
}

/// Bytes in, whole device frames out: a fixed 64-byte buffer (no allocation). The caller reads from its port
/// into [`space`](Self::space), reports how many bytes came with [`filled`](Self::filled), and takes frames
/// with [`next_frame`](Self::next_frame).
#[derive(Debug, Clone)]
pub struct FrameAssembler {
    buf: [u8; 64],
    len: usize,
    malformed: u64,
    received: u64,
}

impl Default for FrameAssembler {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameAssembler {
    /// An empty assembler.
    pub const fn new() -> FrameAssembler {
        FrameAssembler {
            buf: [0; 64],
            len: 0,
            malformed: 0,
            received: 0,
        }
    }

    /// Where the next bytes from the port go (never empty after [`next_frame`](Self::next_frame) returned
    /// `None`: fewer than 16 bytes are kept then).
    pub fn space(&mut self) -> &mut [u8] {
        &mut self.buf[self.len..]
    }

    /// `n` bytes were written at the start of [`space`](Self::space).
    pub fn filled(&mut self, n: usize) {
        self.len = (self.len + n).min(self.buf.len());
        self.received = self.received.saturating_add(n as u64);
    }

    /// Bytes taken so far.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Drops every byte held (after the port's input was discarded).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Frames dropped as malformed so far.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    /// The next well-formed frame, or `None` until more bytes come. A 16-byte run that is not `<`…`>` is counted
    /// as malformed and skipped up to the next `<` (libnifalcon drops such frames).
    pub fn next_frame(&mut self) -> Option<FalconReply> {
        while self.len >= FRAME_LEN {
            let mut candidate = [0u8; FRAME_LEN];
            candidate.copy_from_slice(&self.buf[..FRAME_LEN]);
            if let Some(reply) = decode_reply(&candidate) {
                self.buf.copy_within(FRAME_LEN..self.len, 0);
                self.len -= FRAME_LEN;
                return Some(reply);
            }
            self.malformed += 1;
            let skip = self.buf[1..self.len]
                .iter()
                .position(|&b| b == b'<')
                .map_or(self.len, |i| i + 1);
            self.buf.copy_within(skip..self.len, 0);
            self.len -= skip;
        }
        None
    }
}

impl super::assemble::Receive for FrameAssembler {
    fn space(&mut self) -> &mut [u8] {
        FrameAssembler::space(self)
    }
    fn filled(&mut self, n: usize) {
        FrameAssembler::filled(self, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes in any split, with noise before a frame and a frame cut by a stray byte: whole frames come out in
    /// order, each malformed run is counted once.
    #[test]
    fn the_assembler_resynchronises_on_the_next_start_byte() {
        let first = encode_command([1, 2, 3], 0, false);
        let second = encode_command([-4, 5, -6], 0, true);
        let mut stream = vec![0x00, 0x41];
        stream.extend_from_slice(&first);
        stream.extend_from_slice(&second[..7]);
        stream.push(b'x');
        stream.extend_from_slice(&second);
        let mut assembler = FrameAssembler::new();
        let mut out = Vec::new();
        for piece in stream.chunks(5) {
            assembler.space()[..piece.len()].copy_from_slice(piece);
            assembler.filled(piece.len());
            while let Some(reply) = assembler.next_frame() {
                out.push(reply.encoders);
            }
        }
        assert_eq!(out, vec![[1, 2, 3], [-4, 5, -6]]);
        assert!(assembler.malformed() >= 1);
    }

    #[test]
    fn frames_round_trip_through_the_nibble_encoding() {
        let frame = encode_command([-2, 0x1234, i16::MIN], LED_RED, true);
        assert_eq!(frame[0], b'<');
        assert_eq!(frame[15], b'>');
        // -2 = 0xfffe: nibbles e, f, f, f (least significant first), each + 0x41.
        assert_eq!(
            &frame[1..5],
            &[0x41 + 0xe, 0x41 + 0xf, 0x41 + 0xf, 0x41 + 0xf]
        );
        assert_eq!(frame[13], 0x41 + (LED_RED | HOMING_MODE));
        assert_eq!(frame[14], 0x41);
        assert!(frame[1..15].iter().all(|b| (0x41..=0x50).contains(b)));
        let reply = decode_reply(&frame).unwrap();
        assert_eq!(reply.encoders, [-2, 0x1234, i16::MIN]);
        let mut bad = frame;
        bad[15] = b'x';
        assert!(decode_reply(&bad).is_none());
        // A value byte outside the nibble range (FalconFirmwareNovintSDK.h:33-34: bytes run 0x41 to 0x50).
        let mut bad = frame;
        bad[5] = 0x51;
        assert!(decode_reply(&bad).is_none());
        // The status byte is not a nibble: homing bits 0x10-0x40 (FalconFirmwareNovintSDK.h:78-80) and the
        // grip (0x0f) give 0x41 + 0x7f.
        let mut homed = frame;
        homed[13] = 0x41 + 0x7f;
        assert_eq!(
            decode_reply(&homed).map(|r| (r.homing, r.grip)),
            Some((7, 0xf))
        );
    }
}
