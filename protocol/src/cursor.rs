//! Little-endian cursors over a payload buffer and the field checks every message's decoder shares.
//!
//! Where it sits: under [`crate::message`] and [`crate::local`], which both lay out payloads with these; it
//! depends only on [`crate::wire`] and [`crate::error`].

use crate::error::PayloadError;
use crate::wire::MAX_PAYLOAD_LEN;

pub(crate) struct Writer<'a> {
    out: &'a mut [u8; MAX_PAYLOAD_LEN],
    pub(crate) pos: usize,
}

impl<'a> Writer<'a> {
    pub(crate) fn new(out: &'a mut [u8; MAX_PAYLOAD_LEN]) -> Self {
        Self { out, pos: 0 }
    }
    pub(crate) fn bytes<const N: usize>(&mut self, bytes: [u8; N]) {
        self.out[self.pos..self.pos + N].copy_from_slice(&bytes);
        self.pos += N;
    }
    pub(crate) fn u8(&mut self, value: u8) {
        self.bytes([value]);
    }
    pub(crate) fn u16(&mut self, value: u16) {
        self.bytes(value.to_le_bytes());
    }
    pub(crate) fn u32(&mut self, value: u32) {
        self.bytes(value.to_le_bytes());
    }
    pub(crate) fn u64(&mut self, value: u64) {
        self.bytes(value.to_le_bytes());
    }
    pub(crate) fn f32(&mut self, value: f32) {
        self.bytes(value.to_le_bytes());
    }
    pub(crate) fn vec3(&mut self, value: [f32; 3]) {
        value.into_iter().for_each(|v| self.f32(v));
    }
}

/// Reads a payload whose length the caller has checked against the layout.
pub(crate) struct Reader<'a> {
    payload: &'a [u8],
    pub(crate) pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(payload: &'a [u8]) -> Self {
        Self { payload, pos: 0 }
    }
    pub(crate) fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.payload[self.pos..self.pos + N]);
        self.pos += N;
        out
    }
    pub(crate) fn u8(&mut self) -> u8 {
        self.bytes::<1>()[0]
    }
    pub(crate) fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.bytes())
    }
    pub(crate) fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    pub(crate) fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.bytes())
    }
    pub(crate) fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.bytes())
    }
    pub(crate) fn vec3(&mut self) -> [f32; 3] {
        [self.f32(), self.f32(), self.f32()]
    }
}

pub(crate) fn check_length(
    message_type: u8,
    expected: Option<usize>,
    actual: usize,
) -> Result<(), PayloadError> {
    match expected {
        None => Err(PayloadError::UnknownType(message_type)),
        Some(expected) if expected != actual => Err(PayloadError::BadLength {
            message_type,
            expected,
            actual,
        }),
        Some(_) => Ok(()),
    }
}

pub(crate) fn finite(
    message_type: u8,
    field: &'static str,
    values: &[f32],
) -> Result<(), PayloadError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(PayloadError::NonFinite {
            message_type,
            field,
        })
    }
}

pub(crate) fn in_range(
    message_type: u8,
    field: &'static str,
    ok: bool,
) -> Result<(), PayloadError> {
    if ok {
        Ok(())
    } else {
        Err(PayloadError::InvalidValue {
            message_type,
            field,
        })
    }
}
