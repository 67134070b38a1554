//! Helpers of the volume loader tests (tests/volume_io/): where the repository's real scans are, and the synthetic volume
//! every written test file describes (its grid, its values per scalar type, their bytes in either byte order, and
//! the header fields each format names the types by).

use glam::DVec3;
use std::io::Write;
use std::path::{Path, PathBuf};
use voxhap::volume::io::{LoadedVolume, ScalarType};
use voxhap::volume::AnyVolume;

/// A real scan shipped in the repository's `data/` folder (data/NOTICE.md says where each comes from).
/// It is part of the repository, so a missing file fails the test instead of skipping it.
pub fn real_scan(name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name);
    assert!(
        path.is_file(),
        "{} is missing: the real scans are part of the repository (data/NOTICE.md)",
        path.display()
    );
    path
}

pub fn scalar(loaded: &LoadedVolume) -> &voxhap::volume::ScalarVolume {
    match &loaded.volume {
        AnyVolume::Scalar(volume) => volume,
        AnyVolume::Vector(_) => panic!("expected a scalar volume"),
    }
}

pub const DIMS: [usize; 3] = [3, 4, 5];
/// Spacing (mm) and RAS origin (mm) every written file describes.
pub const SPACING_MM: [f64; 3] = [0.5, 1.0, 2.0];
pub const ORIGIN_MM: [f64; 3] = [1.0, -2.0, 3.0];

pub fn voxel_count() -> usize {
    DIMS.iter().product()
}

/// The test value of element `n`, within range of every type (negative for signed types).
pub fn value(scalar_type: ScalarType, n: usize) -> f64 {
    let signed = matches!(
        scalar_type,
        ScalarType::I8
            | ScalarType::I16
            | ScalarType::I32
            | ScalarType::I64
            | ScalarType::F32
            | ScalarType::F64
    );
    let base = n as f64 * 2.0 - if signed { 50.0 } else { 0.0 };
    if matches!(scalar_type, ScalarType::F32 | ScalarType::F64) {
        base + 0.25
    } else {
        base
    }
}

pub fn encode(scalar_type: ScalarType, big: bool, values: impl Iterator<Item = f64>) -> Vec<u8> {
    let mut out = Vec::new();
    for v in values {
        let mut bytes: Vec<u8> = match scalar_type {
            ScalarType::U8 => (v as u8).to_le_bytes().into(),
            ScalarType::I8 => (v as i8).to_le_bytes().into(),
            ScalarType::U16 => (v as u16).to_le_bytes().into(),
            ScalarType::I16 => (v as i16).to_le_bytes().into(),
            ScalarType::U32 => (v as u32).to_le_bytes().into(),
            ScalarType::I32 => (v as i32).to_le_bytes().into(),
            ScalarType::U64 => (v as u64).to_le_bytes().into(),
            ScalarType::I64 => (v as i64).to_le_bytes().into(),
            ScalarType::F32 => (v as f32).to_le_bytes().into(),
            ScalarType::F64 => v.to_le_bytes().into(),
        };
        if big {
            bytes.reverse();
        }
        out.extend(bytes);
    }
    out
}

pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

pub fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

/// Scalar data, x fastest.
pub fn scalar_bytes(scalar_type: ScalarType, big: bool) -> Vec<u8> {
    encode(
        scalar_type,
        big,
        (0..voxel_count()).map(|n| value(scalar_type, n)),
    )
}

/// Checks the grid every written file describes and the stored scalar values.
pub fn check_scalar(loaded: &LoadedVolume, scalar_type: ScalarType, label: &str) {
    assert_eq!(loaded.source_type, scalar_type, "{label}");
    let volume = scalar(loaded);
    check_grid(volume.grid(), label);
    let expected: Vec<f32> = (0..voxel_count())
        .map(|n| value(scalar_type, n) as f32)
        .collect();
    assert_eq!(volume.data(), expected.as_slice(), "{label}");
}

pub fn check_grid(grid: &voxhap::volume::Grid, label: &str) {
    assert_eq!(grid.dims(), DIMS, "{label}");
    assert!(
        (grid.spacing_m() - DVec3::from_array(SPACING_MM) * 1e-3).length() < 1e-12,
        "{label}: spacing {}",
        grid.spacing_m()
    );
    assert!(
        (grid.origin_m() - DVec3::from_array(ORIGIN_MM) * 1e-3).length() < 1e-12,
        "{label}: origin {}",
        grid.origin_m()
    );
    assert!(
        grid.direction().abs_diff_eq(glam::DMat3::IDENTITY, 1e-12),
        "{label}: direction {}",
        grid.direction()
    );
}

pub fn nrrd_type(scalar_type: ScalarType) -> &'static str {
    match scalar_type {
        ScalarType::U8 => "uint8",
        ScalarType::I8 => "signed char",
        ScalarType::U16 => "unsigned short",
        ScalarType::I16 => "int16",
        ScalarType::U32 => "uint",
        ScalarType::I32 => "int32_t",
        ScalarType::U64 => "unsigned long long int",
        ScalarType::I64 => "int64",
        ScalarType::F32 => "float",
        ScalarType::F64 => "double",
    }
}

pub fn metaimage_type(scalar_type: ScalarType) -> &'static str {
    match scalar_type {
        ScalarType::U8 => "MET_UCHAR",
        ScalarType::I8 => "MET_CHAR",
        ScalarType::U16 => "MET_USHORT",
        ScalarType::I16 => "MET_SHORT",
        ScalarType::U32 => "MET_UINT",
        ScalarType::I32 => "MET_INT",
        ScalarType::U64 => "MET_ULONG_LONG",
        ScalarType::I64 => "MET_LONG_LONG",
        ScalarType::F32 => "MET_FLOAT",
        ScalarType::F64 => "MET_DOUBLE",
    }
}

pub fn nifti_datatype(scalar_type: ScalarType) -> i16 {
    match scalar_type {
        ScalarType::U8 => 2,
        ScalarType::I16 => 4,
        ScalarType::I32 => 8,
        ScalarType::F32 => 16,
        ScalarType::F64 => 64,
        ScalarType::I8 => 256,
        ScalarType::U16 => 512,
        ScalarType::U32 => 768,
        ScalarType::I64 => 1024,
        ScalarType::U64 => 1280,
    }
}

/// The NRRD header lines describing the common grid (RAS) for `dimension` axes.
pub fn nrrd_header(scalar_type: ScalarType, big: bool, encoding: &str, vector: bool) -> String {
    let [x, y, z] = SPACING_MM;
    let [ox, oy, oz] = ORIGIN_MM;
    let (dimension, sizes, none) = if vector {
        (4, format!("3 {} {} {}", DIMS[0], DIMS[1], DIMS[2]), "none ")
    } else {
        (3, format!("{} {} {}", DIMS[0], DIMS[1], DIMS[2]), "")
    };
    format!(
        "NRRD0005\n# written by voxhap tests\ntype: {}\ndimension: {dimension}\nspace: RAS\nsizes: {sizes}\n\
         space directions: {none}({x},0,0) (0,{y},0) (0,0,{z})\nendian: {}\nencoding: {encoding}\n\
         space origin: ({ox},{oy},{oz})\nspace units: \"mm\" \"mm\" \"mm\"\n",
        nrrd_type(scalar_type),
        if big { "big" } else { "little" },
    )
}
