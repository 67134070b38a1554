//! The OpenIGTLink wire format, sans-IO: the 58-byte header, the version-3 extended header and metadata,
//! the CRC-64, and the message contents voxhap speaks (TRANSFORM, STATUS, STRING, IMAGE). Decoders take byte
//! slices and say what is wrong; encoders append to a caller's buffer.
//!
//! Written from the published specification (github.com/openigtlink/OpenIGTLink, Documents/Protocol/
//! header.md, transform.md, status.md, string.md, image.md, timestamp.md; the CRC table of
//! Source/igtlutil/igtl_util.c):
//!
//! - Header, big-endian: `V` u16 (header version: 1 for protocol 1 and 2, 2 for protocol 3), `TYPE`
//!   char[12], `DEVICE_NAME` char[20], `TIME_STAMP` u64 (seconds since 1970 in the high 32 bits, the
//!   fraction of a second in the low 32), `BODY_SIZE` u64, `CRC` u64 of the whole body.
//! - Header version 2 bodies: extended header (`EXT_HEADER_SIZE` u16 = 12, `META_HEADER_SIZE` u16,
//!   `META_SIZE` u32, `MSG_ID` u32), then the content, then the metadata header (`INDEX_COUNT` u16 and
//!   per entry `KEY_SIZE` u16, `VALUE_ENCODING` u16, `VALUE_SIZE` u32) and the keys and values.
//! - CRC-64 of ECMA-182: polynomial 0x42F0E1EBA9EA3693, initial value 0, no reflection, no final xor.
//!
//! Where it sits: the OpenIGTLink server (`super`) reads and writes these on its tokio tasks, never on the
//! servo thread.

use glam::{DMat3, DVec3};

/// Bytes in a message header.
pub const HEADER_BYTES: usize = 58;
/// Bytes in the version-3 extended header.
pub const EXTENDED_HEADER_BYTES: usize = 12;
/// Bytes of a TRANSFORM content: 12 big-endian float32.
pub const TRANSFORM_BYTES: usize = 48;
/// Bytes of an IMAGE content header (before the voxels).
pub const IMAGE_HEADER_BYTES: usize = 72;
/// Character encoding US-ASCII as an IANA MIBenum (STRING messages and metadata values).
pub const MIB_US_ASCII: u16 = 3;
/// Character encoding UTF-8 as an IANA MIBenum.
pub const MIB_UTF8: u16 = 106;

/// STATUS codes of the specification (status.md) that voxhap uses.
pub mod status_code {
    pub const OK: u16 = 1;
    pub const UNKNOWN_ERROR: u16 = 2;
    pub const NOT_FOUND: u16 = 4;
    pub const ACCESS_DENIED: u16 = 5;
    pub const BUSY: u16 = 6;
    pub const CHECKSUM_ERROR: u16 = 9;
    pub const CONFIGURATION_ERROR: u16 = 10;
    pub const NOT_ENOUGH_RESOURCE: u16 = 11;
    pub const UNKNOWN_INSTRUCTION: u16 = 12;
    pub const DEVICE_NOT_READY: u16 = 13;
    pub const DEVICE_DISABLED: u16 = 15;
}

/// Why bytes are not a valid OpenIGTLink message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    #[error("header version {0} is not 1 (protocol 1 and 2) or 2 (protocol 3)")]
    HeaderVersion(u16),
    #[error("the {field} field is not ASCII text")]
    NotAscii { field: &'static str },
    #[error("a body of {size} bytes is larger than the {limit}-byte limit")]
    BodyTooLarge { size: u64, limit: u64 },
    #[error("CRC-64 mismatch: the header says {expected:#018x}, the body gives {computed:#018x}")]
    Crc { expected: u64, computed: u64 },
    #[error("{what}: {needed} bytes needed, {got} present")]
    Short {
        what: &'static str,
        needed: usize,
        got: usize,
    },
    #[error("extended header: {0}")]
    ExtendedHeader(String),
    #[error("metadata: {0}")]
    Metadata(String),
    #[error("TRANSFORM: {0}")]
    Transform(String),
    #[error("STRING: {0}")]
    String(String),
    #[error("IMAGE: {0}")]
    Image(String),
}

/// The CRC-64 table of ECMA-182 (polynomial 0x42F0E1EBA9EA3693), built at compile time.
const CRC_TABLE: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut crc = (byte as u64) << 56;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & (1 << 63) != 0 {
                (crc << 1) ^ 0x42F0_E1EB_A9EA_3693
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
};

/// OpenIGTLink's CRC-64 (ECMA-182, initial value 0) of `data`.
pub fn crc64(data: &[u8]) -> u64 {
    data.iter().fold(0u64, |crc, &byte| {
        CRC_TABLE[usize::from(byte ^ (crc >> 56) as u8)] ^ (crc << 8)
    })
}

/// An OpenIGTLink timestamp: whole seconds since 1970 in the high 32 bits, the fraction in the low 32.
pub fn timestamp_from_unix_ns(ns: u64) -> u64 {
    let seconds = (ns / 1_000_000_000).min(u64::from(u32::MAX));
    let fraction = ((ns % 1_000_000_000) << 32) / 1_000_000_000;
    (seconds << 32) | fraction
}

/// A decoded message header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// 1 (protocol 1 and 2) or 2 (protocol 3: extended header and metadata in the body).
    pub version: u16,
    pub type_name: String,
    pub device_name: String,
    pub timestamp: u64,
    pub body_size: u64,
    pub crc: u64,
}

/// A fixed-width, zero-padded ASCII field as text (up to the first zero byte).
fn fixed_text(bytes: &[u8], field: &'static str) -> Result<String, CodecError> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let text = &bytes[..end];
    if !text.is_ascii() {
        return Err(CodecError::NotAscii { field });
    }
    Ok(String::from_utf8_lossy(text).into_owned())
}

fn u16_at(bytes: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([bytes[at], bytes[at + 1]])
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_be_bytes(b)
}

fn f32_at(bytes: &[u8], at: usize) -> f32 {
    f32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn need(what: &'static str, bytes: &[u8], needed: usize) -> Result<(), CodecError> {
    if bytes.len() < needed {
        return Err(CodecError::Short {
            what,
            needed,
            got: bytes.len(),
        });
    }
    Ok(())
}

impl Header {
    /// Decodes a header and checks the version and the body size against `max_body_bytes`.
    pub fn decode(bytes: &[u8; HEADER_BYTES], max_body_bytes: u64) -> Result<Header, CodecError> {
        let version = u16_at(bytes, 0);
        if !(1..=2).contains(&version) {
            return Err(CodecError::HeaderVersion(version));
        }
        let body_size = u64_at(bytes, 42);
        if body_size > max_body_bytes {
            return Err(CodecError::BodyTooLarge {
                size: body_size,
                limit: max_body_bytes,
            });
        }
        Ok(Header {
            version,
            type_name: fixed_text(&bytes[2..14], "TYPE")?,
            device_name: fixed_text(&bytes[14..34], "DEVICE_NAME")?,
            timestamp: u64_at(bytes, 34),
            body_size,
            crc: u64_at(bytes, 50),
        })
    }

    /// Checks `body` against the header's CRC.
    pub fn check_crc(&self, body: &[u8]) -> Result<(), CodecError> {
        let computed = crc64(body);
        if computed != self.crc {
            return Err(CodecError::Crc {
                expected: self.crc,
                computed,
            });
        }
        Ok(())
    }
}

/// A message body split into its content and (version 2 headers) metadata.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Body<'a> {
    pub content: &'a [u8],
    /// Metadata `(key, value)` pairs, in order; empty for header version 1.
    pub metadata: Vec<(String, String)>,
    pub message_id: u32,
}

impl<'a> Body<'a> {
    /// Splits `body` according to the header `version`.
    pub fn split(version: u16, body: &'a [u8]) -> Result<Body<'a>, CodecError> {
        if version < 2 {
            return Ok(Body {
                content: body,
                metadata: Vec::new(),
                message_id: 0,
            });
        }
        need("extended header", body, EXTENDED_HEADER_BYTES)?;
        let extended = usize::from(u16_at(body, 0));
        let meta_header = usize::from(u16_at(body, 2));
        let meta_size = u32_at(body, 4) as usize;
        let message_id = u32_at(body, 8);
        if extended < EXTENDED_HEADER_BYTES {
            return Err(CodecError::ExtendedHeader(format!(
                "EXT_HEADER_SIZE {extended} is smaller than {EXTENDED_HEADER_BYTES}"
            )));
        }
        let trailer = meta_header.checked_add(meta_size);
        let content_end = trailer
            .and_then(|t| body.len().checked_sub(t))
            .filter(|&end| end >= extended)
            .ok_or_else(|| {
                CodecError::ExtendedHeader(format!(
                    "EXT_HEADER_SIZE {extended} + META_HEADER_SIZE {meta_header} + META_SIZE {meta_size} \
                     exceed the {}-byte body",
                    body.len()
                ))
            })?;
        let metadata = if meta_header == 0 {
            Vec::new()
        } else {
            decode_metadata(
                &body[content_end..content_end + meta_header],
                &body[content_end + meta_header..],
            )?
        };
        Ok(Body {
            content: &body[extended..content_end],
            metadata,
            message_id,
        })
    }

    /// The value of metadata `key`, if present.
    pub fn metadata_value(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

fn decode_metadata(header: &[u8], data: &[u8]) -> Result<Vec<(String, String)>, CodecError> {
    need("metadata header", header, 2)?;
    let count = usize::from(u16_at(header, 0));
    if header.len() != 2 + 8 * count {
        return Err(CodecError::Metadata(format!(
            "META_HEADER_SIZE {} does not fit INDEX_COUNT {count} (expected {})",
            header.len(),
            2 + 8 * count
        )));
    }
    let mut pairs = Vec::with_capacity(count);
    let mut at = 0usize;
    for index in 0..count {
        let entry = 2 + 8 * index;
        let key_size = usize::from(u16_at(header, entry));
        let value_size = u32_at(header, entry + 4) as usize;
        let end = at
            .checked_add(key_size)
            .and_then(|e| e.checked_add(value_size))
            .filter(|&e| e <= data.len())
            .ok_or_else(|| {
                CodecError::Metadata(format!("entry {index} runs past the end of the metadata"))
            })?;
        let key = std::str::from_utf8(&data[at..at + key_size])
            .map_err(|_| CodecError::Metadata(format!("key {index} is not UTF-8")))?;
        let value = std::str::from_utf8(&data[at + key_size..end])
            .map_err(|_| CodecError::Metadata(format!("value of {key:?} is not UTF-8")))?;
        pairs.push((key.to_owned(), value.to_owned()));
        at = end;
    }
    Ok(pairs)
}

/// Appends a whole message (header and body) to `out`: header version `version` (1 or 2; 2 adds the
/// extended header and `metadata`), type `type_name`, device `device_name`, `timestamp` (OpenIGTLink
/// format, [`timestamp_from_unix_ns`]), content written by `content`.
pub fn encode_message(
    out: &mut Vec<u8>,
    version: u16,
    type_name: &str,
    device_name: &str,
    timestamp: u64,
    metadata: &[(&str, &str)],
    content: impl FnOnce(&mut Vec<u8>),
) {
    let start = out.len();
    out.extend_from_slice(&version.to_be_bytes());
    put_fixed(out, type_name, 12);
    put_fixed(out, device_name, 20);
    out.extend_from_slice(&timestamp.to_be_bytes());
    out.extend_from_slice(&[0u8; 16]); // body size and CRC, filled below
    let body_start = out.len();
    if version >= 2 {
        let meta_header = 2 + 8 * metadata.len();
        let meta_size: usize = metadata.iter().map(|(k, v)| k.len() + v.len()).sum();
        out.extend_from_slice(&(EXTENDED_HEADER_BYTES as u16).to_be_bytes());
        out.extend_from_slice(&(meta_header as u16).to_be_bytes());
        out.extend_from_slice(&(meta_size as u32).to_be_bytes());
        out.extend_from_slice(&0u32.to_be_bytes());
        content(out);
        out.extend_from_slice(&(metadata.len() as u16).to_be_bytes());
        for (key, value) in metadata {
            out.extend_from_slice(&(key.len() as u16).to_be_bytes());
            out.extend_from_slice(&MIB_US_ASCII.to_be_bytes());
            out.extend_from_slice(&(value.len() as u32).to_be_bytes());
        }
        for (key, value) in metadata {
            out.extend_from_slice(key.as_bytes());
            out.extend_from_slice(value.as_bytes());
        }
    } else {
        content(out);
    }
    let body_size = (out.len() - body_start) as u64;
    let crc = crc64(&out[body_start..]);
    out[start + 42..start + 50].copy_from_slice(&body_size.to_be_bytes());
    out[start + 50..start + 58].copy_from_slice(&crc.to_be_bytes());
}

/// Writes `text` as a zero-padded field of `width` bytes (cut at `width`; callers pass ASCII names).
fn put_fixed(out: &mut Vec<u8>, text: &str, width: usize) {
    let bytes = text.as_bytes();
    let used = bytes.len().min(width);
    out.extend_from_slice(&bytes[..used]);
    out.resize(out.len() + width - used, 0);
}

/// A TRANSFORM content: the upper 3 x 4 of a homogeneous matrix, translation in millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    /// Columns of the 3 x 3 part (rotation for a rigid transform).
    pub rotation: DMat3,
    /// Translation (the 4th column), in the unit of the message (mm for poses).
    pub translation: DVec3,
}

impl Transform {
    /// A pure translation.
    pub fn translation(translation: DVec3) -> Self {
        Transform {
            rotation: DMat3::IDENTITY,
            translation,
        }
    }

    /// Appends the 48-byte content: R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ, big-endian float32.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let columns = [
            self.rotation.x_axis,
            self.rotation.y_axis,
            self.rotation.z_axis,
            self.translation,
        ];
        for column in columns {
            for value in column.to_array() {
                out.extend_from_slice(&(value as f32).to_be_bytes());
            }
        }
    }

    /// Decodes a TRANSFORM content; every element must be finite.
    pub fn decode(content: &[u8]) -> Result<Transform, CodecError> {
        if content.len() != TRANSFORM_BYTES {
            return Err(CodecError::Transform(format!(
                "content is {} bytes, expected {TRANSFORM_BYTES}",
                content.len()
            )));
        }
        let mut values = [0f64; 12];
        for (index, value) in values.iter_mut().enumerate() {
            *value = f64::from(f32_at(content, 4 * index));
            if !value.is_finite() {
                return Err(CodecError::Transform(format!(
                    "element {index} is not finite"
                )));
            }
        }
        let column = |c: usize| DVec3::new(values[3 * c], values[3 * c + 1], values[3 * c + 2]);
        Ok(Transform {
            rotation: DMat3::from_cols(column(0), column(1), column(2)),
            translation: column(3),
        })
    }
}

/// Appends a STATUS content: code, sub-code, error name (20 bytes), message with a terminating zero.
pub fn encode_status(out: &mut Vec<u8>, code: u16, sub_code: i64, error_name: &str, message: &str) {
    out.extend_from_slice(&code.to_be_bytes());
    out.extend_from_slice(&sub_code.to_be_bytes());
    put_fixed(out, error_name, 20);
    out.extend_from_slice(message.as_bytes());
    out.push(0);
}

/// A decoded STATUS content.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Status {
    pub code: u16,
    pub sub_code: i64,
    pub error_name: String,
    pub message: String,
}

/// Decodes a STATUS content.
pub fn decode_status(content: &[u8]) -> Result<Status, CodecError> {
    need("STATUS", content, 30)?;
    let message = &content[30..];
    let end = message
        .iter()
        .position(|&b| b == 0)
        .unwrap_or(message.len());
    Ok(Status {
        code: u16_at(content, 0),
        sub_code: u64_at(content, 2) as i64,
        error_name: fixed_text(&content[10..30], "ERROR_NAME")?,
        message: String::from_utf8_lossy(&message[..end]).into_owned(),
    })
}

/// Appends a STRING content (US-ASCII when the text is ASCII, else UTF-8); text past 65535 bytes is an
/// error of the caller, so it is cut at a character boundary.
pub fn encode_string(out: &mut Vec<u8>, text: &str) {
    let mut end = text.len().min(usize::from(u16::MAX));
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let encoding = if text.is_ascii() {
        MIB_US_ASCII
    } else {
        MIB_UTF8
    };
    out.extend_from_slice(&encoding.to_be_bytes());
    out.extend_from_slice(&(end as u16).to_be_bytes());
    out.extend_from_slice(&text.as_bytes()[..end]);
}

/// Decodes a STRING content (US-ASCII or UTF-8).
pub fn decode_string(content: &[u8]) -> Result<String, CodecError> {
    need("STRING", content, 4)?;
    let encoding = u16_at(content, 0);
    let length = usize::from(u16_at(content, 2));
    if content.len() != 4 + length {
        return Err(CodecError::String(format!(
            "LENGTH {length} does not match the {} bytes of text",
            content.len() - 4
        )));
    }
    if encoding != MIB_US_ASCII && encoding != MIB_UTF8 {
        return Err(CodecError::String(format!(
            "encoding {encoding} is not US-ASCII (3) or UTF-8 (106)"
        )));
    }
    std::str::from_utf8(&content[4..])
        .map(str::to_owned)
        .map_err(|_| CodecError::String("the text is not valid UTF-8".to_owned()))
}

/// The voxel types of an IMAGE.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    fn from_code(code: u8) -> Option<ScalarType> {
        Some(match code {
            2 => ScalarType::I8,
            3 => ScalarType::U8,
            4 => ScalarType::I16,
            5 => ScalarType::U16,
            6 => ScalarType::I32,
            7 => ScalarType::U32,
            10 => ScalarType::F32,
            11 => ScalarType::F64,
            _ => return None,
        })
    }

    /// The specification's code for this type.
    pub fn code(self) -> u8 {
        match self {
            ScalarType::I8 => 2,
            ScalarType::U8 => 3,
            ScalarType::I16 => 4,
            ScalarType::U16 => 5,
            ScalarType::I32 => 6,
            ScalarType::U32 => 7,
            ScalarType::F32 => 10,
            ScalarType::F64 => 11,
        }
    }

    /// Bytes per value.
    pub fn bytes(self) -> usize {
        match self {
            ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }
}

/// A decoded scalar IMAGE, in RAS millimetres.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Index axis directions scaled by the voxel spacing (mm), RAS: columns i, j, k.
    pub axes_mm: DMat3,
    /// RAS position of voxel (0, 0, 0) (mm).
    pub origin_mm: DVec3,
    /// Values, i fastest, converted to f32 (every one finite).
    pub values: Vec<f32>,
}

#[cfg(test)]
impl Image {
    /// A test image: `dims` voxels `spacing_mm` apart along x, y, z (no rotation) from `origin_mm`, valued
    /// 0, 1, 2, ... in storage order.
    pub(crate) fn ramp(dims: [usize; 3], spacing_mm: [f64; 3], origin_mm: [f64; 3]) -> Image {
        let voxels = dims.iter().product::<usize>();
        Image {
            dims,
            axes_mm: DMat3::from_diagonal(DVec3::from_array(spacing_mm)),
            origin_mm: DVec3::from_array(origin_mm),
            values: (0..voxels).map(|v| v as f32).collect(),
        }
    }
}

/// Decodes a scalar IMAGE content: one component, a whole (not partial) volume of at most `max_voxels`
/// voxels, finite geometry. The position `PX, PY, PZ` is the image centre (image.md), so the origin is
/// `centre - axes (dims - 1) / 2`; an LPS image is turned into RAS by negating x and y.
pub fn decode_image(content: &[u8], max_voxels: usize) -> Result<Image, CodecError> {
    need("IMAGE header", content, IMAGE_HEADER_BYTES)?;
    let bad = |message: String| CodecError::Image(message);
    let components = content[2];
    if components != 1 {
        return Err(bad(format!(
            "{components} components per voxel: only scalar images (1 component) can be loaded"
        )));
    }
    let scalar = ScalarType::from_code(content[3])
        .ok_or_else(|| bad(format!("unknown scalar type {}", content[3])))?;
    let big_endian = match content[4] {
        1 => true,
        2 => false,
        other => return Err(bad(format!("endian {other} is not 1 (big) or 2 (little)"))),
    };
    let lps = match content[5] {
        1 => false,
        2 => true,
        other => return Err(bad(format!("coordinate {other} is not 1 (RAS) or 2 (LPS)"))),
    };
    let dims = [0, 1, 2].map(|a| usize::from(u16_at(content, 6 + 2 * a)));
    let mut matrix = [0f64; 12];
    for (index, value) in matrix.iter_mut().enumerate() {
        *value = f64::from(f32_at(content, 12 + 4 * index));
        if !value.is_finite() {
            return Err(bad(format!("matrix element {index} is not finite")));
        }
    }
    let offset = [0, 1, 2].map(|a| usize::from(u16_at(content, 60 + 2 * a)));
    let sub_dims = [0, 1, 2].map(|a| usize::from(u16_at(content, 66 + 2 * a)));
    if dims.contains(&0) {
        return Err(bad(format!(
            "dimensions {dims:?}: every one must be at least 1"
        )));
    }
    if offset != [0, 0, 0] || sub_dims != dims {
        return Err(bad(format!(
            "a partial image (sub-volume at {offset:?} of size {sub_dims:?} in {dims:?}) cannot be loaded; send the whole volume"
        )));
    }
    let voxels = dims[0] * dims[1] * dims[2];
    if voxels > max_voxels {
        return Err(bad(format!(
            "{voxels} voxels ({dims:?}) is more than the {max_voxels}-voxel limit"
        )));
    }
    let data = &content[IMAGE_HEADER_BYTES..];
    let expected = voxels * scalar.bytes();
    if data.len() != expected {
        return Err(bad(format!(
            "{} bytes of voxels, expected {expected} ({dims:?} of {scalar:?})",
            data.len()
        )));
    }
    let column = |c: usize| DVec3::new(matrix[3 * c], matrix[3 * c + 1], matrix[3 * c + 2]);
    let flip = if lps {
        DVec3::new(-1.0, -1.0, 1.0)
    } else {
        DVec3::ONE
    };
    let axes_mm = DMat3::from_cols(column(0) * flip, column(1) * flip, column(2) * flip);
    if axes_mm.determinant().abs() < 1e-12 {
        return Err(bad(
            "the index axes are degenerate (zero spacing or parallel axes)".to_owned(),
        ));
    }
    let centre_mm = column(3) * flip;
    let half = DVec3::new(
        (dims[0] - 1) as f64,
        (dims[1] - 1) as f64,
        (dims[2] - 1) as f64,
    ) * 0.5;
    let origin_mm = centre_mm - axes_mm * half;
    let size = scalar.bytes();
    let mut values = Vec::with_capacity(voxels);
    for chunk in data.chunks_exact(size) {
        let mut b = [0u8; 8];
        if big_endian {
            b[..size].copy_from_slice(chunk);
        } else {
            for (slot, byte) in b[..size].iter_mut().zip(chunk.iter().rev()) {
                *slot = *byte;
            }
        }
        // `b[..size]` now holds the value big-endian.
        let value = match scalar {
            ScalarType::I8 => f64::from(b[0] as i8),
            ScalarType::U8 => f64::from(b[0]),
            ScalarType::I16 => f64::from(i16::from_be_bytes([b[0], b[1]])),
            ScalarType::U16 => f64::from(u16::from_be_bytes([b[0], b[1]])),
            ScalarType::I32 => f64::from(i32::from_be_bytes([b[0], b[1], b[2], b[3]])),
            ScalarType::U32 => f64::from(u32::from_be_bytes([b[0], b[1], b[2], b[3]])),
            ScalarType::F32 => f64::from(f32::from_be_bytes([b[0], b[1], b[2], b[3]])),
            ScalarType::F64 => f64::from_be_bytes(b),
        };
        let value = value as f32;
        if !value.is_finite() {
            return Err(bad(format!(
                "voxel {} is not finite as a 32-bit float",
                values.len()
            )));
        }
        values.push(value);
    }
    Ok(Image {
        dims,
        axes_mm,
        origin_mm,
        values,
    })
}

/// Appends a scalar float32 IMAGE content (RAS, little-endian voxels) for `image` (tests and tools).
pub fn encode_image(out: &mut Vec<u8>, image: &Image) {
    out.extend_from_slice(&1u16.to_be_bytes());
    out.push(1);
    out.push(ScalarType::F32.code());
    out.push(2);
    out.push(1);
    for d in image.dims {
        out.extend_from_slice(&(d as u16).to_be_bytes());
    }
    let half = DVec3::new(
        (image.dims[0] - 1) as f64,
        (image.dims[1] - 1) as f64,
        (image.dims[2] - 1) as f64,
    ) * 0.5;
    let centre = image.origin_mm + image.axes_mm * half;
    for column in [
        image.axes_mm.x_axis,
        image.axes_mm.y_axis,
        image.axes_mm.z_axis,
        centre,
    ] {
        for value in column.to_array() {
            out.extend_from_slice(&(value as f32).to_be_bytes());
        }
    }
    out.extend_from_slice(&[0u8; 6]);
    for d in image.dims {
        out.extend_from_slice(&(d as u16).to_be_bytes());
    }
    for value in &image.values {
        out.extend_from_slice(&value.to_le_bytes());
    }
}

#[cfg(test)]
#[path = "codec_tests.rs"]
mod tests;
