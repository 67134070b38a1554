//! The regular grid under every volume: dimensions and the index-to-world affine.
//!
//! A voxel index `u = (i, j, k)` (continuous: `u = (1.5, 0, 2)` is half way between two voxel centres)
//! maps to world space by
//!
//! ```text
//! p_world = origin_m + D · diag(spacing_m) · u   =   origin_m + L · u
//! ```
//!
//! where column `a` of the direction matrix `D` is the world-space unit vector of index axis `a` and `L`
//! is the linear part of the affine. Voxel `(0, 0, 0)` sits at `origin_m`. World space is metres
//! (RAS for loaded files, see [`voxhap_io`]).
//!
//! Derivatives go the other way: for a field `f(u(p))` with `u = L⁻¹ (p - origin)`, the chain rule gives
//! `∇_world f = L⁻ᵀ ∇_index f`, so the grid keeps `L⁻¹` and `L⁻ᵀ` precomputed for the samplers.

use super::error::VolumeError;
use glam::{DMat3, DMat4, DVec3, DVec4};

/// Tolerance on the length of a direction cosine column (they must be unit vectors).
const DIRECTION_UNIT_TOLERANCE: f64 = 1e-4;
/// Smallest accepted `|det D|`: below this the index axes are (nearly) coplanar.
const MIN_DIRECTION_DETERMINANT: f64 = 1e-6;

/// A regular 3-D grid of voxel centres with its index-to-world affine.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    dims: [usize; 3],
    spacing_m: DVec3,
    direction: DMat3,
    origin_m: DVec3,
    /// `L = D · diag(spacing)`: index -> world, linear part.
    linear: DMat3,
    /// `L⁻¹`: world -> index, linear part.
    linear_inverse: DMat3,
    /// `L⁻ᵀ`: maps index-space gradients to world-space gradients.
    gradient_to_world: DMat3,
    /// `(nx - 1, ny - 1, nz - 1)` as floats, for the samplers' clamping.
    last_index: DVec3,
    /// Data-array strides of the index axes: `(1, nx, nx·ny)`.
    strides: [usize; 3],
}

impl Grid {
    /// Builds a grid. `direction` holds one unit column per index axis (direction cosines).
    ///
    /// Rejects zero dimensions, a voxel count that overflows `usize`, non-finite or non-positive
    /// spacing, a non-finite origin, direction columns that are not unit vectors, and a singular
    /// direction matrix.
    pub fn new(
        dims: [usize; 3],
        spacing_m: DVec3,
        direction: DMat3,
        origin_m: DVec3,
    ) -> Result<Grid, VolumeError> {
        if dims.contains(&0) {
            return Err(VolumeError::ZeroDimension { dims });
        }
        if dims[0]
            .checked_mul(dims[1])
            .and_then(|n| n.checked_mul(dims[2]))
            .is_none()
        {
            return Err(VolumeError::TooManyVoxels { dims });
        }
        if !spacing_m.is_finite() || spacing_m.min_element() <= 0.0 {
            return Err(VolumeError::BadSpacing { spacing_m });
        }
        if !origin_m.is_finite() {
            return Err(VolumeError::BadOrigin { origin_m });
        }
        if !direction.is_finite() {
            return Err(VolumeError::BadDirection {
                reason: "it has non-finite entries",
            });
        }
        for axis in 0..3 {
            if (direction.col(axis).length() - 1.0).abs() > DIRECTION_UNIT_TOLERANCE {
                return Err(VolumeError::BadDirection {
                    reason: "its columns must be unit vectors (direction cosines)",
                });
            }
        }
        if direction.determinant().abs() < MIN_DIRECTION_DETERMINANT {
            return Err(VolumeError::BadDirection {
                reason: "it is singular (index axes are coplanar)",
            });
        }
        let linear = direction * DMat3::from_diagonal(spacing_m);
        let linear_inverse = linear.inverse();
        if !linear_inverse.is_finite() {
            return Err(VolumeError::BadDirection {
                reason: "the index-to-world map cannot be inverted",
            });
        }
        Ok(Grid {
            dims,
            spacing_m,
            direction,
            origin_m,
            linear,
            linear_inverse,
            gradient_to_world: linear_inverse.transpose(),
            last_index: DVec3::new(
                (dims[0] - 1) as f64,
                (dims[1] - 1) as f64,
                (dims[2] - 1) as f64,
            ),
            strides: [1, dims[0], dims[0] * dims[1]],
        })
    }

    /// An axis-aligned grid (identity direction).
    pub fn axis_aligned(
        dims: [usize; 3],
        spacing_m: DVec3,
        origin_m: DVec3,
    ) -> Result<Grid, VolumeError> {
        Grid::new(dims, spacing_m, DMat3::IDENTITY, origin_m)
    }

    /// A cube grid of `dims` voxels whose voxel centres span `[-half_extent_m, half_extent_m]` on
    /// every axis, centred on the world origin. Used by the procedural volumes.
    pub fn centred_cube(dims: [usize; 3], half_extent_m: f64) -> Result<Grid, VolumeError> {
        if dims.iter().any(|&n| n < 2) {
            return Err(VolumeError::ZeroDimension { dims });
        }
        let spacing_m = DVec3::new(
            2.0 * half_extent_m / (dims[0] - 1) as f64,
            2.0 * half_extent_m / (dims[1] - 1) as f64,
            2.0 * half_extent_m / (dims[2] - 1) as f64,
        );
        Grid::axis_aligned(dims, spacing_m, DVec3::splat(-half_extent_m))
    }

    /// Builds a grid from a homogeneous index-to-world affine (metres). The spacing is the length of
    /// each column of the linear part and the direction is the normalised column.
    pub fn from_affine(dims: [usize; 3], affine: DMat4) -> Result<Grid, VolumeError> {
        let column = |a: usize| affine.col(a).truncate();
        let spacing_m = DVec3::new(column(0).length(), column(1).length(), column(2).length());
        if !spacing_m.is_finite() || spacing_m.min_element() <= 0.0 {
            return Err(VolumeError::BadSpacing { spacing_m });
        }
        let direction = DMat3::from_cols(
            column(0) / spacing_m.x,
            column(1) / spacing_m.y,
            column(2) / spacing_m.z,
        );
        Grid::new(dims, spacing_m, direction, affine.col(3).truncate())
    }

    /// Number of voxels along each index axis `(nx, ny, nz)`.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Total number of voxels `nx · ny · nz` (cannot overflow: checked in [`Grid::new`]).
    pub fn voxel_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// `field` at every voxel centre, in the volumes' layout (x fastest).
    pub(crate) fn sample_centres<T>(&self, field: impl Fn(DVec3) -> T) -> Vec<T> {
        let [nx, ny, nz] = self.dims();
        let mut data = Vec::with_capacity(self.voxel_count());
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    data.push(field(
                        self.index_to_world(DVec3::new(i as f64, j as f64, k as f64)),
                    ));
                }
            }
        }
        data
    }

    /// Whether `len` values, one per voxel, fill this grid: [`VolumeError::DataLength`] if not.
    pub(crate) fn check_data_length(&self, len: usize) -> Result<(), VolumeError> {
        let expected = self.voxel_count();
        if len != expected {
            return Err(VolumeError::DataLength {
                expected,
                actual: len,
            });
        }
        Ok(())
    }

    /// Distance between voxel centres along each index axis, metres.
    pub fn spacing_m(&self) -> DVec3 {
        self.spacing_m
    }

    /// Direction cosines: column `a` is the world unit vector of index axis `a`.
    pub fn direction(&self) -> DMat3 {
        self.direction
    }

    /// World position of voxel `(0, 0, 0)`, metres.
    pub fn origin_m(&self) -> DVec3 {
        self.origin_m
    }

    /// Linear part `L = D · diag(spacing)` of the index-to-world map.
    pub fn linear(&self) -> DMat3 {
        self.linear
    }

    /// `L⁻ᵀ`: multiplies an index-space gradient to give the world-space gradient.
    pub fn gradient_to_world(&self) -> DMat3 {
        self.gradient_to_world
    }

    /// `L⁻¹`: multiplies world-space displacement to give index-space displacement.
    pub fn linear_inverse(&self) -> DMat3 {
        self.linear_inverse
    }

    /// `(nx - 1, ny - 1, nz - 1)`: the largest index on each axis.
    #[inline]
    pub fn last_index(&self) -> DVec3 {
        self.last_index
    }

    /// Data-array strides of the index axes, `(1, nx, nx·ny)`.
    #[inline]
    pub fn strides(&self) -> [usize; 3] {
        self.strides
    }

    /// Continuous index -> world position (metres).
    #[inline]
    pub fn index_to_world(&self, index: DVec3) -> DVec3 {
        self.origin_m + self.linear * index
    }

    /// World position (metres) -> continuous index. Not clamped: outside the grid the result lies
    /// outside `[0, n-1]`.
    #[inline]
    pub fn world_to_index(&self, p_world: DVec3) -> DVec3 {
        self.linear_inverse * (p_world - self.origin_m)
    }

    /// The homogeneous index-to-world affine (metres), column-major as glam stores it.
    pub fn affine(&self) -> DMat4 {
        DMat4::from_cols(
            self.linear.col(0).extend(0.0),
            self.linear.col(1).extend(0.0),
            self.linear.col(2).extend(0.0),
            DVec4::new(self.origin_m.x, self.origin_m.y, self.origin_m.z, 1.0),
        )
    }

    /// The axis-aligned world box `(min, max)` that holds every voxel centre (the 8 corner voxels).
    pub fn bounds_world(&self) -> (DVec3, DVec3) {
        let last = self.last_index;
        let mut min = DVec3::splat(f64::INFINITY);
        let mut max = DVec3::splat(f64::NEG_INFINITY);
        for corner in 0..8 {
            let index = DVec3::new(
                if corner & 1 != 0 { last.x } else { 0.0 },
                if corner & 2 != 0 { last.y } else { 0.0 },
                if corner & 4 != 0 { last.z } else { 0.0 },
            );
            let p = self.index_to_world(index);
            min = min.min(p);
            max = max.max(p);
        }
        (min, max)
    }

    /// Linear offset of voxel `(i, j, k)` in the data array: `i + nx·(j + ny·k)` (x fastest).
    #[inline]
    pub fn offset(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.strides[1] * j + self.strides[2] * k
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rotated_anisotropic() -> Grid {
        let direction = DMat3::from_rotation_z(0.4) * DMat3::from_rotation_x(-1.1);
        Grid::new(
            [10, 20, 7],
            DVec3::new(0.001, 0.0025, 0.004),
            direction,
            DVec3::new(0.01, -0.02, 0.03),
        )
        .unwrap()
    }

    #[test]
    fn rejects_bad_grids() {
        let one = DVec3::ONE;
        let id = DMat3::IDENTITY;
        assert!(matches!(
            Grid::new([0, 1, 1], one, id, DVec3::ZERO),
            Err(VolumeError::ZeroDimension { .. })
        ));
        assert!(matches!(
            Grid::new([usize::MAX, 2, 2], one, id, DVec3::ZERO),
            Err(VolumeError::TooManyVoxels { .. })
        ));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Grid::new([2, 2, 2], DVec3::new(1.0, bad, 1.0), id, DVec3::ZERO),
                Err(VolumeError::BadSpacing { .. })
            ));
        }
        let singular = DMat3::from_cols(DVec3::X, DVec3::X, DVec3::Z);
        assert!(matches!(
            Grid::new([2, 2, 2], one, singular, DVec3::ZERO),
            Err(VolumeError::BadDirection { .. })
        ));
        assert!(matches!(
            Grid::new([2, 2, 2], one, id * 2.0, DVec3::ZERO),
            Err(VolumeError::BadDirection { .. })
        ));
        assert!(matches!(
            Grid::new([2, 2, 2], one, id, DVec3::new(f64::NAN, 0.0, 0.0)),
            Err(VolumeError::BadOrigin { .. })
        ));
    }

    #[test]
    fn affine_matches_index_to_world_and_decomposes_back() {
        let grid = rotated_anisotropic();
        let index = DVec3::new(3.5, -2.0, 6.25);
        let via_affine = grid.affine().transform_point3(index);
        assert!((via_affine - grid.index_to_world(index)).length() < 1e-15);
        let rebuilt = Grid::from_affine(grid.dims(), grid.affine()).unwrap();
        assert!((rebuilt.spacing_m() - grid.spacing_m()).length() < 1e-15);
        assert!(rebuilt.direction().abs_diff_eq(grid.direction(), 1e-12));
        assert_eq!(rebuilt.origin_m(), grid.origin_m());
    }

    #[test]
    fn bounds_contain_all_corners_and_are_tight() {
        let grid = Grid::axis_aligned([3, 4, 5], DVec3::new(1.0, 2.0, 3.0), DVec3::ONE).unwrap();
        let (min, max) = grid.bounds_world();
        assert_eq!(min, DVec3::ONE);
        assert_eq!(max, DVec3::new(3.0, 7.0, 13.0));
    }

    proptest! {
        #[test]
        fn world_index_round_trip_on_rotated_anisotropic_grid(
            i in -50.0..50.0f64, j in -50.0..50.0f64, k in -50.0..50.0f64,
        ) {
            let grid = rotated_anisotropic();
            let index = DVec3::new(i, j, k);
            let back = grid.world_to_index(grid.index_to_world(index));
            prop_assert!((back - index).length() < 1e-9, "{index} -> {back}");
            // Spacing is the world distance between neighbouring voxels along each axis.
            for axis in 0..3 {
                let step = grid.index_to_world(index + DVec3::AXES[axis]) - grid.index_to_world(index);
                prop_assert!((step.length() - grid.spacing_m()[axis]).abs() < 1e-12);
            }
        }
    }
}
