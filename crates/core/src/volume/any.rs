//! A volume of either kind, as files and the built-in generators produce them.

use super::grid::Grid;
use super::scalar::ScalarVolume;
use super::vector::VectorVolume;

/// A volume of either kind, as loaded from a file.
#[derive(Debug, Clone, PartialEq)]
pub enum AnyVolume {
    Scalar(ScalarVolume),
    Vector(VectorVolume),
}

impl AnyVolume {
    /// The volume's grid.
    pub fn grid(&self) -> &Grid {
        match self {
            AnyVolume::Scalar(volume) => volume.grid(),
            AnyVolume::Vector(volume) => volume.grid(),
        }
    }

    /// `"scalar"` or `"vector"`.
    pub fn kind(&self) -> &'static str {
        match self {
            AnyVolume::Scalar(_) => "scalar",
            AnyVolume::Vector(_) => "vector",
        }
    }

    /// Value range: the stored minimum and maximum for a scalar volume, the minimum and maximum
    /// vector magnitude for a vector volume.
    pub fn value_range(&self) -> (f32, f32) {
        match self {
            AnyVolume::Scalar(volume) => volume.value_range(),
            AnyVolume::Vector(volume) => volume.magnitude_range(),
        }
    }
}
