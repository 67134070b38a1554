//! Volume file loaders: NIfTI-1, NRRD, MetaImage and raw data with a TOML header.
//!
//! Place in the data flow: [`load`] runs once, off the servo thread, when a scene is built; it picks
//! the loader by extension and returns a [`LoadedVolume`] whose [`AnyVolume`] the haptic modes sample.
//!
//! **World-space convention.** Every loaded volume is in the file's physical space, expressed as
//! RAS+ (x to the subject's Right, y Anterior, z Superior, as NIfTI defines it) and in **metres**:
//! - NIfTI: the sform if `sform_code > 0`, else the qform if `qform_code > 0`, else `pixdim` scaling
//!   with the origin at voxel 0 (NIfTI "method 1"). NIfTI space is already RAS. Units from
//!   `xyzt_units` (metre, millimetre, micron); unknown units are taken as millimetres.
//! - NRRD: `space directions` and `space origin` (or `spacings`, origin 0). `space` LPS (or LAS) is
//!   converted to RAS by negating x and y (x only for LAS); RAS, `scanner-xyz`, `3D-right-handed` and a
//!   bare `space dimension: 3` are used as they are. Units from `space units` (default millimetres).
//! - MetaImage: `Offset` (or `Position`/`Origin`), `ElementSpacing`, `TransformMatrix` (ITK's
//!   reading: the i-th group of three numbers is the direction of index axis i). MetaImage physical
//!   space is ITK's LPS, converted to RAS by negating x and y. Units: millimetres.
//! - Raw + TOML: as the header says (`units`, default millimetres), no flip.
//!
//! Vector components follow the same flips as positions (LPS -> RAS negates the x and y components)
//! and keep the file's own units.
//!
//! **Values.** Every type is read into `f32`. Integers above 2^24 in magnitude and `f64` values are
//! rounded to the nearest `f32` (the report counts values that changed). Non-finite values (NaN and
//! infinities, common as masks in float NIfTI) are replaced by 0 and counted in
//! [`LoadedVolume::non_finite_replaced`]: no NaN reaches a sampler. NIfTI `scl_slope`/`scl_inter` are
//! applied when the slope is finite and non-zero.
//!
//! **Errors.** Every failure is a [`LoadError`] naming the file and the problem; sizes are checked
//! against the header before any large allocation, and no loader panics on any input.
//!
//! **Limits** ([`source`]): only regular files are opened (a FIFO, device or socket is refused at once);
//! each load reads or inflates only the bytes its header describes (byte skips and header sizes included,
//! with checked arithmetic), and at most `--max-volume-bytes` ([`LoadOptions`], default 4 GiB) counting
//! the data and its `f32` copy; a data file named in a header must resolve inside the header's folder
//! unless `--allow-outside-paths`.

mod decode;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod raw;
pub mod scene;
pub mod source;

pub use decode::{decode_samples, Decoded, Endian, ScalarType};
pub use source::{
    confined_path, open_regular, process_options, read_regular, read_text_file,
    set_process_options, FileError, LoadOptions, DEFAULT_MAX_VOLUME_BYTES, MAX_HEADER_BYTES,
    MAX_TEXT_FILE_BYTES,
};

use std::path::{Path, PathBuf};
use voxhap_core::volume::{AnyVolume, VolumeError};

/// Largest voxel count a loader accepts (2^30 voxels, 4 GiB of `f32`).
pub const MAX_VOXELS: usize = 1 << 30;

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

/// A loader failure: the file and what is wrong with it.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct LoadError {
    pub path: PathBuf,
    pub problem: LoadProblem,
}

/// What went wrong reading a volume file.
#[derive(Debug, thiserror::Error)]
pub enum LoadProblem {
    #[error("cannot read the file: {0}")]
    Io(#[from] std::io::Error),
    #[error("cannot read the file: {0}")]
    File(FileError),
    #[error("cannot read the data file {}: {source}", path.display())]
    DataFile { path: PathBuf, source: FileError },
    #[error("loading this volume needs {needed_bytes} bytes (the data read or inflated plus 4 bytes per value), more than --max-volume-bytes {limit_bytes}")]
    OverLimit { needed_bytes: u64, limit_bytes: u64 },
    #[error("unknown extension: expected .nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd or .toml")]
    UnknownExtension,
    #[error("bad header: {0}")]
    Header(String),
    #[error("unsupported: {0}")]
    Unsupported(String),
    #[error("data is truncated: the header describes {expected_bytes} bytes but only {actual_bytes} are there")]
    Truncated {
        expected_bytes: u64,
        actual_bytes: u64,
    },
    #[error(
        "data is longer than the header describes ({expected_bytes} bytes expected, more found)"
    )]
    TrailingData { expected_bytes: u64 },
    #[error("compressed data is corrupt: {0}")]
    Decompress(std::io::Error),
    #[error("{voxels} voxels is more than the loader limit of {MAX_VOXELS}")]
    TooLarge { voxels: u128 },
    #[error("invalid volume: {0}")]
    Volume(#[from] VolumeError),
}

impl LoadProblem {
    /// Shorthand for a header problem.
    pub(crate) fn header(message: impl Into<String>) -> LoadProblem {
        LoadProblem::Header(message.into())
    }

    /// Shorthand for an unsupported feature.
    pub(crate) fn unsupported(message: impl Into<String>) -> LoadProblem {
        LoadProblem::Unsupported(message.into())
    }

    /// Attaches the file name.
    pub fn at(self, path: &Path) -> LoadError {
        LoadError {
            path: path.to_path_buf(),
            problem: self,
        }
    }
}

/// Loads a volume file, choosing the loader by extension (`.nii`, `.nii.gz`, `.nrrd`, `.nhdr`, `.mha`,
/// `.mhd`, `.toml`), with the process-wide limits ([`process_options`]).
pub fn load(path: &Path) -> Result<LoadedVolume, LoadError> {
    load_with(path, &process_options())
}

/// [`load`] with explicit limits.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<LoadedVolume, LoadError> {
    let format =
        FileFormat::from_path(path).ok_or_else(|| LoadProblem::UnknownExtension.at(path))?;
    let result = match format {
        FileFormat::Nifti => nifti::load_with(path, options),
        FileFormat::Nrrd => nrrd::load_with(path, options),
        FileFormat::MetaImage => metaimage::load_with(path, options),
        FileFormat::RawToml => raw::load_with(path, options),
    };
    result.map_err(|problem| problem.at(path))
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
