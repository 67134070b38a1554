//! The errors of volume loading: [`LoadError`] (the file and what is wrong with it), its
//! [`LoadProblem`], and [`FileError`] for a file that cannot be opened as a plain file.
//!
//! Every loader returns a [`LoadProblem`]; [`crate::load`] attaches the path. Messages name the
//! value the file gave and what was wrong with it.

use std::path::{Path, PathBuf};
use voxhap_core::volume::VolumeError;

/// Largest voxel count a loader accepts (2^30 voxels, 4 GiB of `f32`).
pub const MAX_VOXELS: usize = 1 << 30;

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

/// Why a file cannot be opened as a plain file.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("it is a {kind}, not a regular file (only regular files are read)")]
    NotRegular { kind: &'static str },
    #[error("it is {size_bytes} bytes, more than the {limit_bytes}-byte limit for {what}")]
    TooLong {
        size_bytes: u64,
        limit_bytes: u64,
        what: &'static str,
    },
    #[error(
        "it resolves to {}, outside the folder {} (add --allow-outside-paths to allow this)",
        resolved.display(),
        folder.display()
    )]
    Outside { resolved: PathBuf, folder: PathBuf },
}
