//! MetaImage loader (`.mha` with inline data, `.mhd` with a detached data file), hand-written
//! (format reference: the MetaIO documentation of ITK).
//!
//! Read fields (`Key = Value` lines, keys case-insensitive, up to `ElementDataFile`, which must come
//! last): `NDims` (3), `DimSize`, `ElementType` (`MET_CHAR` ... `MET_DOUBLE`, `MET_LONG` = 32 bit),
//! `ElementNumberOfChannels` (1, or 3 for a vector volume, channels interleaved), `ElementSpacing`,
//! `Offset` / `Origin` / `Position`, `TransformMatrix` / `Rotation` / `Orientation` (nine numbers; the
//! i-th three are the direction of index axis i, as ITK reads them), `ElementByteOrderMSB` /
//! `BinaryDataByteOrderMSB`, `CompressedData` (zlib, or gzip detected by its magic), `HeaderSize`
//! (bytes to skip in a detached file; −1: data at the end) and `ElementDataFile` (`LOCAL` or one file
//! name relative to the header). MetaImage physical space is ITK's LPS in millimetres; positions and
//! vector components are flipped to RAS and scaled to metres. Unsupported (clear errors): ASCII data
//! (`BinaryData = False`), file lists, other dimensionalities.

use crate::decode::{decode_samples, inflate, Endian, ScalarType};
use crate::error::LoadProblem;
use crate::header_lines::{parse_value, HeaderLines};
use crate::loaded::{assemble, checked_voxel_count, FileFormat, Layout, LoadedVolume};
use crate::source::{check_budget, header_format_entry_points, DataRange, HeaderFile};
use glam::{DMat3, DVec3};
use std::path::Path;
use voxhap_core::volume::Grid;

/// LPS -> RAS: negate x and y.
const LPS_TO_RAS: DVec3 = DVec3::new(-1.0, -1.0, 1.0);

/// The header fields the loader uses.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MetaImageHeader {
    pub dims: Option<Vec<u64>>,
    pub ndims: Option<usize>,
    pub scalar_type: Option<ScalarType>,
    pub channels: usize,
    pub spacing: Option<Vec<f64>>,
    pub offset: Option<Vec<f64>>,
    pub transform: Option<Vec<f64>>,
    pub big_endian: bool,
    pub compressed: bool,
    pub header_size: i64,
    pub binary: bool,
    /// `None` for `LOCAL`.
    pub data_file: Option<String>,
    /// Where inline data starts (just after the `ElementDataFile` line).
    pub header_bytes: usize,
}

header_format_entry_points!(
    files: "`.mha` or `.mhd`",
    name: "MetaImage",
    budget: "`HeaderSize` plus the data `DimSize` describes"
);

/// The volume `header` describes, its data read from `file`.
fn from_header(header: MetaImageHeader, file: &HeaderFile) -> Result<LoadedVolume, LoadProblem> {
    if header.ndims.is_some_and(|n| n != 3) {
        return Err(LoadProblem::unsupported(format!(
            "NDims = {}: only 3-D images are read",
            header.ndims.unwrap_or(0)
        )));
    }
    let dims = match header.dims.as_deref() {
        Some(&[x, y, z]) => [x, y, z],
        Some(other) => {
            return Err(LoadProblem::unsupported(format!(
                "DimSize {other:?}: only 3-D images are read"
            )))
        }
        None => return Err(missing("DimSize")),
    };
    let scalar_type = header.scalar_type.ok_or_else(|| missing("ElementType"))?;
    if !header.binary {
        return Err(LoadProblem::unsupported("ASCII data (BinaryData = False)"));
    }
    let components = match header.channels {
        1 => 1,
        3 => 3,
        n => {
            return Err(LoadProblem::unsupported(format!(
                "ElementNumberOfChannels = {n}: only 1 (scalar) or 3 (vector)"
            )))
        }
    };
    let voxels = checked_voxel_count(dims, components as u64)?;
    let count = voxels * components;
    let expected_bytes = crate::loaded::data_bytes(count, scalar_type)?;
    check_budget(expected_bytes, count as u64, file.options)?;
    let grid = grid(&header, dims)?;

    let range = || match (header.compressed, header.header_size) {
        (true, _) => DataRange::From {
            skip: 0,
            needed: file.options.max_volume_bytes,
        },
        (false, -1) => DataRange::Tail {
            needed: expected_bytes,
        },
        (false, skip) => DataRange::From {
            skip: u64::try_from(skip).unwrap_or(0),
            needed: expected_bytes,
        },
    };
    let data = file.data(header.header_bytes, header.data_file.as_deref(), range)?;
    let inflated;
    let data = if header.compressed {
        inflated = inflate(&data, expected_bytes)?;
        &inflated[..]
    } else {
        // A detached file was read from HeaderSize on (or its tail for -1); inline data starts here.
        &data[..]
    };
    let endian = if header.big_endian {
        Endian::Big
    } else {
        Endian::Little
    };
    let decoded = decode_samples(data, scalar_type, endian, count, None)?;
    let layout = Layout::interleaved(
        scalar_type,
        FileFormat::MetaImage,
        components,
        LPS_TO_RAS.as_vec3().to_array(),
    );
    assemble(grid, decoded, &layout, file.path)
}

fn missing(field: &str) -> LoadProblem {
    LoadProblem::header(format!("missing required field {field}"))
}

fn grid(header: &MetaImageHeader, dims: [u64; 3]) -> Result<Grid, LoadProblem> {
    let three = |name: &str, values: &Option<Vec<f64>>, default: [f64; 3]| match values.as_deref() {
        None => Ok(DVec3::from_array(default)),
        Some(&[x, y, z]) => Ok(DVec3::new(x, y, z)),
        Some(other) => Err(LoadProblem::header(format!(
            "{name} has {} values, expected 3",
            other.len()
        ))),
    };
    let spacing_mm = three("ElementSpacing", &header.spacing, [1.0; 3])?;
    let offset_mm = three("Offset", &header.offset, [0.0; 3])?;
    let direction = match header.transform.as_deref() {
        None => DMat3::IDENTITY,
        Some(values) if values.len() == 9 => DMat3::from_cols_slice(values),
        Some(values) => {
            return Err(LoadProblem::header(format!(
                "TransformMatrix has {} values, expected 9",
                values.len()
            )))
        }
    };
    let flip = DMat3::from_diagonal(LPS_TO_RAS);
    Ok(Grid::new(
        dims.map(|d| d as usize),
        spacing_mm * 1e-3,
        flip * direction,
        flip * offset_mm * 1e-3,
    )?)
}

/// Parses the header lines up to and including `ElementDataFile`.
pub fn parse_header(bytes: &[u8]) -> Result<MetaImageHeader, LoadProblem> {
    let mut header = MetaImageHeader {
        channels: 1,
        binary: true,
        ..MetaImageHeader::default()
    };
    let mut lines = HeaderLines::new(bytes);
    loop {
        let Some(line) = lines.next() else {
            return Err(missing("ElementDataFile (it must be the last header line)"));
        };
        let line = line?.trim();
        let line_number = lines.line_number();
        if line.is_empty() {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(LoadProblem::header(format!(
                "line {line_number} {line:?} is not \"Key = Value\""
            )));
        };
        let key = key.trim().to_ascii_lowercase();
        let value = value.trim();
        let done = key == "elementdatafile";
        parse_field(&mut header, &key, value).map_err(|message| {
            LoadProblem::header(format!("line {line_number} ({}): {message}", key))
        })?;
        if done {
            header.header_bytes = lines.position();
            return Ok(header);
        }
    }
}

/// What is wrong with the value of one MetaImage header field (the line and key are added by the caller).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetaImageFieldError {
    #[error("ObjectType {value:?} is not Image")]
    NotImage { value: String },
    #[error("{value:?} is not a valid number")]
    NotANumber { value: String },
    #[error("spacing {spacing:?} must be finite and positive")]
    SpacingNotPositive { spacing: Vec<f64> },
    #[error("{value:?} has non-finite numbers")]
    NonFinite { value: String },
    #[error("{value:?} is not True or False")]
    NotBoolean { value: String },
    #[error("ElementType {value:?} is not supported")]
    UnsupportedElementType { value: String },
    #[error("HeaderSize {size} must be >= -1")]
    HeaderSize { size: i64 },
    #[error("multi-file data {value:?} is not supported")]
    MultiFile { value: String },
}

fn parse_field(
    header: &mut MetaImageHeader,
    key: &str,
    value: &str,
) -> Result<(), MetaImageFieldError> {
    match key {
        "objecttype" if !value.eq_ignore_ascii_case("image") => {
            return Err(MetaImageFieldError::NotImage {
                value: value.to_owned(),
            })
        }
        "ndims" => header.ndims = Some(number(value)?),
        "dimsize" => header.dims = Some(numbers(value)?),
        "elementtype" => header.scalar_type = Some(element_type(value)?),
        "elementnumberofchannels" => header.channels = number(value)?,
        "elementspacing" => {
            let spacing: Vec<f64> = numbers(value)?;
            if spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(MetaImageFieldError::SpacingNotPositive { spacing });
            }
            header.spacing = Some(spacing)
        }
        "offset" | "origin" | "position" => header.offset = Some(finite_numbers(value)?),
        "transformmatrix" | "rotation" | "orientation" => {
            header.transform = Some(finite_numbers(value)?)
        }
        "elementbyteordermsb" | "binarydatabyteordermsb" => header.big_endian = boolean(value)?,
        "compresseddata" => header.compressed = boolean(value)?,
        "binarydata" => header.binary = boolean(value)?,
        "headersize" => {
            let size: i64 = number(value)?;
            if size < -1 {
                return Err(MetaImageFieldError::HeaderSize { size });
            }
            header.header_size = size
        }
        "elementdatafile" => {
            if value.eq_ignore_ascii_case("local") {
                header.data_file = None;
            } else if value.eq_ignore_ascii_case("list")
                || value.contains('%')
                || value.split_whitespace().count() != 1
            {
                return Err(MetaImageFieldError::MultiFile {
                    value: value.to_owned(),
                });
            } else {
                header.data_file = Some(value.to_owned());
            }
        }
        _ => {} // Comment, AnatomicalOrientation, CenterOfRotation, ElementSize, ...
    }
    Ok(())
}

fn number<T: std::str::FromStr>(value: &str) -> Result<T, MetaImageFieldError> {
    parse_value(value, |value| MetaImageFieldError::NotANumber { value })
}

fn numbers<T: std::str::FromStr>(value: &str) -> Result<Vec<T>, MetaImageFieldError> {
    value.split_whitespace().map(number).collect()
}

fn finite_numbers(value: &str) -> Result<Vec<f64>, MetaImageFieldError> {
    let values: Vec<f64> = numbers(value)?;
    if values.iter().all(|v| v.is_finite()) {
        Ok(values)
    } else {
        Err(MetaImageFieldError::NonFinite {
            value: value.to_owned(),
        })
    }
}

fn boolean(value: &str) -> Result<bool, MetaImageFieldError> {
    match value.to_ascii_lowercase().as_str() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(MetaImageFieldError::NotBoolean {
            value: value.to_owned(),
        }),
    }
}

fn element_type(value: &str) -> Result<ScalarType, MetaImageFieldError> {
    let name = value.to_ascii_uppercase();
    let name = name.strip_suffix("_ARRAY").unwrap_or(&name);
    Ok(match name {
        "MET_CHAR" => ScalarType::I8,
        "MET_UCHAR" => ScalarType::U8,
        "MET_SHORT" => ScalarType::I16,
        "MET_USHORT" => ScalarType::U16,
        "MET_INT" | "MET_LONG" => ScalarType::I32,
        "MET_UINT" | "MET_ULONG" => ScalarType::U32,
        "MET_LONG_LONG" => ScalarType::I64,
        "MET_ULONG_LONG" => ScalarType::U64,
        "MET_FLOAT" => ScalarType::F32,
        "MET_DOUBLE" => ScalarType::F64,
        _ => {
            return Err(MetaImageFieldError::UnsupportedElementType {
                value: value.to_owned(),
            })
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &[u8] =
        b"ObjectType = Image\nNDims = 3\nDimSize = 2 1 1\nElementType = MET_SHORT\n\
ElementSpacing = 2 3 4\nOffset = 10 20 30\nTransformMatrix = 0 1 0 -1 0 0 0 0 1\n\
ElementByteOrderMSB = True\nElementDataFile = LOCAL\n\x00\x05\xff\xfe";

    #[test]
    fn tiny_inline_file_loads_in_ras() {
        let loaded = parse(TINY, Path::new("tiny.mha")).unwrap();
        let grid = loaded.volume.grid();
        assert_eq!(grid.dims(), [2, 1, 1]);
        assert!((grid.origin_m() - DVec3::new(-0.010, -0.020, 0.030)).length() < 1e-12);
        // Index axis i points along LPS +y, which is RAS -y.
        assert!((grid.direction().x_axis - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-12);
        assert!((grid.direction().y_axis - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-12);
        assert_eq!(loaded.volume.value_range(), (-2.0, 5.0));
    }

    #[test]
    fn header_errors_are_specific() {
        let message = parse(
            b"NDims = 3\nDimSize = 2 2\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n",
            Path::new("x.mha"),
        )
        .unwrap_err()
        .to_string();
        assert!(message.contains("DimSize"), "{message}");
        let message = parse(b"NDims = 3\n", Path::new("x.mha"))
            .unwrap_err()
            .to_string();
        assert!(message.contains("ElementDataFile"), "{message}");
    }

    crate::test_edits::header_property_tests! {
        parse: parse,
        tiny: TINY,
        path: "/nonexistent/x.mha",
        prefixes: [b""],
        lines: 0usize..9,
        separator: " = ",
    }
}
