//! NIfTI-1 loader (`.nii`, `.nii.gz`): header parsing by the `nifti` crate, then our own checks,
//! orientation and data decoding.
//!
//! What is read: `dim` (3-D; a 2-D image loads with one slice; 4-D and higher only when the extra
//! dimensions are 1, except a vector volume), `datatype` (every integer and float type), byte order
//! (detected from the header), `vox_offset`, `scl_slope`/`scl_inter`, `xyzt_units` (space part),
//! `intent_code` (1007 = vector: `dim[5] = 3`, one whole volume per component) and the orientation:
//!
//! - `sform_code > 0`: the affine rows `srow_x`, `srow_y`, `srow_z`;
//! - else `qform_code > 0`: the quaternion `(b, c, d)`, `a = sqrt(1 - b² - c² - d²)`, rotation
//!   `R(a, b, c, d)`, `qfac = pixdim[0]` (−1 flips the k axis), affine
//!   `R · diag(pixdim[1], pixdim[2], qfac · pixdim[3])` plus `(quatern_x, quatern_y, quatern_z)`;
//! - else: `diag(pixdim[1..4])` with voxel 0 at the origin.
//!
//! NIfTI world space is RAS+ already. The affine is scaled from the file's units to metres.
//! Not supported (clear errors): NIfTI-2, `.hdr`/`.img` pairs, complex and RGB types, 4-D series.

use crate::decode::{decode_samples, inflate_skip, Endian, ScalarType};
use crate::error::LoadProblem;
use crate::loaded::{assemble, checked_voxel_count, FileFormat, Layout, LoadedVolume};
use crate::source::{check_budget, read_volume_file, LoadOptions};
use glam::{DMat3, DMat4, DVec3};
use nifti::{NiftiHeader, NiftiType};
use std::path::Path;
use voxhap_core::volume::Grid;

/// Size of a NIfTI-1 header.
const HEADER_BYTES: usize = 348;
/// NIfTI intent code of a vector field.
const INTENT_VECTOR: i16 = 1007;

/// Loads a `.nii` or `.nii.gz` file with the default limits.
pub fn load(path: &Path) -> Result<LoadedVolume, LoadProblem> {
    load_with(path, &LoadOptions::default())
}

/// Loads a `.nii` or `.nii.gz` file within `options`' limits.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<LoadedVolume, LoadProblem> {
    let bytes = read_volume_file(path, options)?;
    let gzipped = path
        .file_name()
        .is_some_and(|name| name.to_string_lossy().to_ascii_lowercase().ends_with(".gz"));
    parse_with(&bytes, gzipped, path, options)
}

/// Parses an in-memory NIfTI-1 file (gzipped or not) with the default limits. `path` only labels the
/// result.
pub fn parse(bytes: &[u8], gzipped: bool, path: &Path) -> Result<LoadedVolume, LoadProblem> {
    parse_with(bytes, gzipped, path, &LoadOptions::default())
}

/// [`parse`] within `options`' limits: the header's sizes are checked against `--max-volume-bytes`
/// before anything is inflated, and inflating stops one byte past what the header describes.
pub fn parse_with(
    bytes: &[u8],
    gzipped: bool,
    path: &Path,
    options: &LoadOptions,
) -> Result<LoadedVolume, LoadProblem> {
    // Inflate just the header first: its dimensions bound how much inflating the rest may produce.
    let header_bytes = if gzipped {
        inflate_prefix(bytes, HEADER_BYTES)?
    } else {
        bytes
            .get(..HEADER_BYTES.min(bytes.len()))
            .unwrap_or_default()
            .to_vec()
    };
    if header_bytes.len() < HEADER_BYTES {
        return Err(LoadProblem::Truncated {
            expected_bytes: HEADER_BYTES as u64,
            actual_bytes: header_bytes.len() as u64,
        });
    }
    let header = parse_header(&header_bytes)?;
    let plan = plan(&header)?;
    let total_bytes = plan
        .data_offset
        .checked_add(plan.data_bytes)
        .ok_or_else(|| LoadProblem::header("vox_offset is too large"))?;
    check_budget(total_bytes, (plan.voxels * plan.components) as u64, options)?;
    let inflated;
    let data: &[u8] = if gzipped {
        // vox_offset bytes of the inflated stream are skipped without being kept.
        inflated = inflate_skip(bytes, plan.data_offset, plan.data_bytes)?;
        &inflated
    } else {
        usize::try_from(plan.data_offset)
            .ok()
            .and_then(|offset| bytes.get(offset..))
            .ok_or(LoadProblem::Truncated {
                expected_bytes: total_bytes,
                actual_bytes: bytes.len() as u64,
            })?
    };
    let decoded = decode_samples(
        data,
        plan.scalar_type,
        plan.endian,
        plan.voxels * plan.components,
        plan.scale,
    )?;
    let layout = Layout {
        source_type: plan.scalar_type,
        format: FileFormat::Nifti,
        components: plan.components,
        planar: true,
        component_signs: [1.0; 3],
    };
    assemble(plan.grid, decoded, &layout, path)
}

/// Inflates the first `count` bytes of a gzip stream (fewer if the stream is shorter).
fn inflate_prefix(gz: &[u8], count: usize) -> Result<Vec<u8>, LoadProblem> {
    use std::io::Read;
    let mut out = Vec::with_capacity(count);
    flate2::read::MultiGzDecoder::new(gz)
        .take(count as u64)
        .read_to_end(&mut out)
        .map_err(LoadProblem::Decompress)?;
    Ok(out)
}

/// Parses and sanity-checks the 348-byte header.
pub fn parse_header(header_bytes: &[u8]) -> Result<NiftiHeader, LoadProblem> {
    let sizeof_hdr = header_bytes
        .get(..4)
        .map(|b| [b[0], b[1], b[2], b[3]])
        .unwrap_or_default();
    if [
        i32::from_le_bytes(sizeof_hdr),
        i32::from_be_bytes(sizeof_hdr),
    ]
    .contains(&540)
    {
        return Err(LoadProblem::unsupported("NIfTI-2 files"));
    }
    let header = NiftiHeader::from_reader(header_bytes)
        .map_err(|err| LoadProblem::header(format!("not a NIfTI-1 header ({err})")))?;
    if header.sizeof_hdr != HEADER_BYTES as i32 {
        return Err(LoadProblem::header(format!(
            "sizeof_hdr is {}, expected 348",
            header.sizeof_hdr
        )));
    }
    if &header.magic == b"ni1\0" {
        return Err(LoadProblem::unsupported(
            "separate .hdr/.img NIfTI pairs (magic ni1); convert to a single .nii",
        ));
    }
    Ok(header)
}

/// Everything needed to decode the data, checked against the header.
struct Plan {
    grid: Grid,
    scalar_type: ScalarType,
    endian: Endian,
    voxels: usize,
    components: usize,
    data_offset: u64,
    data_bytes: u64,
    scale: Option<(f64, f64)>,
}

fn plan(header: &NiftiHeader) -> Result<Plan, LoadProblem> {
    let rank = usize::from(header.dim[0]);
    if !(1..=7).contains(&rank) {
        return Err(LoadProblem::header(format!(
            "dim[0] = {rank} is not in 1..=7"
        )));
    }
    let dim = |axis: usize| if axis <= rank { header.dim[axis] } else { 1 };
    let vector = header.intent_code == INTENT_VECTOR;
    let components = if vector {
        if dim(4) != 1 || dim(5) != 3 || (6..=7).any(|a| dim(a) != 1) {
            return Err(LoadProblem::unsupported(format!(
                "vector intent with dim[4..8] = {:?}: only dim[4] = 1, dim[5] = 3 is read",
                &header.dim[4..]
            )));
        }
        3
    } else {
        if (4..=7).any(|a| dim(a) != 1) {
            return Err(LoadProblem::unsupported(format!(
                "{rank}-D data with dim = {:?}: only 3-D volumes (or vector intent 1007) are read",
                &header.dim[1..=rank]
            )));
        }
        1
    };
    let dims = [dim(1), dim(2), dim(3)].map(u64::from);
    let voxels = checked_voxel_count(dims, components as u64)?;
    let scalar_type = scalar_type(header)?;
    let endian = match header.endianness {
        nifti::Endianness::Little => Endian::Little,
        nifti::Endianness::Big => Endian::Big,
    };
    let vox_offset = header.vox_offset;
    if !vox_offset.is_finite() || vox_offset < HEADER_BYTES as f32 || vox_offset.fract() != 0.0 {
        return Err(LoadProblem::header(format!(
            "vox_offset {vox_offset} must be a whole number >= 348"
        )));
    }
    // A whole number >= 348 below 2^64 (f32 holds at most 2^128; larger values fail the conversion).
    let data_offset = vox_offset as u64;
    let data_bytes = crate::loaded::data_bytes(voxels * components, scalar_type)?;
    let slope = f64::from(header.scl_slope);
    let intercept = f64::from(header.scl_inter);
    let scale = (slope.is_finite() && slope != 0.0 && !(slope == 1.0 && intercept == 0.0))
        .then_some((
            slope,
            if intercept.is_finite() {
                intercept
            } else {
                0.0
            },
        ));
    let metres = metres_per_unit(header)?;
    let affine = affine_in_file_units(header)?;
    let affine_m = DMat4::from_cols(
        affine.x_axis * metres,
        affine.y_axis * metres,
        affine.z_axis * metres,
        (affine.w_axis.truncate() * metres).extend(1.0),
    );
    let usize_dims = dims.map(|d| d as usize);
    let grid = Grid::from_affine(usize_dims, affine_m)?;
    Ok(Plan {
        grid,
        scalar_type,
        endian,
        voxels,
        components,
        data_offset,
        data_bytes,
        scale,
    })
}

fn scalar_type(header: &NiftiHeader) -> Result<ScalarType, LoadProblem> {
    let nifti_type = header
        .data_type()
        .map_err(|_| LoadProblem::header(format!("unknown datatype code {}", header.datatype)))?;
    Ok(match nifti_type {
        NiftiType::Uint8 => ScalarType::U8,
        NiftiType::Int8 => ScalarType::I8,
        NiftiType::Uint16 => ScalarType::U16,
        NiftiType::Int16 => ScalarType::I16,
        NiftiType::Uint32 => ScalarType::U32,
        NiftiType::Int32 => ScalarType::I32,
        NiftiType::Uint64 => ScalarType::U64,
        NiftiType::Int64 => ScalarType::I64,
        NiftiType::Float32 => ScalarType::F32,
        NiftiType::Float64 => ScalarType::F64,
        other => {
            return Err(LoadProblem::unsupported(format!(
                "NIfTI datatype {other:?} (code {})",
                header.datatype
            )))
        }
    })
}

fn metres_per_unit(header: &NiftiHeader) -> Result<f64, LoadProblem> {
    match header.xyzt_units & 0o7 {
        0 | 2 => Ok(1e-3), // unknown: millimetres, as every neuroimaging tool assumes
        1 => Ok(1.0),
        3 => Ok(1e-6),
        code => Err(LoadProblem::header(format!(
            "unknown spatial unit code {code}"
        ))),
    }
}

/// The index-to-world affine in the file's length unit (see the module header for the rules).
pub fn affine_in_file_units(header: &NiftiHeader) -> Result<DMat4, LoadProblem> {
    let f = |v: f32| f64::from(v);
    if header.sform_code > 0 {
        let rows = [header.srow_x, header.srow_y, header.srow_z];
        let column = |c: usize| DVec3::new(f(rows[0][c]), f(rows[1][c]), f(rows[2][c]));
        return Ok(DMat4::from_cols(
            column(0).extend(0.0),
            column(1).extend(0.0),
            column(2).extend(0.0),
            column(3).extend(1.0),
        ));
    }
    let pixdim = |axis: usize| f(header.pixdim[axis]).abs();
    let spacing = DVec3::new(pixdim(1), pixdim(2), pixdim(3));
    if !spacing.is_finite() || spacing.min_element() <= 0.0 {
        return Err(LoadProblem::header(format!(
            "pixdim[1..4] = {:?} must be finite and non-zero",
            &header.pixdim[1..4]
        )));
    }
    if header.qform_code > 0 {
        let (mut b, mut c, mut d) = (
            f(header.quatern_b),
            f(header.quatern_c),
            f(header.quatern_d),
        );
        if !(b.is_finite() && c.is_finite() && d.is_finite()) {
            return Err(LoadProblem::header("qform quaternion is not finite"));
        }
        let mut a = 1.0 - (b * b + c * c + d * d);
        if a < 1e-7 {
            // Numerically a 180-degree rotation: renormalise (b, c, d), as nifti1_io does.
            let norm = (b * b + c * c + d * d).sqrt();
            if norm == 0.0 {
                return Err(LoadProblem::header("qform quaternion is degenerate"));
            }
            (b, c, d) = (b / norm, c / norm, d / norm);
            a = 0.0;
        } else {
            a = a.sqrt();
        }
        let rotation = DMat3::from_cols(
            DVec3::new(
                a * a + b * b - c * c - d * d,
                2.0 * (b * c + a * d),
                2.0 * (b * d - a * c),
            ),
            DVec3::new(
                2.0 * (b * c - a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d + a * b),
            ),
            DVec3::new(
                2.0 * (b * d + a * c),
                2.0 * (c * d - a * b),
                a * a + d * d - c * c - b * b,
            ),
        );
        let qfac = if header.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let linear = rotation * DMat3::from_diagonal(spacing * DVec3::new(1.0, 1.0, qfac));
        let offset = DVec3::new(
            f(header.quatern_x),
            f(header.quatern_y),
            f(header.quatern_z),
        );
        return Ok(DMat4::from_cols(
            linear.x_axis.extend(0.0),
            linear.y_axis.extend(0.0),
            linear.z_axis.extend(0.0),
            offset.extend(1.0),
        ));
    }
    Ok(DMat4::from_scale(spacing))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A minimal valid `.nii`: 2x2x2 int16 little-endian, sform with 2 mm voxels.
    fn tiny_nii() -> Vec<u8> {
        let mut h = vec![0u8; 352];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        for (i, d) in [3u16, 2, 2, 2, 1, 1, 1, 1].iter().enumerate() {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        }
        h[70..72].copy_from_slice(&4i16.to_le_bytes());
        h[72..74].copy_from_slice(&16i16.to_le_bytes());
        for (i, p) in [1.0f32, 2.0, 2.0, 2.0].iter().enumerate() {
            h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
        }
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        h[123] = 2;
        h[254..256].copy_from_slice(&1i16.to_le_bytes());
        for (row, values) in [
            [2.0f32, 0.0, 0.0, -1.0],
            [0.0, 2.0, 0.0, -2.0],
            [0.0, 0.0, 2.0, -3.0],
        ]
        .iter()
        .enumerate()
        {
            for (c, v) in values.iter().enumerate() {
                let at = 280 + 16 * row + 4 * c;
                h[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
        }
        h[344..348].copy_from_slice(b"n+1\0");
        for v in 0..8i16 {
            h.extend_from_slice(&(v * 10).to_le_bytes());
        }
        h
    }

    #[test]
    fn tiny_file_loads() {
        let loaded = parse(&tiny_nii(), false, Path::new("tiny.nii")).unwrap();
        let grid = loaded.volume.grid();
        assert_eq!(grid.dims(), [2, 2, 2]);
        assert_eq!(grid.spacing_m(), DVec3::splat(0.002));
        assert_eq!(grid.origin_m(), DVec3::new(-0.001, -0.002, -0.003));
        assert_eq!(loaded.volume.value_range(), (0.0, 70.0));
    }

    #[test]
    fn qform_quaternion_matches_a_known_rotation() {
        // b = 0, c = 0, d = sin(45°): 90° about z; qfac -1 flips k.
        let mut header = NiftiHeader {
            sform_code: 0,
            qform_code: 1,
            quatern_d: std::f32::consts::FRAC_1_SQRT_2,
            pixdim: [-1.0, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0],
            quatern_x: 5.0,
            ..NiftiHeader::default()
        };
        let affine = affine_in_file_units(&header).unwrap();
        let i = affine.transform_vector3(DVec3::X);
        let j = affine.transform_vector3(DVec3::Y);
        let k = affine.transform_vector3(DVec3::Z);
        assert!((i - DVec3::Y).length() < 1e-6, "{i}");
        assert!((j - DVec3::new(-2.0, 0.0, 0.0)).length() < 1e-6, "{j}");
        assert!((k - DVec3::new(0.0, 0.0, -3.0)).length() < 1e-6, "{k}");
        assert_eq!(affine.w_axis.x, 5.0);
        header.qform_code = 0;
        assert_eq!(
            affine_in_file_units(&header).unwrap(),
            DMat4::from_scale(DVec3::new(1.0, 2.0, 3.0))
        );
    }

    #[test]
    fn truncated_and_oversized_files_are_errors() {
        let nii = tiny_nii();
        let path = Path::new("t.nii");
        assert!(matches!(
            parse(&nii[..nii.len() - 1], false, path),
            Err(LoadProblem::Truncated { .. })
        ));
        assert!(matches!(
            parse(&nii[..100], false, path),
            Err(LoadProblem::Truncated { .. })
        ));
        let mut longer = nii.clone();
        longer.push(0);
        assert!(matches!(
            parse(&longer, false, path),
            Err(LoadProblem::TrailingData { .. })
        ));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..800)) {
            let _ = parse(&bytes, false, Path::new("x.nii"));
            let _ = parse(&bytes, true, Path::new("x.nii.gz"));
        }

        #[test]
        fn mutated_gzip_streams_never_panic(
            edits in proptest::collection::vec((0usize..64, any::<u8>()), 1..4),
        ) {
            use std::io::Write;
            let mut encoder =
                flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
            encoder.write_all(&tiny_nii()).unwrap();
            let mut gz = encoder.finish().unwrap();
            let len = gz.len();
            for (at, value) in edits {
                gz[at % len] = value;
            }
            let _ = parse(&gz, true, Path::new("x.nii.gz"));
        }

        #[test]
        fn mutated_headers_never_panic(
            edits in proptest::collection::vec((0usize..368, any::<u8>()), 1..8),
        ) {
            let bytes = crate::test_edits::with_bytes_edited(&tiny_nii(), edits);
            if let Ok(loaded) = parse(&bytes, false, Path::new("x.nii")) {
                let (min, max) = loaded.volume.value_range();
                prop_assert!(min.is_finite() && max.is_finite());
            }
        }
    }
}
