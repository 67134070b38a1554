//! Raw volume loader: a binary data file described by a small TOML header (`.toml`).
//!
//! Schema (unknown keys are errors, so typos are caught):
//!
//! ```toml
//! data_file = "head.raw"            # required; relative to the header's folder
//! dims = [256, 256, 128]            # required; voxels along i, j, k (i fastest in the file)
//! scalar_type = "u16"               # required; u8 i8 u16 i16 u32 i32 u64 i64 f32 f64
//! endianness = "little"             # required for multi-byte types; "little" or "big"
//! spacing = [0.9, 0.9, 1.2]         # required; distance between voxel centres, in `units`
//! origin = [-115.0, -115.0, -76.8]  # optional, default [0, 0, 0]; world position of voxel (0,0,0)
//! direction = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]  # optional; direction[a] = world unit vector of index axis a
//! units = "mm"                      # optional, default "mm"; also "m", "cm", "um"
//! components = 1                    # optional, default 1; 3 = vector volume, components interleaved
//! header_bytes = 0                  # optional; bytes to skip at the start of the data file
//! compression = "none"              # optional; "none", "gzip" or "zlib"
//! ```
//!
//! The world frame is taken to be RAS as written (no flip).

use crate::decode::{decode_samples, inflate, Endian, ScalarType};
use crate::error::LoadProblem;
use crate::loaded::{
    assemble, checked_voxel_count, metres_per_unit, FileFormat, Layout, LoadedVolume,
};
use crate::source::{
    check_budget, data_file_path, read_data_file, read_regular, DataRange, LoadOptions,
    MAX_HEADER_BYTES,
};
use glam::{DMat3, DVec3};
use serde::Deserialize;
use std::path::Path;
use voxhap_core::volume::Grid;

/// The TOML header.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawHeader {
    pub data_file: String,
    pub dims: [u64; 3],
    pub scalar_type: String,
    pub endianness: Option<String>,
    pub spacing: [f64; 3],
    #[serde(default)]
    pub origin: [f64; 3],
    pub direction: Option<[[f64; 3]; 3]>,
    pub units: Option<String>,
    #[serde(default = "one")]
    pub components: usize,
    #[serde(default)]
    pub header_bytes: usize,
    pub compression: Option<String>,
}

fn one() -> usize {
    1
}

/// Loads a raw volume through its `.toml` header with the default limits.
pub fn load(path: &Path) -> Result<LoadedVolume, LoadProblem> {
    load_with(path, &LoadOptions::default())
}

/// Loads a raw volume through its `.toml` header within `options`' limits: the header is at most 1 MiB,
/// the data `dims` describe is checked against `--max-volume-bytes` before the data file is read (its
/// `header_bytes` are sought past, not read), and the data file must lie in the header's folder.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<LoadedVolume, LoadProblem> {
    let text = read_regular(path, MAX_HEADER_BYTES, "a raw volume's TOML header")
        .map_err(LoadProblem::File)?;
    let header = parse_header(&text)?;
    let scalar_type = ScalarType::from_name(&header.scalar_type).ok_or_else(|| {
        LoadProblem::header(format!(
            "scalar_type {:?} is not one of u8 i8 u16 i16 u32 i32 u64 i64 f32 f64",
            header.scalar_type
        ))
    })?;
    let voxels = checked_voxel_count(header.dims, header.components.max(1) as u64)?;
    let count = voxels * header.components.max(1);
    let expected_bytes = crate::loaded::data_bytes(count, scalar_type)?;
    check_budget(expected_bytes, count as u64, options)?;
    let data_path = data_file_path(path, &header.data_file, options)?;
    let compressed = !matches!(header.compression.as_deref(), None | Some("none"));
    if compressed {
        let range = DataRange::From {
            skip: 0,
            needed: options.max_volume_bytes,
        };
        let data = read_data_file(&data_path, range, options)?;
        return decode_with_header(&header, &data, path);
    }
    // Uncompressed: `header_bytes` is sought past, not read.
    let range = DataRange::From {
        skip: header.header_bytes as u64,
        needed: expected_bytes,
    };
    let data = read_data_file(&data_path, range, options)?;
    let mut after_header = header;
    after_header.header_bytes = 0;
    decode_with_header(&after_header, &data, path)
}

/// Parses the TOML header.
pub fn parse_header(text: &[u8]) -> Result<RawHeader, LoadProblem> {
    let text = std::str::from_utf8(text)
        .map_err(|_| LoadProblem::header("the header is not UTF-8 text"))?;
    toml::from_str(text).map_err(|err| LoadProblem::header(err.to_string().trim_end().to_owned()))
}

/// Decodes the data file's bytes as the header describes.
pub fn decode_with_header(
    header: &RawHeader,
    data: &[u8],
    path: &Path,
) -> Result<LoadedVolume, LoadProblem> {
    let scalar_type = ScalarType::from_name(&header.scalar_type).ok_or_else(|| {
        LoadProblem::header(format!(
            "scalar_type {:?} is not one of u8 i8 u16 i16 u32 i32 u64 i64 f32 f64",
            header.scalar_type
        ))
    })?;
    let endian = match header.endianness.as_deref() {
        Some("little") => Endian::Little,
        Some("big") => Endian::Big,
        None if scalar_type.size_bytes() == 1 => Endian::Little,
        None => {
            return Err(LoadProblem::header(
                "endianness is required for multi-byte types",
            ))
        }
        Some(other) => {
            return Err(LoadProblem::header(format!(
                "endianness {other:?} is not \"little\" or \"big\""
            )))
        }
    };
    if !matches!(header.components, 1 | 3) {
        return Err(LoadProblem::header(format!(
            "components = {} must be 1 (scalar) or 3 (vector)",
            header.components
        )));
    }
    let units = header.units.as_deref().unwrap_or("mm");
    let metres = metres_per_unit(units)
        .ok_or_else(|| LoadProblem::header(format!("units {units:?} is not mm, m, cm or um")))?;
    let voxels = checked_voxel_count(header.dims, header.components as u64)?;
    let count = voxels * header.components;
    let direction = header
        .direction
        .map_or(DMat3::IDENTITY, |rows| DMat3::from_cols_array_2d(&rows));
    let grid = Grid::new(
        header.dims.map(|d| d as usize),
        DVec3::from_array(header.spacing) * metres,
        direction,
        DVec3::from_array(header.origin) * metres,
    )?;
    let data = data
        .get(header.header_bytes..)
        .ok_or(LoadProblem::Truncated {
            expected_bytes: header.header_bytes as u64,
            actual_bytes: data.len() as u64,
        })?;
    let expected_bytes = crate::loaded::data_bytes(count, scalar_type)?;
    let inflated;
    let data = match header.compression.as_deref() {
        None | Some("none") => data,
        Some("gzip") | Some("zlib") => {
            inflated = inflate(data, expected_bytes)?;
            &inflated[..]
        }
        Some(other) => {
            return Err(LoadProblem::header(format!(
                "compression {other:?} is not none, gzip or zlib"
            )))
        }
    };
    let decoded = decode_samples(data, scalar_type, endian, count, None)?;
    let layout = Layout::interleaved(
        scalar_type,
        FileFormat::RawToml,
        header.components,
        [1.0; 3],
    );
    assemble(grid, decoded, &layout, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const HEADER: &str = r#"
data_file = "x.raw"
dims = [2, 1, 1]
scalar_type = "i16"
endianness = "big"
spacing = [2.0, 3.0, 4.0]
origin = [1.0, 2.0, 3.0]
direction = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
"#;

    #[test]
    fn header_and_data_decode() {
        let header = parse_header(HEADER.as_bytes()).unwrap();
        let loaded = decode_with_header(&header, &[0, 5, 0xff, 0xfe], Path::new("x.toml")).unwrap();
        let grid = loaded.volume.grid();
        assert_eq!(grid.direction().x_axis, DVec3::Y);
        assert!((grid.origin_m() - DVec3::new(0.001, 0.002, 0.003)).length() < 1e-15);
        assert_eq!(loaded.volume.value_range(), (-2.0, 5.0));
    }

    #[test]
    fn typos_and_bad_values_are_reported() {
        let typo = HEADER.replace("spacing", "spaceing");
        let message = parse_header(typo.as_bytes()).unwrap_err().to_string();
        assert!(message.contains("spaceing"), "{message}");
        let header = parse_header(HEADER.replace("\"i16\"", "\"int\"").as_bytes()).unwrap();
        let message = decode_with_header(&header, &[0; 4], Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(message.contains("scalar_type"), "{message}");
    }

    proptest! {
        #[test]
        fn arbitrary_headers_and_data_never_panic(
            text in "[ -~\n]{0,200}",
            data in proptest::collection::vec(any::<u8>(), 0..32),
        ) {
            if let Ok(header) = parse_header(text.as_bytes()) {
                let _ = decode_with_header(&header, &data, Path::new("x.toml"));
            }
        }

        #[test]
        fn mutated_header_values_never_panic(
            line in 1usize..8, value in "[ -~]{0,24}",
            data in proptest::collection::vec(any::<u8>(), 0..8),
        ) {
            let text = crate::test_edits::with_field_value(HEADER.as_bytes(), line, " = ", &value);
            if let Ok(header) = parse_header(text.as_bytes()) {
                let _ = decode_with_header(&header, &data, Path::new("x.toml"));
            }
        }
    }
}
