//! The wire format (SPEC sections 3 and 4), written from the text: type bytes, status, fault and reject codes,
//! payload sizes, CRC-16/CCITT-FALSE, COBS, frames and the payload fields.

// ---------------------------------------------------------------------------------------------------------------
// Wire format (SPEC sections 3 and 4), written from the text.

/// Message type bytes (SPEC section 3).
pub mod types {
    pub const HELLO: u8 = 0x01;
    pub const ENABLE: u8 = 0x02;
    pub const DISABLE: u8 = 0x03;
    pub const SET_FORCE: u8 = 0x04;
    pub const HEARTBEAT: u8 = 0x05;
    pub const CLEAR_FAULT: u8 = 0x06;
    pub const SET_STATE_RATE: u8 = 0x07;
    pub const DEVICE_INFO: u8 = 0x81;
    pub const STATE: u8 = 0x82;
    pub const HEARTBEAT_REPLY: u8 = 0x83;
    pub const FAULT: u8 = 0x84;
    pub const REJECTED: u8 = 0x85;
}

/// Status bits (SPEC section 6.1).
pub mod status {
    pub const SESSION_OPEN: u16 = 1 << 0;
    pub const ENABLED: u16 = 1 << 1;
    pub const FAULTED: u16 = 1 << 2;
    pub const WATCHDOG_TRIPPED: u16 = 1 << 3;
    pub const FORCE_CLAMPED: u16 = 1 << 4;
    pub const LOCKSTEP: u16 = 1 << 5;
}

/// Fault codes (SPEC section 3.2).
pub mod fault {
    pub const WATCHDOG_EXPIRED: u8 = 0;
    pub const EMERGENCY_STOP: u8 = 1;
    pub const OVER_CURRENT: u8 = 3;
}

/// Reject reasons (SPEC section 3.2).
pub mod reject {
    pub const NO_SESSION: u8 = 1;
    pub const VERSION_MISMATCH: u8 = 2;
    pub const FAULTED: u8 = 3;
    pub const INVALID_ARGUMENT: u8 = 4;
}

/// Payload size of each type (SPEC section 3), `None` for a type this direction does not know.
pub fn payload_len(message_type: u8) -> Option<usize> {
    Some(match message_type {
        types::HELLO => 2,
        types::ENABLE => 4,
        types::DISABLE => 0,
        types::SET_FORCE => 18,
        types::HEARTBEAT => 4,
        types::CLEAR_FAULT => 0,
        types::SET_STATE_RATE => 2,
        types::DEVICE_INFO => 62,
        types::STATE => 46,
        types::HEARTBEAT_REPLY => 14,
        types::FAULT => 11,
        types::REJECTED => 2,
        _ => return None,
    })
}

/// CRC-16/CCITT-FALSE, table-driven exactly as SPEC section 4.2 spells it (16-bit masks included).
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut table = [0u32; 256];
    for (i, entry) in table.iter_mut().enumerate() {
        let mut t = (i as u32) << 8;
        for _ in 0..8 {
            t = if t & 0x8000 != 0 {
                ((t << 1) ^ 0x1021) & 0xFFFF
            } else {
                (t << 1) & 0xFFFF
            };
        }
        *entry = t;
    }
    let mut crc: u32 = 0xFFFF;
    for &b in bytes {
        crc = ((crc << 8) & 0xFFFF) ^ table[(((crc >> 8) ^ u32::from(b)) & 0xFF) as usize];
    }
    crc as u16
}

/// COBS-stuffs `raw` (SPEC section 4.2); the result has no 0x00 and no delimiter.
pub fn cobs_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(raw.len() + 2);
    for piece in raw.split(|&b| b == 0) {
        // Frames here are far below 254 bytes, so every piece fits one code byte.
        assert!(
            piece.len() < 254,
            "pieces of 254 bytes never occur in this protocol"
        );
        out.push(piece.len() as u8 + 1);
        out.extend_from_slice(piece);
    }
    out
}

/// Unstuffs one frame (the bytes between delimiters), or `None` when the chain of codes is broken.
pub fn cobs_decode(stuffed: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(stuffed.len());
    let mut at = 0;
    while at < stuffed.len() {
        let code = usize::from(stuffed[at]);
        if code == 0 || at + code > stuffed.len() {
            return None;
        }
        out.extend_from_slice(&stuffed[at + 1..at + code]);
        at += code;
        if code < 0xFF && at < stuffed.len() {
            out.push(0);
        }
    }
    Some(out)
}

/// A whole wire frame: `COBS(type ‖ payload ‖ crc_lo ‖ crc_hi) ‖ 0x00`.
pub fn encode_frame(message_type: u8, payload: &[u8]) -> Vec<u8> {
    let mut raw = Vec::with_capacity(payload.len() + 3);
    raw.push(message_type);
    raw.extend_from_slice(payload);
    let crc = crc16(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    let mut wire = cobs_encode(&raw);
    wire.push(0);
    wire
}

/// Why a frame was dropped (SPEC section 4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameDrop {
    Cobs,
    Oversize,
    TooShort,
    Crc,
    UnknownType,
    BadLength,
}

/// Decodes the stuffed bytes of one frame (delimiter removed) into `(type, payload)`.
pub fn decode_frame(stuffed: &[u8]) -> Result<(u8, Vec<u8>), FrameDrop> {
    if stuffed.len() > 66 {
        return Err(FrameDrop::Oversize);
    }
    let raw = cobs_decode(stuffed).ok_or(FrameDrop::Cobs)?;
    if raw.len() > 65 {
        return Err(FrameDrop::Oversize);
    }
    if raw.len() < 3 {
        return Err(FrameDrop::TooShort);
    }
    let (body, crc) = raw.split_at(raw.len() - 2);
    if crc16(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameDrop::Crc);
    }
    let message_type = body[0];
    let expected = payload_len(message_type).ok_or(FrameDrop::UnknownType)?;
    if body.len() - 1 != expected {
        return Err(FrameDrop::BadLength);
    }
    Ok((message_type, body[1..].to_vec()))
}

pub(super) fn u16_at(p: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([p[at], p[at + 1]])
}

pub(super) fn u32_at(p: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([p[at], p[at + 1], p[at + 2], p[at + 3]])
}

pub(super) fn f32_at(p: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(p, at))
}

pub(super) fn vec3_at(p: &[u8], at: usize) -> [f32; 3] {
    [f32_at(p, at), f32_at(p, at + 4), f32_at(p, at + 8)]
}

pub(super) fn put_vec3(out: &mut Vec<u8>, v: [f32; 3]) {
    for c in v {
        out.extend_from_slice(&c.to_le_bytes());
    }
}

pub(super) fn label(text: &str) -> [u8; 12] {
    let mut out = [0u8; 12];
    for (slot, byte) in out
        .iter_mut()
        .zip(text.bytes().filter(|b| (0x20..=0x7E).contains(b)))
    {
        *slot = byte;
    }
    out
}

/// SPEC 6.8: a device with 2 DOF uses x and y, one with 1 DOF x alone; the other components are 0. Any other
/// DOF count uses all three.
pub fn used_components(v: [f32; 3], dof: u8) -> [f32; 3] {
    match dof {
        1 => [v[0], 0.0, 0.0],
        2 => [v[0], v[1], 0.0],
        _ => v,
    }
}
