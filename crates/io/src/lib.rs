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
mod error;
mod header_lines;
mod loaded;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod raw;
pub mod scene;
pub mod scene_solve;
pub mod source;
#[cfg(test)]
mod test_edits;

pub use decode::{decode_samples, Decoded, Endian, ScalarType};
pub use error::{FileError, LoadError, LoadProblem, MAX_VOXELS};
pub use loaded::{FileFormat, LoadedVolume};
pub use source::{
    confined_path, open_regular, process_options, read_regular, read_text_file,
    set_process_options, LoadOptions, DEFAULT_MAX_VOLUME_BYTES, MAX_HEADER_BYTES,
    MAX_TEXT_FILE_BYTES,
};

use std::path::Path;

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
