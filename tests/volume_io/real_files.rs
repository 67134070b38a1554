//! The real scans in the repository's data/ folder against numbers from independent readers (nibabel, pynrrd).

use crate::util::volume_files::{real_scan, scalar};
use glam::{DMat4, DVec3, DVec4};
use voxhap::volume::io::{load, FileFormat, ScalarType};

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
    let path = real_scan("mni152_t1_1mm.nii.gz");
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
    let path = real_scan("nibabel_anatomical.nii");
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
    let path = real_scan("mni152_wm_1mm.nrrd");
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
