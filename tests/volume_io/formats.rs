//! Every format, encoding, byte order and type, written here into a temp dir and loaded back, and broken files
//! giving errors that name the file and the problem.

use crate::util::volume_files::{
    check_grid, check_scalar, encode, gzip, metaimage_type, nifti_datatype, nrrd_header,
    scalar_bytes, value, voxel_count, zlib, DIMS, ORIGIN_MM, SPACING_MM,
};
use voxhap::volume::io::{load, ScalarType};
use voxhap::volume::AnyVolume;

// ---------------------------------------------------------------------------------------------
// Written files: every format, encoding, byte order and type

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
