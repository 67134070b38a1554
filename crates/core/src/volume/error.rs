//! Why a volume could not be built or loaded.

use glam::DVec3;

/// Names accepted by [`super::procedural::builtin`].
pub const BUILTIN_NAMES: [&str; 6] = [
    "sphere",
    "torus",
    "shells",
    "rankine",
    "burgers",
    "density-flow",
];

/// Errors building a volume in memory (bad grid, data of the wrong length, non-finite values,
/// unknown built-in name).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VolumeError {
    #[error("grid dimensions {dims:?} are invalid: every dimension must be at least 1 (2 for a procedural cube)")]
    ZeroDimension { dims: [usize; 3] },
    #[error("grid dimensions {dims:?} give more voxels than this machine can address")]
    TooManyVoxels { dims: [usize; 3] },
    #[error("grid spacing {spacing_m} m is invalid: it must be finite and positive on every axis")]
    BadSpacing { spacing_m: DVec3 },
    #[error("grid origin {origin_m} m is not finite")]
    BadOrigin { origin_m: DVec3 },
    #[error("grid direction matrix is invalid: {reason}")]
    BadDirection { reason: &'static str },
    #[error("volume data has {actual} elements but the grid has {expected} voxels")]
    DataLength { expected: usize, actual: usize },
    #[error("volume data has a non-finite value at element {index}")]
    NonFiniteValue { index: usize },
    #[error("parameter {name} = {value} is invalid: {reason}")]
    BadParameter {
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("unknown built-in volume {name:?}; known: {}", BUILTIN_NAMES.join(", "))]
    UnknownBuiltin { name: String },
}
