//! What a loader returns ([`LoadedVolume`], [`FileFormat`]) and the steps every loader shares:
//! checking sizes against [`MAX_VOXELS`], turning decoded values into a volume ([`assemble`]) and
//! reading length units ([`metres_per_unit`]).

use crate::decode::{Decoded, ScalarType};
use crate::error::{LoadProblem, MAX_VOXELS};
use std::path::{Path, PathBuf};
use voxhap_core::volume::{AnyVolume, VolumeError};

/// A file format the loaders read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileFormat {
    /// NIfTI-1, `.nii` or `.nii.gz`.
    Nifti,
    /// NRRD, `.nrrd` (attached data) or `.nhdr` (detached).
    Nrrd,
    /// MetaImage, `.mha` (inline data) or `.mhd` (detached).
    MetaImage,
    /// Raw data described by a TOML header, `.toml`.
    RawToml,
}

impl FileFormat {
    /// A short lowercase name: `nifti`, `nrrd`, `metaimage`, `raw`.
    pub fn name(self) -> &'static str {
        match self {
            FileFormat::Nifti => "nifti",
            FileFormat::Nrrd => "nrrd",
            FileFormat::MetaImage => "metaimage",
            FileFormat::RawToml => "raw",
        }
    }

    /// The format a file name's extension selects (case-insensitive), if any.
    pub fn from_path(path: &Path) -> Option<FileFormat> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            Some(FileFormat::Nifti)
        } else if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            Some(FileFormat::Nrrd)
        } else if name.ends_with(".mha") || name.ends_with(".mhd") {
            Some(FileFormat::MetaImage)
        } else if name.ends_with(".toml") {
            Some(FileFormat::RawToml)
        } else {
            None
        }
    }
}

/// A volume read from a file, with what the loader learned on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedVolume {
    /// The volume, in RAS metres.
    pub volume: AnyVolume,
    /// The element type stored in the file.
    pub source_type: ScalarType,
    /// The format it was read as.
    pub format: FileFormat,
    /// The file given to [`load`].
    pub path: PathBuf,
    /// How many stored values were NaN or infinite and replaced by 0.
    pub non_finite_replaced: usize,
    /// How many stored values could not be represented exactly in `f32` and were rounded.
    pub rounded_values: usize,
}

/// Checks a voxel count against [`MAX_VOXELS`] and returns it as `usize`.
pub(crate) fn checked_voxel_count(dims: [u64; 3], components: u64) -> Result<usize, LoadProblem> {
    let voxels = u128::from(dims[0]) * u128::from(dims[1]) * u128::from(dims[2]);
    if voxels == 0 {
        return Err(LoadProblem::header(format!(
            "dimensions {dims:?} contain a zero"
        )));
    }
    if voxels * u128::from(components) > MAX_VOXELS as u128 {
        return Err(LoadProblem::TooLarge { voxels });
    }
    Ok(voxels as usize)
}

/// Bytes of `count` elements of `scalar_type`, checked.
pub(crate) fn data_bytes(count: usize, scalar_type: ScalarType) -> Result<u64, LoadProblem> {
    (count as u64)
        .checked_mul(scalar_type.size_bytes() as u64)
        .ok_or(LoadProblem::TooLarge {
            voxels: count as u128,
        })
}

/// How decoded values become a volume.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layout {
    pub source_type: ScalarType,
    pub format: FileFormat,
    /// 1 (scalar) or 3 (vector).
    pub components: usize,
    /// Vector data stored as one whole volume per component (NIfTI) rather than interleaved,
    /// component fastest (NRRD, MetaImage, raw).
    pub planar: bool,
    /// Multiplies each vector component (-1 for the axes an LPS -> RAS conversion flips).
    pub component_signs: [f32; 3],
}

impl Layout {
    /// Interleaved data (component fastest), as NRRD, MetaImage and raw files store it.
    pub(crate) fn interleaved(
        source_type: ScalarType,
        format: FileFormat,
        components: usize,
        component_signs: [f32; 3],
    ) -> Layout {
        Layout {
            source_type,
            format,
            components,
            planar: false,
            component_signs,
        }
    }
}

/// Builds the volume from decoded values.
pub(crate) fn assemble(
    grid: voxhap_core::volume::Grid,
    decoded: Decoded,
    layout: &Layout,
    path: &Path,
) -> Result<LoadedVolume, LoadProblem> {
    let Decoded {
        values,
        non_finite_replaced,
        rounded_values,
    } = decoded;
    let Layout {
        source_type,
        format,
        components,
        planar,
        component_signs,
    } = *layout;
    let volume = if components == 1 {
        AnyVolume::Scalar(voxhap_core::volume::ScalarVolume::new(grid, values)?)
    } else {
        let voxels = grid.voxel_count();
        if values.len() != voxels * 3 {
            return Err(VolumeError::DataLength {
                expected: voxels * 3,
                actual: values.len(),
            }
            .into());
        }
        let vectors = (0..voxels)
            .map(|v| {
                let component = |c: usize| {
                    let index = if planar { c * voxels + v } else { 3 * v + c };
                    values[index] * component_signs[c]
                };
                [component(0), component(1), component(2)]
            })
            .collect();
        AnyVolume::Vector(voxhap_core::volume::VectorVolume::new(grid, vectors)?)
    };
    Ok(LoadedVolume {
        volume,
        source_type,
        format,
        path: path.to_path_buf(),
        non_finite_replaced,
        rounded_values,
    })
}

/// Metres per unit for a length-unit name (`mm`, `m`, `cm`, `um`/`µm`/`micron`), case-insensitive.
pub(crate) fn metres_per_unit(name: &str) -> Option<f64> {
    match name.trim().to_ascii_lowercase().as_str() {
        "m" | "meter" | "meters" | "metre" | "metres" => Some(1.0),
        "cm" => Some(1e-2),
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => Some(1e-3),
        "um" | "µm" | "micron" | "microns" | "micrometer" | "micrometre" => Some(1e-6),
        _ => None,
    }
}
