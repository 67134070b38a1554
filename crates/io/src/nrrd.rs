//! NRRD loader (`.nrrd` with attached data, `.nhdr` with a detached data file), hand-written
//! (format reference: teem's "NRRD format" page, NRRD0001-NRRD0005).
//!
//! Read fields: `type` (every integer and float spelling), `dimension` (3 for a scalar volume, or 4
//! with a leading 3-component axis for a vector volume, components interleaved), `sizes`, `encoding`
//! (`raw`, `gzip`/`gz`, `ascii`/`text`/`txt`), `endian`, `space` (RAS, LAS, LPS, scanner-xyz,
//! 3D-right-handed) or `space dimension: 3`, `space directions`, `space origin`, `space units`,
//! `spacings` (when there are no space directions), `data file`/`datafile` (one file, relative to the
//! header), `line skip`, `byte skip` (−1: data at the end of a raw file). Other fields and `key:=value`
//! pairs are ignored. LPS/LAS positions and vector components are flipped to RAS (module
//! [`super`]). Unsupported (clear errors): bzip2 and hex encodings, `block` type, multi-file `data
//! file` lists, time axes.

use crate::decode::{decode_samples, inflate_skip, Decoded, Endian, ScalarType};
use crate::error::LoadProblem;
use crate::header_lines::HeaderLines;
use crate::loaded::{
    assemble, checked_voxel_count, metres_per_unit, FileFormat, Layout, LoadedVolume,
};
use crate::source::{check_budget, header_format_entry_points, DataRange, HeaderFile};
use glam::{DMat3, DVec3};
use std::path::Path;
use voxhap_core::volume::Grid;

/// Data encodings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Raw,
    Gzip,
    Ascii,
}

/// The header fields the loader uses.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NrrdHeader {
    pub scalar_type: Option<ScalarType>,
    pub dimension: Option<usize>,
    pub sizes: Vec<u64>,
    pub encoding: Option<Encoding>,
    pub endian: Option<Endian>,
    /// Per world axis, +1 or −1: the flip that takes the file's space to RAS.
    pub space_flip: Option<[f64; 3]>,
    /// One entry per axis: `None` for a non-spatial axis (`none`).
    pub space_directions: Option<Vec<Option<DVec3>>>,
    pub space_origin: Option<DVec3>,
    pub space_units: Option<Vec<String>>,
    pub spacings: Option<Vec<f64>>,
    pub data_file: Option<String>,
    pub line_skip: usize,
    pub byte_skip: i64,
    /// Bytes up to and including the blank line that ends the header (where attached data starts).
    pub header_bytes: usize,
}

header_format_entry_points!(
    files: "`.nrrd` or `.nhdr`",
    name: "NRRD",
    budget: "the byte skip plus the data the sizes describe"
);

/// The volume `header` describes, its data read from `file`.
fn from_header(header: NrrdHeader, file: &HeaderFile) -> Result<LoadedVolume, LoadProblem> {
    let scalar_type = header.scalar_type.ok_or_else(|| missing("type"))?;
    let dimension = header.dimension.ok_or_else(|| missing("dimension"))?;
    if header.sizes.len() != dimension {
        return Err(LoadProblem::header(format!(
            "sizes has {} entries but dimension is {dimension}",
            header.sizes.len()
        )));
    }
    let (components, domain_sizes) = match (dimension, header.sizes.as_slice()) {
        (3, sizes) => (1, sizes),
        (4, [3, rest @ ..]) => (3, rest),
        _ => {
            return Err(LoadProblem::unsupported(format!(
            "dimension {dimension} with sizes {:?}: only 3-D scalar volumes or 4-D volumes with \
                 a leading 3-component axis are read",
            header.sizes
        )))
        }
    };
    let dims = [domain_sizes[0], domain_sizes[1], domain_sizes[2]];
    let voxels = checked_voxel_count(dims, components as u64)?;
    let count = voxels * components;
    let encoding = header.encoding.ok_or_else(|| missing("encoding"))?;
    let endian = match (header.endian, encoding, scalar_type.size_bytes()) {
        (Some(endian), _, _) => endian,
        (None, Encoding::Ascii, _) | (None, _, 1) => Endian::Little,
        (None, _, _) => return Err(missing("endian")),
    };
    let grid = grid(&header, components, dims)?;
    let flip = header.space_flip.unwrap_or([1.0; 3]);
    let expected_bytes = crate::loaded::data_bytes(count, scalar_type)?;
    // What the reader must read or inflate: the byte skip, then the data. ASCII data is text, several
    // bytes a value: its file size is bounded by the volume file limit instead.
    let byte_skip = u64::try_from(header.byte_skip).unwrap_or(0);
    let needed_bytes = byte_skip
        .checked_add(expected_bytes)
        .ok_or_else(|| LoadProblem::header(format!("byte skip {byte_skip} is too large")))?;
    check_budget(needed_bytes, count as u64, file.options)?;

    let mut applied_byte_skip = false;
    // Lines to skip come first; the bounded read below covers detached raw data without line skips, the
    // common case; other layouts read the file up to the limit and are checked after decoding.
    let range = || match (encoding, header.line_skip, header.byte_skip) {
        (Encoding::Raw, 0, -1) => DataRange::Tail {
            needed: expected_bytes,
        },
        // The byte skip is sought past, not read.
        (Encoding::Raw, 0, _) => {
            applied_byte_skip = true;
            DataRange::From {
                skip: byte_skip,
                needed: expected_bytes,
            }
        }
        _ => DataRange::From {
            skip: 0,
            needed: file.options.max_volume_bytes,
        },
    };
    let data = file.data(header.header_bytes, header.data_file.as_deref(), range)?;
    let data = skip_lines(&data, header.line_skip)?;
    let byte_skip = if applied_byte_skip {
        0
    } else {
        header.byte_skip
    };
    let decoded = decode(data, byte_skip, encoding, scalar_type, endian, count)?;
    let layout = Layout::interleaved(
        scalar_type,
        FileFormat::Nrrd,
        components,
        flip.map(|s| s as f32),
    );
    assemble(grid, decoded, &layout, file.path)
}

fn missing(field: &str) -> LoadProblem {
    LoadProblem::header(format!("missing required field \"{field}\""))
}

/// Decodes `data` (after its line skips): `byte_skip` bytes (of the inflated stream for gzip) are skipped
/// first, without copying or keeping them.
fn decode<'a>(
    data: &'a [u8],
    byte_skip: i64,
    encoding: Encoding,
    scalar_type: ScalarType,
    endian: Endian,
    count: usize,
) -> Result<Decoded, LoadProblem> {
    // Checked against the limit by the caller, so these fit in memory and in usize.
    let expected_bytes = count * scalar_type.size_bytes();
    let skip_count = || {
        u64::try_from(byte_skip).map_err(|_| {
            LoadProblem::header(format!(
                "byte skip {byte_skip} is only allowed (as -1) with raw encoding"
            ))
        })
    };
    let skip = |data: &'a [u8]| -> Result<&'a [u8], LoadProblem> {
        let byte_skip = usize::try_from(skip_count()?).unwrap_or(usize::MAX);
        data.get(byte_skip..).ok_or(LoadProblem::Truncated {
            expected_bytes: (byte_skip as u64).saturating_add(expected_bytes as u64),
            actual_bytes: data.len() as u64,
        })
    };
    match encoding {
        Encoding::Raw => {
            let data = if byte_skip == -1 {
                let start =
                    data.len()
                        .checked_sub(expected_bytes)
                        .ok_or(LoadProblem::Truncated {
                            expected_bytes: expected_bytes as u64,
                            actual_bytes: data.len() as u64,
                        })?;
                &data[start..]
            } else {
                skip(data)?
            };
            decode_samples(data, scalar_type, endian, count, None)
        }
        Encoding::Gzip => {
            let inflated = inflate_skip(data, skip_count()?, expected_bytes as u64)?;
            decode_samples(&inflated, scalar_type, endian, count, None)
        }
        Encoding::Ascii => {
            let data = skip(data)?;
            decode_text(data, scalar_type, count)
        }
    }
}

/// Parses whitespace- or comma-separated numbers (ASCII encoding).
fn decode_text(data: &[u8], scalar_type: ScalarType, count: usize) -> Result<Decoded, LoadProblem> {
    let text = std::str::from_utf8(data)
        .map_err(|_| LoadProblem::header("ascii-encoded data is not text"))?;
    let mut decoded = Decoded::default();
    for token in text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
    {
        if decoded.values.len() == count {
            return Err(LoadProblem::TrailingData {
                expected_bytes: count as u64,
            });
        }
        let value: f64 = token.parse().map_err(|_| {
            LoadProblem::header(format!("ascii data value {token:?} is not a number"))
        })?;
        let is_integer_type = !matches!(scalar_type, ScalarType::F32 | ScalarType::F64);
        if is_integer_type && value.fract() != 0.0 {
            return Err(LoadProblem::header(format!(
                "ascii data value {token} is not a whole number but the type is {scalar_type}"
            )));
        }
        let stored = value as f32;
        if !stored.is_finite() {
            decoded.non_finite_replaced += 1;
            decoded.values.push(0.0);
        } else {
            if f64::from(stored) != value {
                decoded.rounded_values += 1;
            }
            decoded.values.push(stored);
        }
    }
    if decoded.values.len() < count {
        return Err(LoadProblem::Truncated {
            expected_bytes: count as u64,
            actual_bytes: decoded.values.len() as u64,
        });
    }
    Ok(decoded)
}

fn skip_lines(data: &[u8], lines: usize) -> Result<&[u8], LoadProblem> {
    let mut rest = data;
    for _ in 0..lines {
        let end = rest.iter().position(|&b| b == b'\n').ok_or_else(|| {
            LoadProblem::header(format!("line skip {lines} passes the end of the data"))
        })?;
        rest = &rest[end + 1..];
    }
    Ok(rest)
}

/// The RAS, metre grid of the header's domain axes.
fn grid(header: &NrrdHeader, components: usize, dims: [u64; 3]) -> Result<Grid, LoadProblem> {
    let first_domain_axis = components / 3; // 0 for scalar, 1 for vector
    let metres = match &header.space_units {
        None => 1e-3,
        Some(units) => {
            let first = units.first().map(String::as_str).unwrap_or("mm");
            if units.iter().any(|u| u != first) {
                return Err(LoadProblem::unsupported(format!(
                    "mixed space units {units:?}"
                )));
            }
            metres_per_unit(first)
                .ok_or_else(|| LoadProblem::unsupported(format!("space unit {first:?}")))?
        }
    };
    let (columns, origin) = match &header.space_directions {
        Some(directions) => {
            if directions.len() != header.sizes.len() {
                return Err(LoadProblem::header(format!(
                    "space directions has {} entries for {} axes",
                    directions.len(),
                    header.sizes.len()
                )));
            }
            if components == 3 && directions[0].is_some() {
                return Err(LoadProblem::header(
                    "the 3-component axis must have space direction \"none\"",
                ));
            }
            let mut columns = [DVec3::ZERO; 3];
            for (axis, column) in columns.iter_mut().enumerate() {
                *column = directions[first_domain_axis + axis].ok_or_else(|| {
                    LoadProblem::header(format!("domain axis {axis} has space direction none"))
                })?;
            }
            (columns, header.space_origin.unwrap_or(DVec3::ZERO))
        }
        None => {
            let spacings = match &header.spacings {
                Some(spacings) => {
                    if spacings.len() != header.sizes.len() {
                        return Err(LoadProblem::header(
                            "spacings has the wrong number of entries",
                        ));
                    }
                    [0, 1, 2].map(|a| spacings[first_domain_axis + a])
                }
                None => [1.0; 3],
            };
            (
                [
                    DVec3::X * spacings[0],
                    DVec3::Y * spacings[1],
                    DVec3::Z * spacings[2],
                ],
                header.space_origin.unwrap_or(DVec3::ZERO),
            )
        }
    };
    let flip = DVec3::from_array(header.space_flip.unwrap_or([1.0; 3]));
    let linear = DMat3::from_cols(columns[0] * flip, columns[1] * flip, columns[2] * flip) * metres;
    let affine = glam::DMat4::from_cols(
        linear.x_axis.extend(0.0),
        linear.y_axis.extend(0.0),
        linear.z_axis.extend(0.0),
        (origin * flip * metres).extend(1.0),
    );
    Ok(Grid::from_affine(dims.map(|d| d as usize), affine)?)
}

/// Parses the header (up to the first blank line, or the whole input for a detached header).
pub fn parse_header(bytes: &[u8]) -> Result<NrrdHeader, LoadProblem> {
    let mut header = NrrdHeader::default();
    let mut lines = HeaderLines::new(bytes);
    loop {
        let Some(line) = lines.next() else {
            header.header_bytes = bytes.len();
            break;
        };
        let line = line?.trim_end_matches('\r');
        let line_number = lines.line_number();
        if line_number == 1 {
            let version = line
                .strip_prefix("NRRD000")
                .and_then(|v| v.parse::<u8>().ok());
            if !matches!(version, Some(1..=5)) || line.len() != 8 {
                return Err(LoadProblem::header(format!(
                    "first line {line:?} is not a NRRD magic (NRRD0001 to NRRD0005)"
                )));
            }
            continue;
        }
        if line.is_empty() {
            header.header_bytes = lines.position();
            break;
        }
        if line.starts_with('#') {
            continue;
        }
        let field_at = line.find(": ");
        let pair_at = line.find(":=");
        if pair_at.is_some_and(|p| field_at.is_none_or(|f| p < f)) {
            continue; // key:=value pair, not used
        }
        let Some(field_at) = field_at else {
            return Err(LoadProblem::header(format!(
                "line {line_number} {line:?} is not \"field: value\""
            )));
        };
        let (key, value) = (&line[..field_at], line[field_at + 2..].trim());
        parse_field(&mut header, &key.to_ascii_lowercase(), value).map_err(|message| {
            LoadProblem::header(format!("line {line_number} ({key}): {message}"))
        })?;
    }
    Ok(header)
}

/// What is wrong with the value of one NRRD header field (the line and field are added by the caller).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NrrdFieldError {
    #[error("{value:?} is not a valid number")]
    NotANumber { value: String },
    #[error("{value:?} must be finite and positive")]
    NotPositive { value: String },
    #[error("{values:?} is not a finite 3-vector")]
    NotAVector3 { values: Vec<f64> },
    #[error("unclosed '('")]
    UnclosedParenthesis,
    #[error("expected a vector \"(x,y,z)\" or none at {rest:?}")]
    ExpectedVector { rest: String },
    #[error("expected one vector (x,y,z)")]
    ExpectedOneVector,
    #[error("encoding {value:?} is not supported (raw, gzip, ascii)")]
    UnsupportedEncoding { value: String },
    #[error("unknown endian {value:?}")]
    UnknownEndian { value: String },
    #[error("only 3-D spaces are supported")]
    NotThreeDimensional,
    #[error("space {value:?} is not supported (RAS, LAS, LPS, scanner-xyz, 3D-right-handed)")]
    UnsupportedSpace { value: String },
    #[error("type {value:?} is not supported")]
    UnsupportedType { value: String },
    #[error("multi-file data ({value:?}) is not supported: use one data file")]
    MultiFile { value: String },
    #[error("byte skip {skip} must be >= -1")]
    ByteSkip { skip: i64 },
}

fn parse_field(header: &mut NrrdHeader, key: &str, value: &str) -> Result<(), NrrdFieldError> {
    match key {
        "type" => header.scalar_type = Some(parse_type(value)?),
        "dimension" => header.dimension = Some(parse_number(value)?),
        "sizes" => {
            header.sizes = value
                .split_whitespace()
                .map(parse_number)
                .collect::<Result<_, _>>()?
        }
        "encoding" => {
            header.encoding = Some(match value.to_ascii_lowercase().as_str() {
                "raw" => Encoding::Raw,
                "gzip" | "gz" => Encoding::Gzip,
                "ascii" | "text" | "txt" => Encoding::Ascii,
                other => {
                    return Err(NrrdFieldError::UnsupportedEncoding {
                        value: other.to_owned(),
                    })
                }
            })
        }
        "endian" => {
            header.endian = Some(match value.to_ascii_lowercase().as_str() {
                "little" => Endian::Little,
                "big" => Endian::Big,
                other => {
                    return Err(NrrdFieldError::UnknownEndian {
                        value: other.to_owned(),
                    })
                }
            })
        }
        "space" => header.space_flip = Some(parse_space(value)?),
        "space dimension" => {
            if parse_number::<usize>(value)? != 3 {
                return Err(NrrdFieldError::NotThreeDimensional);
            }
            header.space_flip.get_or_insert([1.0; 3]);
        }
        "space directions" => {
            header.space_directions = Some(
                parse_vectors(value)?
                    .into_iter()
                    .map(|v| v.map(vector3).transpose())
                    .collect::<Result<_, _>>()?,
            )
        }
        "space origin" => {
            let mut vectors = parse_vectors(value)?;
            match (vectors.pop(), vectors.is_empty()) {
                (Some(Some(v)), true) => header.space_origin = Some(vector3(v)?),
                _ => return Err(NrrdFieldError::ExpectedOneVector),
            }
        }
        "space units" => {
            header.space_units = Some(
                value
                    .split('"')
                    .skip(1)
                    .step_by(2)
                    .map(str::to_owned)
                    .collect(),
            )
        }
        "spacings" => {
            header.spacings = Some(
                value
                    .split_whitespace()
                    .map(|s| match s.to_ascii_lowercase().as_str() {
                        "nan" => Ok(f64::NAN),
                        _ => parse_positive(s),
                    })
                    .collect::<Result<_, _>>()?,
            )
        }
        "data file" | "datafile" => {
            if value.split_whitespace().count() != 1 || value.eq_ignore_ascii_case("list") {
                return Err(NrrdFieldError::MultiFile {
                    value: value.to_owned(),
                });
            }
            header.data_file = Some(value.to_owned())
        }
        "line skip" | "lineskip" => header.line_skip = parse_number(value)?,
        "byte skip" | "byteskip" => {
            let skip: i64 = parse_number(value)?;
            if skip < -1 {
                return Err(NrrdFieldError::ByteSkip { skip });
            }
            header.byte_skip = skip
        }
        _ => {} // kinds, content, centers, labels, thicknesses, ...: not needed
    }
    Ok(())
}

fn parse_number<T: std::str::FromStr>(value: &str) -> Result<T, NrrdFieldError> {
    crate::header_lines::parse_value(value, |value| NrrdFieldError::NotANumber { value })
}

fn parse_positive(value: &str) -> Result<f64, NrrdFieldError> {
    let number: f64 = parse_number(value)?;
    if number.is_finite() && number > 0.0 {
        Ok(number)
    } else {
        Err(NrrdFieldError::NotPositive {
            value: value.to_owned(),
        })
    }
}

fn vector3(values: Vec<f64>) -> Result<DVec3, NrrdFieldError> {
    match values.as_slice() {
        &[x, y, z] if x.is_finite() && y.is_finite() && z.is_finite() => Ok(DVec3::new(x, y, z)),
        _ => Err(NrrdFieldError::NotAVector3 { values }),
    }
}

/// Parses `(1,0,0) none (0, 1, 0)`: a list of parenthesised vectors or `none`.
fn parse_vectors(value: &str) -> Result<Vec<Option<Vec<f64>>>, NrrdFieldError> {
    let mut vectors = Vec::new();
    let mut rest = value.trim();
    while !rest.is_empty() {
        if let Some(inner) = rest.strip_prefix('(') {
            let close = inner.find(')').ok_or(NrrdFieldError::UnclosedParenthesis)?;
            let numbers = inner[..close]
                .split(',')
                .map(parse_number)
                .collect::<Result<Vec<f64>, _>>()?;
            vectors.push(Some(numbers));
            rest = inner[close + 1..].trim_start();
        } else if rest
            .get(..4)
            .is_some_and(|word| word.eq_ignore_ascii_case("none"))
        {
            vectors.push(None);
            rest = rest[4..].trim_start();
        } else {
            return Err(NrrdFieldError::ExpectedVector {
                rest: rest.to_owned(),
            });
        }
    }
    Ok(vectors)
}

fn parse_space(value: &str) -> Result<[f64; 3], NrrdFieldError> {
    match value.to_ascii_lowercase().as_str() {
        "right-anterior-superior" | "ras" | "scanner-xyz" | "3d-right-handed" => {
            Ok([1.0, 1.0, 1.0])
        }
        "left-anterior-superior" | "las" => Ok([-1.0, 1.0, 1.0]),
        "left-posterior-superior" | "lps" => Ok([-1.0, -1.0, 1.0]),
        other => Err(NrrdFieldError::UnsupportedSpace {
            value: other.to_owned(),
        }),
    }
}

fn parse_type(value: &str) -> Result<ScalarType, NrrdFieldError> {
    let normalised = value
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_ascii_lowercase();
    Ok(match normalised.as_str() {
        "signed char" | "int8" | "int8_t" => ScalarType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => ScalarType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            ScalarType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            ScalarType::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => ScalarType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => ScalarType::U32,
        "longlong"
        | "long long"
        | "long long int"
        | "signed long long"
        | "signed long long int"
        | "int64"
        | "int64_t" => ScalarType::I64,
        "ulonglong" | "unsigned long long" | "unsigned long long int" | "uint64" | "uint64_t" => {
            ScalarType::U64
        }
        "float" => ScalarType::F32,
        "double" => ScalarType::F64,
        other => {
            return Err(NrrdFieldError::UnsupportedType {
                value: other.to_owned(),
            })
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &[u8] =
        b"NRRD0004\n# comment\ntype: short\ndimension: 3\nspace: left-posterior-superior\n\
sizes: 2 1 1\nspace directions: (2,0,0) (0,3,0) (0,0,4)\nendian: big\nencoding: raw\n\
space origin: (10,20,30)\nkey:=value\n\n\x00\x05\xff\xfe";

    #[test]
    fn tiny_lps_file_is_flipped_to_ras() {
        let loaded = parse(TINY, Path::new("tiny.nrrd")).unwrap();
        let grid = loaded.volume.grid();
        assert_eq!(grid.dims(), [2, 1, 1]);
        assert!((grid.origin_m() - DVec3::new(-0.010, -0.020, 0.030)).length() < 1e-12);
        assert!((grid.spacing_m() - DVec3::new(0.002, 0.003, 0.004)).length() < 1e-12);
        assert!((grid.direction().x_axis - -DVec3::X).length() < 1e-12);
        assert_eq!(loaded.volume.value_range(), (-2.0, 5.0));
        assert_eq!(loaded.source_type, ScalarType::I16);
    }

    #[test]
    fn field_errors_name_the_line() {
        let bad = b"NRRD0004\ntype: quaternion\n\n";
        let message = parse(bad, Path::new("x.nrrd")).unwrap_err().to_string();
        assert!(message.contains("line 2"), "{message}");
        let message = parse(b"NRRD0004\ntype: float\n\n", Path::new("x.nrrd"))
            .unwrap_err()
            .to_string();
        assert!(message.contains("dimension"), "{message}");
        assert!(parse(b"P5\n", Path::new("x.nrrd")).is_err());
    }

    #[test]
    fn vectors_parse_with_spaces_and_none() {
        assert_eq!(
            parse_vectors("none (1, 0,0) (0,1.5,0)").unwrap(),
            vec![None, Some(vec![1.0, 0.0, 0.0]), Some(vec![0.0, 1.5, 0.0])]
        );
        assert!(parse_vectors("(1,0").is_err());
        assert!(parse_vectors("(1,x,0)").is_err());
    }

    crate::test_edits::header_property_tests! {
        parse: parse,
        tiny: TINY,
        path: "/nonexistent/x.nrrd",
        prefixes: [b"", b"NRRD0004\n"],
        lines: 2usize..11,
        separator: ": ",
    }
}
