//! Receive cores with no I/O and no clock: bytes in, whole replies out, each in a fixed buffer (no allocation).
//! A driver's runner ([`super::exchange`]) reads from its port into [`Receive::space`], reports the count with
//! [`Receive::filled`], and takes whole replies with the core's own `next_*` method.
//!
//! - [`FixedAssembler`]: replies of a fixed length with no marker (the Haply 2DIY board's `[device id][f32 f32]`,
//!   Haply-API-cpp src/Haply/Board.cpp `receive`, which reads exactly `1 + 4 * n` bytes);
//! - [`LineAssembler`]: text lines ended by `\n` (the WoodenHaptics Teensy firmware's `Serial.println` reports);
//! - the Falcon's frames have their own ([`super::falcon_frames::FrameAssembler`]).

/// A receive core the shared runner ([`super::exchange::receive_within`]) reads into.
pub trait Receive {
    /// Where the next bytes from the port go. Empty only when the core holds a whole reply not taken yet.
    fn space(&mut self) -> &mut [u8];
    /// `n` bytes were written at the start of [`space`](Self::space).
    fn filled(&mut self, n: usize);
}

/// A fixed buffer and how many bytes at its start are held: what each core reads into.
#[derive(Debug, Clone)]
struct Buffer<const N: usize> {
    bytes: [u8; N],
    len: usize,
}

impl<const N: usize> Default for Buffer<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Buffer<N> {
    const fn new() -> Self {
        Buffer {
            bytes: [0; N],
            len: 0,
        }
    }

    /// The part after the bytes held ([`Receive::space`]).
    fn space(&mut self) -> &mut [u8] {
        &mut self.bytes[self.len..]
    }

    /// `n` bytes were written at the start of [`space`](Self::space) ([`Receive::filled`]).
    fn filled(&mut self, n: usize) {
        self.len = (self.len + n).min(N);
    }
}

/// Bytes in, replies of exactly `N` bytes out.
#[derive(Debug, Clone, Default)]
pub struct FixedAssembler<const N: usize> {
    buf: Buffer<N>,
}

impl<const N: usize> FixedAssembler<N> {
    /// An empty assembler.
    pub const fn new() -> Self {
        FixedAssembler { buf: Buffer::new() }
    }

    /// Bytes held of a reply not complete yet.
    pub fn held(&self) -> usize {
        self.buf.len
    }

    /// Drops every byte held (the port's input was discarded, or the driver resynchronises).
    pub fn clear(&mut self) {
        self.buf.len = 0;
    }

    /// The next whole reply, or `None` until more bytes come.
    pub fn next_reply(&mut self) -> Option<[u8; N]> {
        if self.buf.len == N {
            self.buf.len = 0;
            Some(self.buf.bytes)
        } else {
            None
        }
    }
}

impl<const N: usize> Receive for FixedAssembler<N> {
    /// Never more than the rest of one reply, so bytes of the next stay in the port.
    fn space(&mut self) -> &mut [u8] {
        self.buf.space()
    }

    fn filled(&mut self, n: usize) {
        self.buf.filled(n);
    }
}

/// What [`LineAssembler::next_line`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Line<'a> {
    /// A whole line, without its `\n`.
    Whole(&'a [u8]),
    /// `N` bytes came without a `\n`: they were dropped (the caller reports it).
    TooLong,
}

/// Bytes in, `\n`-ended lines out, at most `N` bytes each.
#[derive(Debug, Clone, Default)]
pub struct LineAssembler<const N: usize> {
    buf: Buffer<N>,
    /// Bytes of the line handed out last, removed on the next call.
    taken: usize,
}

impl<const N: usize> LineAssembler<N> {
    /// An empty assembler.
    pub const fn new() -> Self {
        LineAssembler {
            buf: Buffer::new(),
            taken: 0,
        }
    }

    /// Drops every byte held.
    pub fn clear(&mut self) {
        self.buf.len = 0;
        self.taken = 0;
    }

    fn forget_taken(&mut self) {
        if self.taken > 0 {
            self.buf.bytes.copy_within(self.taken..self.buf.len, 0);
            self.buf.len -= self.taken;
            self.taken = 0;
        }
    }

    /// The next whole line, [`Line::TooLong`] when `N` bytes held no `\n` (they are dropped), or `None` until
    /// more bytes come.
    pub fn next_line(&mut self) -> Option<Line<'_>> {
        self.forget_taken();
        let held = &self.buf.bytes[..self.buf.len];
        if let Some(end) = held.iter().position(|&b| b == b'\n') {
            self.taken = end + 1;
            return Some(Line::Whole(&self.buf.bytes[..end]));
        }
        if self.buf.len == N {
            self.buf.len = 0;
            return Some(Line::TooLong);
        }
        None
    }
}

impl<const N: usize> Receive for LineAssembler<N> {
    fn space(&mut self) -> &mut [u8] {
        self.forget_taken();
        self.buf.space()
    }

    fn filled(&mut self, n: usize) {
        self.buf.filled(n);
    }
}

#[cfg(test)]
#[path = "assemble_tests.rs"]
mod tests;
