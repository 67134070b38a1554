//! Volume loaders end to end: the real scans in ../shared/data against numbers from independent
//! readers, every format/encoding/endianness/type combination written here into a temp dir, and the
//! `voxhap info` binary.

use glam::{DMat4, DVec3, DVec4};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use voxhap::volume::io::{load, FileFormat, LoadedVolume, ScalarType};
use voxhap::volume::AnyVolume;

// ---------------------------------------------------------------------------------------------
// Real scans

fn shared_data(name: &str) -> Option<PathBuf> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(name);
    if path.exists() {
        Some(path)
    } else {
        eprintln!(
            "SKIPPED: {} is absent (real volumes live in ../shared/data)",
            path.display()
        );
        None
    }
}

fn scalar(loaded: &LoadedVolume) -> &voxhap::volume::ScalarVolume {
    match &loaded.volume {
        AnyVolume::Scalar(volume) => volume,
        AnyVolume::Vector(_) => panic!("expected a scalar volume"),
    }
}

/// Row-major 4x4 in millimetres -> glam affine in metres.
fn affine_mm(rows: [[f64; 4]; 3]) -> DMat4 {
    let mut m =
        DMat4::from_cols_array_2d(&[rows[0], rows[1], rows[2], [0.0, 0.0, 0.0, 1.0]]).transpose();
    for c in 0..4 {
        let col = m.col(c);
        *m.col_mut(c) = DVec4::new(col.x * 1e-3, col.y * 1e-3, col.z * 1e-3, col.w);
    }
    m
}

fn sum(values: &[f32]) -> f64 {
    values.iter().map(|&v| f64::from(v)).sum()
}

// Reference numbers below come from nibabel 5.4.2 (NIfTI) and pynrrd 1.1.3 (NRRD), numpy
// indexing [i, j, k]: `nib.load(f).affine`, `np.asanyarray(img.dataobj)[i, j, k]`, `.sum()`.

#[test]
fn mni152_t1_nifti_matches_nibabel() {
    let Some(path) = shared_data("mni152_t1_1mm.nii.gz") else {
        return;
    };
    let loaded = load(&path).unwrap();
    assert_eq!(loaded.format, FileFormat::Nifti);
    assert_eq!(loaded.source_type, ScalarType::U8);
    let volume = scalar(&loaded);
    let grid = volume.grid();
    assert_eq!(grid.dims(), [197, 233, 189]);
    assert_eq!(grid.spacing_m(), DVec3::splat(0.001));
    let expected = affine_mm([
        [1.0, 0.0, 0.0, -98.0],
        [0.0, 1.0, 0.0, -134.0],
        [0.0, 0.0, 1.0, -72.0],
    ]);
    assert!(
        grid.affine().abs_diff_eq(expected, 1e-12),
        "{}",
        grid.affine()
    );
    assert_eq!(volume.value_range(), (0.0, 255.0));
    for ([i, j, k], value) in [
        ([0, 0, 0], 0.0),
        ([98, 116, 94], 198.0),
        ([100, 120, 80], 175.0),
        ([50, 60, 70], 156.0),
    ] {
        assert_eq!(volume.voxel(i, j, k), Some(value), "voxel {i},{j},{k}");
    }
    assert_eq!(sum(volume.data()), 333_468_829.0);
    // World position of voxel (98, 116, 94) is (0, -18, 22) mm: sampling there gives the voxel.
    assert!((volume.sample(DVec3::new(0.0, -0.018, 0.022)) - 198.0).abs() < 1e-9);
}

#[test]
fn nibabel_anatomical_big_endian_nifti_matches_nibabel() {
    let Some(path) = shared_data("nibabel_anatomical.nii") else {
        return;
    };
    let loaded = load(&path).unwrap();
    assert_eq!(loaded.source_type, ScalarType::I16);
    let volume = scalar(&loaded);
    let grid = volume.grid();
    assert_eq!(grid.dims(), [33, 41, 25]);
    assert!((grid.spacing_m() - DVec3::splat(0.002)).length() < 1e-15);
    let expected = affine_mm([
        [-2.0, 0.0, 0.0, 32.0],
        [0.0, 2.0, 0.0, -40.0],
        [0.0, 0.0, 2.0, -16.0],
    ]);
    assert!(
        grid.affine().abs_diff_eq(expected, 1e-12),
        "{}",
        grid.affine()
    );
    assert_eq!(volume.value_range(), (-610.0, 30393.0));
    for ([i, j, k], value) in [
        ([0, 0, 0], 10712.0),
        ([10, 20, 10], 12482.0),
        ([16, 20, 12], 11881.0),
        ([32, 40, 24], 2971.0),
    ] {
        assert_eq!(volume.voxel(i, j, k), Some(value), "voxel {i},{j},{k}");
    }
    assert_eq!(sum(volume.data()), 284_166_082.0);
}

#[test]
fn mni152_white_matter_nrrd_matches_pynrrd() {
    let Some(path) = shared_data("mni152_wm_1mm.nrrd") else {
        return;
    };
    let loaded = load(&path).unwrap();
    assert_eq!(loaded.format, FileFormat::Nrrd);
    assert_eq!(loaded.source_type, ScalarType::U8);
    let volume = scalar(&loaded);
    let grid = volume.grid();
    assert_eq!(grid.dims(), [197, 233, 189]);
    // space: right-anterior-superior, directions identity, origin (-98, -134, -72) mm.
    let expected = affine_mm([
        [1.0, 0.0, 0.0, -98.0],
        [0.0, 1.0, 0.0, -134.0],
        [0.0, 0.0, 1.0, -72.0],
    ]);
    assert!(
        grid.affine().abs_diff_eq(expected, 1e-12),
        "{}",
        grid.affine()
    );
    assert_eq!(volume.value_range(), (0.0, 255.0));
    for ([i, j, k], value) in [
        ([0, 0, 0], 0.0),
        ([98, 116, 94], 124.0),
        ([100, 120, 80], 2.0),
        ([50, 60, 70], 11.0),
        ([70, 100, 90], 251.0),
    ] {
        assert_eq!(volume.voxel(i, j, k), Some(value), "voxel {i},{j},{k}");
    }
    assert_eq!(sum(volume.data()), 170_935_158.0);
}

// ---------------------------------------------------------------------------------------------
// Written files: every format, encoding, byte order and type

const DIMS: [usize; 3] = [3, 4, 5];
/// Spacing (mm) and RAS origin (mm) every written file describes.
const SPACING_MM: [f64; 3] = [0.5, 1.0, 2.0];
const ORIGIN_MM: [f64; 3] = [1.0, -2.0, 3.0];

fn voxel_count() -> usize {
    DIMS.iter().product()
}

/// The test value of element `n`, within range of every type (negative for signed types).
fn value(scalar_type: ScalarType, n: usize) -> f64 {
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

fn encode(scalar_type: ScalarType, big: bool, values: impl Iterator<Item = f64>) -> Vec<u8> {
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

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

fn zlib(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

/// Scalar data, x fastest.
fn scalar_bytes(scalar_type: ScalarType, big: bool) -> Vec<u8> {
    encode(
        scalar_type,
        big,
        (0..voxel_count()).map(|n| value(scalar_type, n)),
    )
}

/// Checks the grid every written file describes and the stored scalar values.
fn check_scalar(loaded: &LoadedVolume, scalar_type: ScalarType, label: &str) {
    assert_eq!(loaded.source_type, scalar_type, "{label}");
    let volume = scalar(loaded);
    check_grid(volume.grid(), label);
    let expected: Vec<f32> = (0..voxel_count())
        .map(|n| value(scalar_type, n) as f32)
        .collect();
    assert_eq!(volume.data(), expected.as_slice(), "{label}");
}

fn check_grid(grid: &voxhap::volume::Grid, label: &str) {
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

fn nrrd_type(scalar_type: ScalarType) -> &'static str {
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

fn metaimage_type(scalar_type: ScalarType) -> &'static str {
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

fn nifti_datatype(scalar_type: ScalarType) -> i16 {
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
fn nrrd_header(scalar_type: ScalarType, big: bool, encoding: &str, vector: bool) -> String {
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

#[test]
fn nrrd_every_type_endian_encoding_attached_and_detached() {
    let dir = tempfile::tempdir().unwrap();
    for scalar_type in ScalarType::ALL {
        for big in [false, true] {
            for encoding in ["raw", "gzip", "ascii"] {
                let raw = scalar_bytes(scalar_type, big);
                let payload = match encoding {
                    "raw" => raw,
                    "gzip" => gzip(&raw),
                    _ => (0..voxel_count())
                        .map(|n| format!("{}\n", value(scalar_type, n)))
                        .collect::<String>()
                        .into_bytes(),
                };
                let header = nrrd_header(scalar_type, big, encoding, false);
                let stem = format!("{scalar_type}_{big}_{encoding}");
                // Attached.
                let attached = dir.path().join(format!("{stem}.nrrd"));
                let mut bytes = format!("{header}\n").into_bytes();
                bytes.extend_from_slice(&payload);
                std::fs::write(&attached, bytes).unwrap();
                check_scalar(&load(&attached).unwrap(), scalar_type, &stem);
                // Detached.
                let detached = dir.path().join(format!("{stem}.nhdr"));
                std::fs::write(dir.path().join(format!("{stem}.data")), &payload).unwrap();
                std::fs::write(&detached, format!("{header}data file: {stem}.data\n")).unwrap();
                check_scalar(
                    &load(&detached).unwrap(),
                    scalar_type,
                    &format!("{stem} detached"),
                );
            }
        }
    }
}

#[test]
fn nrrd_lps_vector_volume_is_flipped_to_ras() {
    let dir = tempfile::tempdir().unwrap();
    let count = voxel_count();
    let vectors: Vec<[f64; 3]> = (0..count)
        .map(|n| [n as f64, -(n as f64) * 0.5, 2.0])
        .collect();
    let raw = encode(ScalarType::F32, false, vectors.iter().flatten().copied());
    // The same RAS grid written in LPS: negate x and y of the directions and the origin.
    let [x, y, z] = SPACING_MM;
    let [ox, oy, oz] = ORIGIN_MM;
    let header = format!(
        "NRRD0004\ntype: float\ndimension: 4\nspace: left-posterior-superior\nsizes: 3 {} {} {}\n\
         space directions: none ({},0,0) (0,{},0) (0,0,{z})\nkinds: vector domain domain domain\n\
         endian: little\nencoding: raw\nspace origin: ({},{},{oz})\n\n",
        DIMS[0], DIMS[1], DIMS[2], -x, -y, -ox, -oy,
    );
    let path = dir.path().join("flow.nrrd");
    let mut bytes = header.into_bytes();
    bytes.extend(raw);
    std::fs::write(&path, bytes).unwrap();
    let loaded = load(&path).unwrap();
    let AnyVolume::Vector(volume) = &loaded.volume else {
        panic!("expected a vector volume")
    };
    check_grid(volume.grid(), "lps vector");
    for (n, v) in vectors.iter().enumerate() {
        let expected = [-v[0] as f32, -v[1] as f32, v[2] as f32];
        assert_eq!(volume.data()[n], expected, "vector {n}");
    }
}

fn metaimage_header(
    scalar_type: ScalarType,
    big: bool,
    compressed: bool,
    channels: usize,
) -> String {
    // MetaImage space is LPS: the RAS grid has offset (-x, -y, z) and direction diag(-1, -1, 1).
    let [sx, sy, sz] = SPACING_MM;
    let [ox, oy, oz] = ORIGIN_MM;
    format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nElementByteOrderMSB = {}\n\
         CompressedData = {}\nTransformMatrix = -1 0 0 0 -1 0 0 0 1\nOffset = {} {} {oz}\n\
         ElementSpacing = {sx} {sy} {sz}\nDimSize = {} {} {}\nElementNumberOfChannels = {channels}\n\
         ElementType = {}\n",
        if big { "True" } else { "False" },
        if compressed { "True" } else { "False" },
        -ox,
        -oy,
        DIMS[0],
        DIMS[1],
        DIMS[2],
        metaimage_type(scalar_type),
    )
}

#[test]
fn metaimage_every_type_endian_compression_inline_and_detached() {
    let dir = tempfile::tempdir().unwrap();
    for scalar_type in ScalarType::ALL {
        for big in [false, true] {
            for compressed in [false, true] {
                let raw = scalar_bytes(scalar_type, big);
                let payload = if compressed { zlib(&raw) } else { raw };
                let header = metaimage_header(scalar_type, big, compressed, 1);
                let stem = format!("{scalar_type}_{big}_{compressed}");
                let inline = dir.path().join(format!("{stem}.mha"));
                let mut bytes = format!("{header}ElementDataFile = LOCAL\n").into_bytes();
                bytes.extend_from_slice(&payload);
                std::fs::write(&inline, bytes).unwrap();
                check_scalar(&load(&inline).unwrap(), scalar_type, &stem);
                let detached = dir.path().join(format!("{stem}.mhd"));
                std::fs::write(dir.path().join(format!("{stem}.raw")), &payload).unwrap();
                std::fs::write(&detached, format!("{header}ElementDataFile = {stem}.raw\n"))
                    .unwrap();
                check_scalar(
                    &load(&detached).unwrap(),
                    scalar_type,
                    &format!("{stem} detached"),
                );
            }
        }
    }
}

#[test]
fn metaimage_vector_components_are_flipped_from_lps() {
    let dir = tempfile::tempdir().unwrap();
    let count = voxel_count();
    let raw = encode(
        ScalarType::F64,
        true,
        (0..count).flat_map(|n| [1.0, 2.0, n as f64]),
    );
    let mut bytes = format!(
        "{}ElementDataFile = LOCAL\n",
        metaimage_header(ScalarType::F64, true, false, 3)
    )
    .into_bytes();
    bytes.extend(raw);
    let path = dir.path().join("flow.mha");
    std::fs::write(&path, bytes).unwrap();
    let AnyVolume::Vector(volume) = load(&path).unwrap().volume else {
        panic!("expected a vector volume")
    };
    check_grid(volume.grid(), "metaimage vector");
    assert_eq!(volume.voxel(2, 3, 4), Some([-1.0, -2.0, 59.0]));
}

/// A single-file NIfTI-1 with an sform for the common grid.
fn nifti_file(scalar_type: ScalarType, big: bool, vector: bool, data: &[u8]) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put = |h: &mut Vec<u8>, at: usize, bytes: &[u8]| {
        let mut bytes = bytes.to_vec();
        if big {
            bytes.reverse();
        }
        h[at..at + bytes.len()].copy_from_slice(&bytes);
    };
    put(&mut h, 0, &348i32.to_le_bytes());
    let dim: [u16; 8] = if vector {
        [
            5,
            DIMS[0] as u16,
            DIMS[1] as u16,
            DIMS[2] as u16,
            1,
            3,
            1,
            1,
        ]
    } else {
        [
            3,
            DIMS[0] as u16,
            DIMS[1] as u16,
            DIMS[2] as u16,
            1,
            1,
            1,
            1,
        ]
    };
    for (i, d) in dim.iter().enumerate() {
        put(&mut h, 40 + 2 * i, &d.to_le_bytes());
    }
    if vector {
        put(&mut h, 68, &1007i16.to_le_bytes());
    }
    put(&mut h, 70, &nifti_datatype(scalar_type).to_le_bytes());
    put(
        &mut h,
        72,
        &(8 * scalar_type.size_bytes() as i16).to_le_bytes(),
    );
    for (i, p) in [
        1.0f32,
        SPACING_MM[0] as f32,
        SPACING_MM[1] as f32,
        SPACING_MM[2] as f32,
    ]
    .iter()
    .enumerate()
    {
        put(&mut h, 76 + 4 * i, &p.to_le_bytes());
    }
    put(&mut h, 108, &352f32.to_le_bytes());
    h[123] = 2; // millimetres
    put(&mut h, 254, &2i16.to_le_bytes()); // sform_code: aligned
    for row in 0..3 {
        let mut values = [0.0f32; 4];
        values[row] = SPACING_MM[row] as f32;
        values[3] = ORIGIN_MM[row] as f32;
        for (c, v) in values.iter().enumerate() {
            put(&mut h, 280 + 16 * row + 4 * c, &v.to_le_bytes());
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend_from_slice(data);
    h
}

#[test]
fn nifti_every_type_endian_plain_and_gzipped() {
    let dir = tempfile::tempdir().unwrap();
    for scalar_type in ScalarType::ALL {
        for big in [false, true] {
            let file = nifti_file(scalar_type, big, false, &scalar_bytes(scalar_type, big));
            let stem = format!("{scalar_type}_{big}");
            let plain = dir.path().join(format!("{stem}.nii"));
            std::fs::write(&plain, &file).unwrap();
            check_scalar(&load(&plain).unwrap(), scalar_type, &stem);
            let gz = dir.path().join(format!("{stem}.nii.gz"));
            std::fs::write(&gz, gzip(&file)).unwrap();
            check_scalar(&load(&gz).unwrap(), scalar_type, &format!("{stem}.gz"));
        }
    }
}

#[test]
fn nifti_vector_intent_reads_planar_components() {
    let dir = tempfile::tempdir().unwrap();
    let count = voxel_count();
    // One whole volume per component: x components, then y, then z.
    let planes = (0..3).flat_map(|c| (0..count).map(move |n| (c * 100 + n) as f64));
    let file = nifti_file(
        ScalarType::F32,
        false,
        true,
        &encode(ScalarType::F32, false, planes),
    );
    let path = dir.path().join("flow.nii");
    std::fs::write(&path, file).unwrap();
    let AnyVolume::Vector(volume) = load(&path).unwrap().volume else {
        panic!("expected a vector volume")
    };
    check_grid(volume.grid(), "nifti vector");
    assert_eq!(volume.data()[7], [7.0, 107.0, 207.0]);
}

fn raw_header(scalar_type: ScalarType, big: bool, compression: &str, data_file: &str) -> String {
    format!(
        "data_file = \"{data_file}\"\ndims = [{}, {}, {}]\nscalar_type = \"{scalar_type}\"\n\
         endianness = \"{}\"\nspacing = {SPACING_MM:?}\norigin = {ORIGIN_MM:?}\nunits = \"mm\"\n\
         compression = \"{compression}\"\n",
        DIMS[0],
        DIMS[1],
        DIMS[2],
        if big { "big" } else { "little" },
    )
}

#[test]
fn raw_toml_every_type_endian_compression() {
    let dir = tempfile::tempdir().unwrap();
    for scalar_type in ScalarType::ALL {
        for big in [false, true] {
            for compression in ["none", "gzip", "zlib"] {
                let raw = scalar_bytes(scalar_type, big);
                let payload = match compression {
                    "gzip" => gzip(&raw),
                    "zlib" => zlib(&raw),
                    _ => raw,
                };
                let stem = format!("{scalar_type}_{big}_{compression}");
                std::fs::write(dir.path().join(format!("{stem}.raw")), &payload).unwrap();
                let header = dir.path().join(format!("{stem}.toml"));
                let text = raw_header(scalar_type, big, compression, &format!("{stem}.raw"));
                std::fs::write(&header, text).unwrap();
                check_scalar(&load(&header).unwrap(), scalar_type, &stem);
            }
        }
    }
}

#[test]
fn broken_files_give_errors_naming_the_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "short.nrrd",
            {
                let mut b =
                    format!("{}\n", nrrd_header(ScalarType::U16, false, "raw", false)).into_bytes();
                b.extend_from_slice(&[0; 10]);
                b
            },
            "truncated",
        ),
        (
            "missing.nhdr",
            format!(
                "{}data file: nowhere.raw\n",
                nrrd_header(ScalarType::U8, false, "raw", false)
            )
            .into_bytes(),
            "nowhere.raw",
        ),
        ("garbage.nii", vec![7; 500], "NIfTI"),
        ("garbage.mha", b"hello\n".to_vec(), "Key = Value"),
        ("bad.toml", b"dims = [1, 2]\n".to_vec(), "bad header"),
        ("unknown.xyz", vec![], "extension"),
    ];
    for (name, bytes, expected) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let message = load(&path).unwrap_err().to_string();
        assert!(message.contains(name), "{message}");
        assert!(message.contains(expected), "{name}: {message}");
    }
    let message = load(&dir.path().join("absent.nii"))
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("absent.nii") && message.contains("cannot read"),
        "{message}"
    );
}

// ---------------------------------------------------------------------------------------------
// `voxhap info`

fn info(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .arg("info")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn info_json_on_real_files() {
    for (name, format, expected_max, origin_x_m) in [
        ("mni152_t1_1mm.nii.gz", "nifti", 255.0, -0.098),
        ("mni152_wm_1mm.nrrd", "nrrd", 255.0, -0.098),
        ("nibabel_anatomical.nii", "nifti", 30393.0, 0.032),
    ] {
        let Some(path) = shared_data(name) else {
            return;
        };
        let output = info(&[path.to_str().unwrap(), "--json"]);
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!(json["format"], format);
        assert_eq!(json["kind"], "scalar");
        assert_eq!(json["max"], expected_max);
        assert_eq!(json["path"], path.to_str().unwrap());
        let affine = json["affine"].as_array().unwrap();
        assert_eq!(affine.len(), 4);
        assert!((affine[0][3].as_f64().unwrap() - origin_x_m).abs() < 1e-12);
        assert_eq!(affine[3], serde_json::json!([0.0, 0.0, 0.0, 1.0]));
        let spacing = json["spacing"].as_array().unwrap();
        assert!(spacing.iter().all(|s| s.as_f64().unwrap() > 0.0));
    }
    if let Some(path) = shared_data("nibabel_anatomical.nii") {
        let output = info(&[path.to_str().unwrap()]);
        let text = String::from_utf8(output.stdout).unwrap();
        assert!(text.contains("33 x 41 x 25"), "{text}");
        assert!(text.contains("type:     i16"), "{text}");
    }
}

#[test]
fn info_on_builtins_and_errors() {
    let output = info(&["builtin:rankine", "--json"]);
    assert!(output.status.success());
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(json["kind"], "vector");
    assert_eq!(json["type"], "f32");
    let output = info(&["builtin:density-flow", "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let kinds: Vec<&str> = json
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["scalar", "vector"]);
    let output = info(&["/nonexistent/brain.nrrd"]);
    assert!(!output.status.success());
    let stderr = String::from_utf8(output.stderr).unwrap();
    assert!(
        stderr.contains("brain.nrrd") && stderr.contains("error"),
        "{stderr}"
    );
}

/// Runs `voxhap info` with its address space limited to `limit_bytes` (`RLIMIT_AS`), so any allocation
/// beyond it fails (and a Rust program aborts on it) instead of succeeding quietly.
fn info_with_memory_limit(args: &[&str], limit_bytes: u64) -> std::process::Output {
    use std::os::unix::process::CommandExt;
    let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command.arg("info").args(args);
    // SAFETY: only setrlimit, async-signal-safe, between fork and exec.
    unsafe {
        command.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: limit_bytes as libc::rlim_t,
                rlim_max: limit_bytes as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.output().unwrap()
}

/// A crafted gzip NRRD whose byte skip (1.27 GB) is zeros that compress to about 1.2 MB (19 gzip
/// members of 64 MiB each, which NRRD's gzip encoding allows): the loader skips the inflated bytes in
/// bounded chunks without keeping them, so `voxhap info` inside a 768 MiB address space ends with the
/// truncation error (no data after the skip), never an allocation failure. Checked to fail with a
/// loader that inflates the skip into memory: it aborted ("memory allocation of 2147483648 bytes
/// failed"). The same holds for a detached raw file with a byte skip past its end (sought, not read).
#[test]
fn a_huge_byte_skip_allocates_nothing_like_it() {
    let dir = tempfile::tempdir().unwrap();
    let member = gzip(&vec![0u8; 64 << 20]);
    let members = 19usize;
    let skip = members as u64 * (64 << 20);
    let path = dir.path().join("bomb.nrrd");
    let mut file = std::fs::File::create(&path).unwrap();
    write!(
        file,
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: {skip}\n\n"
    )
    .unwrap();
    for _ in 0..members {
        file.write_all(&member).unwrap();
    }
    drop(file);
    assert!(std::fs::metadata(&path).unwrap().len() < 4 << 20);
    let output = info_with_memory_limit(&[path.to_str().unwrap()], 768 << 20);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains(&format!(
            "data is truncated: the header describes {} bytes but only {skip} are there",
            skip + 8
        )),
        "{stderr}"
    );

    // Detached raw data with a byte skip far past the end of a tiny file.
    std::fs::write(dir.path().join("tiny.raw"), [0u8; 8]).unwrap();
    let header = dir.path().join("far.nhdr");
    std::fs::write(
        &header,
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nbyte skip: 3000000000\n\
         data file: tiny.raw\n",
    )
    .unwrap();
    let output = info_with_memory_limit(&[header.to_str().unwrap()], 768 << 20);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("the header describes 3000000008 bytes but only 8 are there"),
        "{stderr}"
    );
}
