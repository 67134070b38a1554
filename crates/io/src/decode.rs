//! Element decoding shared by every loader: scalar types, byte order, gzip/zlib inflation with a
//! size limit, and conversion of stored values to `f32` with NaN/infinity quarantine.

use crate::error::LoadProblem;
use std::io::Read;

voxhap_core::named_enum! {
    /// The element type stored in a file.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
    pub enum ScalarType {
        U8 => "u8",
        I8 => "i8",
        U16 => "u16",
        I16 => "i16",
        U32 => "u32",
        I32 => "i32",
        U64 => "u64",
        I64 => "i64",
        F32 => "f32",
        F64 => "f64",
    }
}

impl ScalarType {
    /// Bytes per element.
    pub fn size_bytes(self) -> usize {
        match self {
            ScalarType::U8 | ScalarType::I8 => 1,
            ScalarType::U16 | ScalarType::I16 => 2,
            ScalarType::U32 | ScalarType::I32 | ScalarType::F32 => 4,
            ScalarType::U64 | ScalarType::I64 | ScalarType::F64 => 8,
        }
    }

    /// Parses a Rust-style name (`u8` ... `f64`).
    pub fn from_name(name: &str) -> Option<ScalarType> {
        ScalarType::ALL.into_iter().find(|t| t.name() == name)
    }
}

impl std::fmt::Display for ScalarType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Byte order of multi-byte elements.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endian {
    Little,
    Big,
}

/// Values read from a file, converted to `f32`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Decoded {
    pub values: Vec<f32>,
    /// NaN or infinite values (after scaling) replaced by 0.
    pub non_finite_replaced: usize,
    /// Values that `f32` cannot hold exactly and were rounded.
    pub rounded_values: usize,
}

/// Decodes exactly `count` elements of `scalar_type` from `bytes` (which must hold exactly
/// `count · size` bytes), applying `value · slope + intercept` when `scale` is given.
pub fn decode_samples(
    bytes: &[u8],
    scalar_type: ScalarType,
    endian: Endian,
    count: usize,
    scale: Option<(f64, f64)>,
) -> Result<Decoded, LoadProblem> {
    let size = scalar_type.size_bytes();
    let expected_bytes = count.checked_mul(size).ok_or(LoadProblem::TooLarge {
        voxels: count as u128,
    })?;
    match bytes.len().cmp(&expected_bytes) {
        std::cmp::Ordering::Less => {
            return Err(LoadProblem::Truncated {
                expected_bytes: expected_bytes as u64,
                actual_bytes: bytes.len() as u64,
            })
        }
        std::cmp::Ordering::Greater => {
            return Err(LoadProblem::TrailingData {
                expected_bytes: expected_bytes as u64,
            })
        }
        std::cmp::Ordering::Equal => {}
    }
    let mut decoded = Decoded {
        values: Vec::with_capacity(count),
        ..Decoded::default()
    };
    // A 64-bit integer goes straight to f32 (through f64 it could round twice); it counts as rounded
    // when the f32 does not hold it exactly.
    macro_rules! wide_integer {
        ($type:ty, $raw:expr) => {{
            let v = <$type>::from_le_bytes($raw);
            if v as f32 as $type != v {
                decoded.rounded_values += 1;
            }
            push(&mut decoded, v as f32, scale, f64::from(v as f32));
            continue;
        }};
    }
    for chunk in bytes.chunks_exact(size) {
        let mut raw = [0u8; 8];
        raw[..size].copy_from_slice(chunk);
        if endian == Endian::Big {
            raw[..size].reverse();
        }
        // `raw` now holds the element little-endian in its first `size` bytes.
        let value: f64 = match scalar_type {
            ScalarType::U8 => f64::from(raw[0]),
            ScalarType::I8 => f64::from(raw[0] as i8),
            ScalarType::U16 => f64::from(u16::from_le_bytes([raw[0], raw[1]])),
            ScalarType::I16 => f64::from(i16::from_le_bytes([raw[0], raw[1]])),
            ScalarType::U32 => f64::from(u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]])),
            ScalarType::I32 => f64::from(i32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]])),
            ScalarType::F32 => f64::from(f32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]])),
            ScalarType::U64 => wide_integer!(u64, raw),
            ScalarType::I64 => wide_integer!(i64, raw),
            ScalarType::F64 => f64::from_le_bytes(raw),
        };
        let stored = value as f32;
        if value.is_finite() && f64::from(stored) != value {
            decoded.rounded_values += 1;
        }
        push(&mut decoded, stored, scale, value);
    }
    Ok(decoded)
}

/// Appends one value, scaled, with non-finite values replaced by zero.
#[inline]
fn push(decoded: &mut Decoded, stored: f32, scale: Option<(f64, f64)>, exact: f64) {
    let value = match scale {
        Some((slope, intercept)) => (exact * slope + intercept) as f32,
        None => stored,
    };
    if value.is_finite() {
        decoded.values.push(value);
    } else {
        decoded.non_finite_replaced += 1;
        decoded.values.push(0.0);
    }
}

/// Inflates gzip (magic `1f 8b`, multi-member allowed) or zlib data, producing at most
/// `expected_bytes + 1` bytes so a lying header or a gzip bomb cannot make it allocate without bound (the
/// caller checked `expected_bytes` against `--max-volume-bytes` first).
pub(crate) fn inflate(compressed: &[u8], expected_bytes: u64) -> Result<Vec<u8>, LoadProblem> {
    inflate_skip(compressed, 0, expected_bytes)
}

/// Deflate's largest expansion: one compressed byte gives at most about 1032 bytes (RFC 1951 length codes
/// of 258 bytes in 2 bits), so `compressed.len() * MAX_INFLATE_RATIO` bounds what a stream can supply.
const MAX_INFLATE_RATIO: u64 = 1032;

/// Inflates `compressed`, discards its first `skip` bytes (NRRD `byte skip`, NIfTI `vox_offset`) in
/// bounded chunks without keeping them, and returns at most the next `expected_bytes + 1` bytes. The
/// buffer it allocates is bounded by what the stream can supply, never by what the header claims.
pub(crate) fn inflate_skip(
    compressed: &[u8],
    skip: u64,
    expected_bytes: u64,
) -> Result<Vec<u8>, LoadProblem> {
    let reader: Box<dyn Read + '_> = if compressed.starts_with(&[0x1f, 0x8b]) {
        Box::new(flate2::read::MultiGzDecoder::new(compressed))
    } else {
        Box::new(flate2::read::ZlibDecoder::new(compressed))
    };
    let mut reader = reader;
    let skipped = std::io::copy(&mut (&mut reader).take(skip), &mut std::io::sink())
        .map_err(LoadProblem::Decompress)?;
    if skipped < skip {
        return Err(LoadProblem::Truncated {
            expected_bytes: skip.saturating_add(expected_bytes),
            actual_bytes: skipped,
        });
    }
    let limit = expected_bytes.saturating_add(1);
    let supply = (compressed.len() as u64).saturating_mul(MAX_INFLATE_RATIO);
    let mut out = Vec::with_capacity(usize::try_from(limit.min(supply)).unwrap_or(0));
    reader
        .take(limit)
        .read_to_end(&mut out)
        .map_err(LoadProblem::Decompress)?;
    if skip > 0 && (out.len() as u64) < expected_bytes {
        // Name the whole extent the header describes, skip included.
        return Err(LoadProblem::Truncated {
            expected_bytes: skip.saturating_add(expected_bytes),
            actual_bytes: skip.saturating_add(out.len() as u64),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn decodes_both_endians_of_every_type() {
        // (type, the value's little-endian bytes, its big-endian bytes, the value as f32).
        macro_rules! case {
            ($type:ident, $value:expr, $expected:expr) => {
                (
                    ScalarType::$type,
                    $value.to_le_bytes().to_vec(),
                    $value.to_be_bytes().to_vec(),
                    $expected,
                )
            };
        }
        let cases: [(ScalarType, Vec<u8>, Vec<u8>, f32); 10] = [
            case!(U8, 200u8, 200.0),
            case!(I8, -2i8, -2.0),
            case!(U16, 60000u16, 60000.0),
            case!(I16, -300i16, -300.0),
            case!(U32, 70000u32, 70000.0),
            case!(I32, -7i32, -7.0),
            case!(U64, 1u64, 1.0),
            case!(I64, -9i64, -9.0),
            case!(F32, 1.5f32, 1.5),
            case!(F64, -0.25f64, -0.25),
        ];
        for (scalar_type, little, big, expected) in cases {
            for (bytes, endian) in [(little, Endian::Little), (big, Endian::Big)] {
                let decoded = decode_samples(&bytes, scalar_type, endian, 1, None).unwrap();
                assert_eq!(decoded.values, vec![expected], "{scalar_type} {endian:?}");
                assert_eq!(decoded.rounded_values, 0);
            }
        }
    }

    #[test]
    fn counts_rounding_and_replaces_non_finite_values() {
        let bytes: Vec<u8> = [16_777_217i32, 3]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let decoded = decode_samples(&bytes, ScalarType::I32, Endian::Little, 2, None).unwrap();
        assert_eq!(decoded.rounded_values, 1);
        let bytes: Vec<u8> = [f32::NAN, 1.0, f32::NEG_INFINITY]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let decoded = decode_samples(&bytes, ScalarType::F32, Endian::Big, 3, None).unwrap();
        assert_eq!(decoded.values, vec![0.0, 1.0, 0.0]);
        assert_eq!(decoded.non_finite_replaced, 2);
        // Scaling that overflows f32 is caught too.
        let decoded =
            decode_samples(&[255], ScalarType::U8, Endian::Little, 1, Some((1e38, 0.0))).unwrap();
        assert_eq!(decoded.values, vec![0.0]);
        assert_eq!(decoded.non_finite_replaced, 1);
    }

    #[test]
    fn wrong_lengths_are_errors() {
        assert!(matches!(
            decode_samples(&[0; 5], ScalarType::U16, Endian::Little, 3, None),
            Err(LoadProblem::Truncated {
                expected_bytes: 6,
                actual_bytes: 5
            })
        ));
        assert!(matches!(
            decode_samples(&[0; 7], ScalarType::U16, Endian::Little, 3, None),
            Err(LoadProblem::TrailingData { expected_bytes: 6 })
        ));
    }

    #[test]
    fn inflate_stops_at_the_limit() {
        use std::io::Write;
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(&[7u8; 1000]).unwrap();
        let gz = encoder.finish().unwrap();
        assert_eq!(inflate(&gz, 10).unwrap().len(), 11);
        assert_eq!(inflate(&gz, 5000).unwrap().len(), 1000);
        assert!(matches!(
            inflate(&gz[..20], 5000),
            Err(LoadProblem::Decompress(_))
        ));
    }

    proptest! {
        #[test]
        fn decode_and_inflate_never_panic(
            bytes in proptest::collection::vec(any::<u8>(), 0..64),
            type_index in 0usize..10,
            big in any::<bool>(),
            count in 0usize..40,
        ) {
            let endian = if big { Endian::Big } else { Endian::Little };
            let scalar_type = ScalarType::ALL[type_index];
            if let Ok(decoded) = decode_samples(&bytes, scalar_type, endian, count, Some((2.0, 1.0))) {
                prop_assert_eq!(decoded.values.len(), count);
                prop_assert!(decoded.values.iter().all(|v| v.is_finite()));
            }
            let _ = inflate(&bytes, count as u64);
        }
    }
}
