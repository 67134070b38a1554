//! Vector volumes (flow fields): storage and the per-tick samplers, including the derivatives the
//! vortex mode needs.
//!
//! Stored vectors are taken to be in world axes (loaders rotate nothing but do flip the x and y
//! components when they convert LPS files to RAS). The Jacobian is
//! `J[a][b] = ∂v_a/∂x_b` (world axes, per metre): the index-space derivatives (interpolated central
//! differences, see [`crate::volume`]) multiplied on the right by `L⁻¹`, since `∂u/∂x = L⁻¹`. Curl and
//! divergence are read off `J`:
//!
//! ```text
//! curl v = (∂v_z/∂y - ∂v_y/∂z, ∂v_x/∂z - ∂v_z/∂x, ∂v_y/∂x - ∂v_x/∂y),   div v = trace J
//! ```
//!
//! All samplers are allocation-free and return zero for non-finite positions.

use super::error::VolumeError;
use super::grid::Grid;
use super::sampling::{index_derivatives, locate, trilinear};
use glam::{DMat3, DVec3};
use std::sync::Arc;

/// A 3-vector field on a regular grid, stored as `[f32; 3]`, `data[i + nx·(j + ny·k)]`.
#[derive(Debug, Clone, PartialEq)]
pub struct VectorVolume {
    grid: Grid,
    /// Shared, so a scene rebuilt for a control command (new transfer function, new mode) reuses the
    /// samples instead of copying them.
    data: Arc<[[f32; 3]]>,
    magnitude_range: (f32, f32),
}

impl VectorVolume {
    /// Wraps `data` (x fastest) on `grid`. Rejects a length other than the voxel count and any
    /// non-finite component.
    pub fn new(grid: Grid, data: Vec<[f32; 3]>) -> Result<VectorVolume, VolumeError> {
        grid.check_data_length(data.len())?;
        let mut min = f32::INFINITY;
        let mut max = f32::NEG_INFINITY;
        for (index, value) in data.iter().enumerate() {
            if !value.iter().all(|c| c.is_finite()) {
                return Err(VolumeError::NonFiniteValue { index });
            }
            // Magnitude in f64 so that large finite components cannot overflow to infinity.
            let magnitude = DVec3::new(value[0].into(), value[1].into(), value[2].into()).length();
            min = min.min(magnitude as f32);
            max = max.max(magnitude as f32);
        }
        Ok(VectorVolume {
            grid,
            data: data.into(),
            magnitude_range: (min, max),
        })
    }

    /// Samples `field(p_world)` at every voxel centre.
    pub fn from_fn(
        grid: Grid,
        field: impl Fn(DVec3) -> DVec3,
    ) -> Result<VectorVolume, VolumeError> {
        let data = grid.sample_centres(|p| field(p).as_vec3().to_array());
        VectorVolume::new(grid, data)
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The stored vectors, x fastest.
    pub fn data(&self) -> &[[f32; 3]] {
        &self.data
    }

    /// Smallest and largest stored vector magnitude.
    pub fn magnitude_range(&self) -> (f32, f32) {
        self.magnitude_range
    }

    /// The stored vector of voxel `(i, j, k)`, `None` outside the grid.
    pub fn voxel(&self, i: usize, j: usize, k: usize) -> Option<[f32; 3]> {
        let [nx, ny, nz] = self.grid.dims();
        (i < nx && j < ny && k < nz).then(|| self.data[self.grid.offset(i, j, k)])
    }

    #[inline]
    fn fetch(&self, offset: usize) -> DVec3 {
        let [x, y, z] = self.data[offset];
        DVec3::new(x.into(), y.into(), z.into())
    }

    /// Trilinear vector at a world position. Outside the grid the clamp-to-edge vector fades to zero over
    /// [`FADE_MARGIN_VOXELS`](crate::volume::FADE_MARGIN_VOXELS) voxels ([`crate::volume`]); zero for non-finite input.
    #[inline]
    pub fn sample(&self, p_world: DVec3) -> DVec3 {
        match locate(&self.grid, p_world) {
            Some(cell) if !cell.faded_out() => {
                trilinear(&cell, |offset| self.fetch(offset)) * cell.fade
            }
            _ => DVec3::ZERO,
        }
    }

    /// World-axis Jacobian, `jacobian(p).col(b)[a] = ∂v_a/∂x_b` (per metre). Derivatives along
    /// index axes where the position is outside the grid are those of the fade (the Jacobian of the faded
    /// field); zero for non-finite input.
    #[inline]
    pub fn jacobian(&self, p_world: DVec3) -> DMat3 {
        match locate(&self.grid, p_world) {
            Some(cell) if !cell.faded_out() => {
                let fetch = |offset| self.fetch(offset);
                let mut d = index_derivatives(&cell, fetch);
                if cell.fade < 1.0 {
                    d = cell.faded(trilinear(&cell, fetch), d).1;
                }
                let [d_di, d_dj, d_dk] = d;
                DMat3::from_cols(d_di, d_dj, d_dk) * self.grid.linear_inverse()
            }
            _ => DMat3::ZERO,
        }
    }

    /// Curl (per metre times the field's unit) from the Jacobian.
    #[inline]
    pub fn curl(&self, p_world: DVec3) -> DVec3 {
        curl_of(&self.jacobian(p_world))
    }

    /// Divergence (per metre times the field's unit), the trace of the Jacobian.
    #[inline]
    pub fn divergence(&self, p_world: DVec3) -> f64 {
        divergence_of(&self.jacobian(p_world))
    }
}

/// Curl from a Jacobian `J.col(b)[a] = ∂v_a/∂x_b`.
#[inline]
pub fn curl_of(jacobian: &DMat3) -> DVec3 {
    let d_dx = jacobian.x_axis;
    let d_dy = jacobian.y_axis;
    let d_dz = jacobian.z_axis;
    DVec3::new(d_dy.z - d_dz.y, d_dz.x - d_dx.z, d_dx.y - d_dy.x)
}

/// Divergence from a Jacobian `J.col(b)[a] = ∂v_a/∂x_b`.
#[inline]
pub fn divergence_of(jacobian: &DMat3) -> f64 {
    jacobian.x_axis.x + jacobian.y_axis.y + jacobian.z_axis.z
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `v(p) = M p + c` on a rotated, anisotropic grid: its Jacobian is exactly `M`.
    fn affine_field() -> (VectorVolume, DMat3) {
        let direction = DMat3::from_rotation_x(0.5) * DMat3::from_rotation_z(1.2);
        let grid = Grid::new(
            [5, 6, 7],
            DVec3::new(0.004, 0.002, 0.003),
            direction,
            DVec3::new(0.0, -0.01, 0.005),
        )
        .unwrap();
        let m = DMat3::from_cols(
            DVec3::new(3.0, -1.0, 2.0),
            DVec3::new(0.5, 4.0, -2.0),
            DVec3::new(1.0, 6.0, -1.5),
        );
        let c = DVec3::new(0.1, 0.2, -0.3);
        (VectorVolume::from_fn(grid, |p| m * p + c).unwrap(), m)
    }

    #[test]
    fn rejects_wrong_length_and_non_finite_data() {
        let grid = Grid::axis_aligned([2, 1, 1], DVec3::ONE, DVec3::ZERO).unwrap();
        assert!(matches!(
            VectorVolume::new(grid.clone(), vec![[0.0; 3]]),
            Err(VolumeError::DataLength { .. })
        ));
        assert_eq!(
            VectorVolume::new(grid, vec![[0.0; 3], [0.0, f32::INFINITY, 0.0]]),
            Err(VolumeError::NonFiniteValue { index: 1 })
        );
    }

    #[test]
    fn magnitude_range_does_not_overflow() {
        let grid = Grid::axis_aligned([2, 1, 1], DVec3::ONE, DVec3::ZERO).unwrap();
        let volume = VectorVolume::new(grid, vec![[3.0, 4.0, 0.0], [0.0; 3]]).unwrap();
        assert_eq!(volume.magnitude_range(), (0.0, 5.0));
    }

    proptest! {
        #[test]
        fn jacobian_curl_and_divergence_of_an_affine_field_are_exact(
            i in 0.0..4.0f64, j in 0.0..5.0f64, k in 0.0..6.0f64,
        ) {
            let (volume, m) = affine_field();
            let p = volume.grid().index_to_world(DVec3::new(i, j, k));
            let jacobian = volume.jacobian(p);
            prop_assert!(jacobian.abs_diff_eq(m, 1e-3), "{jacobian} vs {m}");
            prop_assert!((volume.divergence(p) - divergence_of(&m)).abs() < 1e-3);
            prop_assert!((volume.curl(p) - curl_of(&m)).length() < 1e-3);
        }

        #[test]
        fn samplers_never_panic_or_return_nan(
            x in proptest::num::f64::ANY, y in proptest::num::f64::ANY, z in proptest::num::f64::ANY,
        ) {
            let (volume, _) = affine_field();
            let p = DVec3::new(x, y, z);
            prop_assert!(volume.sample(p).is_finite());
            prop_assert!(volume.jacobian(p).is_finite());
            prop_assert!(volume.curl(p).is_finite());
            prop_assert!(volume.divergence(p).is_finite());
        }
    }

    #[test]
    fn the_flow_ends_two_voxels_outside_the_grid() {
        let (volume, _) = affine_field();
        let grid = volume.grid().clone();
        // Last index along j is 5: one voxel out the field is half the edge's (s(1/2) = 1/2), two out nothing.
        let edge = volume.sample(grid.index_to_world(DVec3::new(2.0, 5.0, 3.0)));
        let half = volume.sample(grid.index_to_world(DVec3::new(2.0, 6.0, 3.0)));
        assert!((half - 0.5 * edge).length() < 1e-6, "{half} vs {edge}");
        for index in [DVec3::new(2.0, 7.0, 3.0), DVec3::new(-30.0, 2.0, 3.0)] {
            let p = grid.index_to_world(index);
            assert_eq!(volume.sample(p), DVec3::ZERO);
            assert_eq!(volume.jacobian(p), DMat3::ZERO);
        }
    }

    #[test]
    fn non_finite_positions_give_zero() {
        let (volume, _) = affine_field();
        let p = DVec3::new(0.0, f64::NAN, 0.0);
        assert_eq!(volume.sample(p), DVec3::ZERO);
        assert_eq!(volume.jacobian(p), DMat3::ZERO);
    }
}
