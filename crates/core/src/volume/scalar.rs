//! Scalar volumes (densities, intensities): storage and the per-tick samplers.
//!
//! The surface, viscosity and gradient-force modes call [`ScalarVolume::sample`] and
//! [`ScalarVolume::sample_with_gradient`] at the proxy every servo tick; both are allocation-free and
//! defined for every input (rules in the [`crate::volume`] header: trilinear values, the cubic B-spline
//! gradient mapped to world axes by `L⁻ᵀ`, outside the grid the clamp-to-edge field fading to 0 over
//! [`FADE_MARGIN_VOXELS`](crate::volume::FADE_MARGIN_VOXELS) voxels, 0 for non-finite positions).

use super::error::VolumeError;
use super::grid::Grid;
use super::sampling::{bspline_derivatives, index_derivatives, locate, trilinear};
use glam::DVec3;
use std::sync::Arc;

/// A scalar field on a regular grid, stored as `f32`, `data[i + nx·(j + ny·k)]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarVolume {
    grid: Grid,
    /// Shared, so a scene rebuilt for a control command (new transfer function, new mode) reuses the
    /// samples instead of copying them.
    data: Arc<[f32]>,
    value_range: (f32, f32),
}

impl ScalarVolume {
    /// Wraps `data` (x fastest) on `grid`. Rejects a length other than the voxel count and any
    /// non-finite value.
    pub fn new(grid: Grid, data: Vec<f32>) -> Result<ScalarVolume, VolumeError> {
        grid.check_data_length(data.len())?;
        let mut min = f32::INFINITY;
        let mut max = f32::NEG_INFINITY;
        for (index, &value) in data.iter().enumerate() {
            if !value.is_finite() {
                return Err(VolumeError::NonFiniteValue { index });
            }
            min = min.min(value);
            max = max.max(value);
        }
        Ok(ScalarVolume {
            grid,
            data: data.into(),
            value_range: (min, max),
        })
    }

    /// Samples `field(p_world)` at every voxel centre.
    pub fn from_fn(grid: Grid, field: impl Fn(DVec3) -> f64) -> Result<ScalarVolume, VolumeError> {
        let data = grid.sample_centres(|p| field(p) as f32);
        ScalarVolume::new(grid, data)
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The stored values, x fastest.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Smallest and largest stored value.
    pub fn value_range(&self) -> (f32, f32) {
        self.value_range
    }

    /// The stored value of voxel `(i, j, k)`, `None` outside the grid.
    pub fn voxel(&self, i: usize, j: usize, k: usize) -> Option<f32> {
        let [nx, ny, nz] = self.grid.dims();
        (i < nx && j < ny && k < nz).then(|| self.data[self.grid.offset(i, j, k)])
    }

    #[inline]
    fn fetch(&self, offset: usize) -> f64 {
        f64::from(self.data[offset])
    }

    /// Trilinear value at a world position (metres). Outside the grid the clamp-to-edge value fades to 0
    /// over [`FADE_MARGIN_VOXELS`](crate::volume::FADE_MARGIN_VOXELS) voxels ([`crate::volume`]); 0 for non-finite input.
    #[inline]
    pub fn sample(&self, p_world: DVec3) -> f64 {
        match locate(&self.grid, p_world) {
            Some(cell) if !cell.faded_out() => {
                trilinear(&cell, |offset| self.fetch(offset)) * cell.fade
            }
            _ => 0.0,
        }
    }

    /// Gradient (value per metre, world axes): the derivative of the cubic B-spline through the 4×4×4
    /// voxels around the position ([`crate::volume`]), continuous across cell faces; outside the grid, the
    /// gradient of the faded field. Zero for non-finite input.
    #[inline]
    pub fn gradient(&self, p_world: DVec3) -> DVec3 {
        self.sample_with_gradient(p_world).1
    }

    /// The value and the gradient of the same smooth field, the cubic B-spline through the 4×4×4 voxels
    /// around the position (faded outside the grid): the gradient is [`gradient`](Self::gradient), the value
    /// agrees with [`sample`](Self::sample) on linear fields and differs from the trilinear one by the
    /// B-spline's smoothing elsewhere. The surface mode reads both, so its plane is tangent to the very
    /// isosurface its strength is read from. Locates the cell once.
    #[inline]
    pub fn sample_with_gradient(&self, p_world: DVec3) -> (f64, DVec3) {
        match locate(&self.grid, p_world) {
            Some(cell) if !cell.faded_out() => {
                let fetch = |offset| self.fetch(offset);
                let (value, d) = bspline_derivatives(&cell, fetch);
                let (value, d) = cell.faded(value, d);
                (value, self.grid.gradient_to_world() * DVec3::from_array(d))
            }
            _ => (0.0, DVec3::ZERO),
        }
    }

    /// The gradient as the samplers computed it before the B-spline estimator: central differences at the
    /// voxels, interpolated trilinearly (clamp-to-edge, no fade). Kept to compare estimators in tests.
    pub fn central_difference_gradient(&self, p_world: DVec3) -> DVec3 {
        match locate(&self.grid, p_world) {
            Some(cell) => {
                let d = index_derivatives(&cell, |offset| self.fetch(offset));
                self.grid.gradient_to_world() * DVec3::from_array(d)
            }
            None => DVec3::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use proptest::prelude::*;

    /// A rotated, anisotropic grid holding the linear field `f(p) = c + a·p`.
    fn linear_field() -> (ScalarVolume, DVec3, f64) {
        let direction = DMat3::from_rotation_y(0.7) * DMat3::from_rotation_z(-0.3);
        let grid = Grid::new(
            [6, 5, 4],
            DVec3::new(0.002, 0.003, 0.005),
            direction,
            DVec3::new(-0.01, 0.02, 0.0),
        )
        .unwrap();
        let slope = DVec3::new(120.0, -40.0, 75.0);
        let constant = 2.5;
        let volume = ScalarVolume::from_fn(grid, |p| constant + slope.dot(p)).unwrap();
        (volume, slope, constant)
    }

    #[test]
    fn rejects_wrong_length_and_non_finite_data() {
        let grid = Grid::axis_aligned([2, 2, 2], DVec3::ONE, DVec3::ZERO).unwrap();
        assert_eq!(
            ScalarVolume::new(grid.clone(), vec![0.0; 7]),
            Err(VolumeError::DataLength {
                expected: 8,
                actual: 7
            })
        );
        let mut data = vec![0.0; 8];
        data[5] = f32::NAN;
        assert_eq!(
            ScalarVolume::new(grid, data),
            Err(VolumeError::NonFiniteValue { index: 5 })
        );
    }

    #[test]
    fn voxel_values_are_at_voxel_centres_x_fastest() {
        let grid = Grid::axis_aligned([3, 2, 2], DVec3::splat(0.5), DVec3::ZERO).unwrap();
        let data: Vec<f32> = (0..12).map(|v| v as f32).collect();
        let volume = ScalarVolume::new(grid, data).unwrap();
        assert_eq!(volume.voxel(2, 1, 1), Some(11.0));
        assert_eq!(volume.voxel(3, 0, 0), None);
        // Voxel (1, 1, 0) = offset 1 + 3·1 = 4, at world (0.5, 0.5, 0).
        assert_eq!(volume.sample(DVec3::new(0.5, 0.5, 0.0)), 4.0);
        assert_eq!(volume.value_range(), (0.0, 11.0));
    }

    #[test]
    fn outside_the_grid_the_field_fades_to_zero_over_the_margin() {
        let (volume, slope, constant) = linear_field();
        let grid = volume.grid().clone();
        let edge = grid.index_to_world(DVec3::new(5.0, 2.0, 1.5));
        let edge_value = constant + slope.dot(edge);
        // One voxel beyond the +i face (last index 5) is half the margin: s(1/2) = 1 - (1/4)(3 - 1) = 1/2.
        let half = grid.index_to_world(DVec3::new(6.0, 2.0, 1.5));
        assert!((volume.sample(half) - 0.5 * edge_value).abs() < 1e-5);
        // Two voxels out and beyond, and diagonally past a corner: nothing, value and gradient.
        for index in [
            DVec3::new(7.0, 2.0, 1.5),
            DVec3::new(7.5, 2.0, 1.5),
            DVec3::new(-2.0, 2.0, 1.5),
            DVec3::new(2.0, 2.0, 50.0),
            DVec3::new(1e6, -1e6, 1e6),
        ] {
            let p = grid.index_to_world(index);
            assert_eq!(
                volume.sample_with_gradient(p),
                (0.0, DVec3::ZERO),
                "{index}"
            );
        }
        // In the margin the gradient is that of the faded field: compare with finite differences of the
        // sampled values (an estimate independent of the product rule the sampler uses).
        for index in [
            DVec3::new(5.7, 2.0, 1.5),
            DVec3::new(6.3, 3.2, -0.8),
            DVec3::new(-1.2, 0.5, 3.9),
        ] {
            let p = grid.index_to_world(index);
            let h = 1e-7;
            let numeric = DVec3::new(
                volume.sample(p + DVec3::X * h) - volume.sample(p - DVec3::X * h),
                volume.sample(p + DVec3::Y * h) - volume.sample(p - DVec3::Y * h),
                volume.sample(p + DVec3::Z * h) - volume.sample(p - DVec3::Z * h),
            ) / (2.0 * h);
            let gradient = volume.gradient(p);
            assert!(
                (gradient - numeric).length() < 1e-4 * slope.length(),
                "{index}: {gradient} vs {numeric}"
            );
        }
    }

    #[test]
    fn non_finite_positions_sample_zero() {
        let (volume, _, _) = linear_field();
        for p in [
            DVec3::new(f64::NAN, 0.0, 0.0),
            DVec3::new(0.0, f64::INFINITY, 0.0),
            DVec3::splat(f64::NEG_INFINITY),
            DVec3::splat(f64::MAX),
        ] {
            assert_eq!(volume.sample(p), 0.0);
            assert_eq!(volume.gradient(p), DVec3::ZERO);
            assert_eq!(volume.sample_with_gradient(p), (0.0, DVec3::ZERO));
        }
    }

    #[test]
    fn single_voxel_axes_are_constant() {
        let grid = Grid::axis_aligned([1, 3, 1], DVec3::ONE, DVec3::ZERO).unwrap();
        let volume = ScalarVolume::new(grid, vec![1.0, 2.0, 4.0]).unwrap();
        assert_eq!(volume.sample(DVec3::new(3.0, 1.5, -2.0)), 3.0);
        assert_eq!(volume.gradient(DVec3::new(3.0, 1.5, -2.0)).x, 0.0);
        // The cubic B-spline over 0, 1, 2, 4, 6 (the voxels 1, 2, 4 with the linear extrapolations
        // 2·1 - 2 = 0 and 2·4 - 2 = 6 beyond them) at t = 1/2 between voxels 0 and 1: the derivative weights
        // (-(1-t)²/2, (3t² - 4t)/2, (-3t² + 2t + 1)/2, t²/2) = (-1/8, -5/8, 5/8, 1/8) on 0, 1, 2, 4 give 9/8.
        assert_eq!(volume.gradient(DVec3::new(0.0, 0.5, 0.0)).y, 1.125);
    }

    proptest! {
        #[test]
        fn trilinear_and_gradient_reproduce_a_linear_field_exactly(
            i in 0.0..5.0f64, j in 0.0..4.0f64, k in 0.0..3.0f64,
        ) {
            let (volume, slope, constant) = linear_field();
            let p = volume.grid().index_to_world(DVec3::new(i, j, k));
            let (value, gradient) = volume.sample_with_gradient(p);
            let exact = constant + slope.dot(p);
            // f32 storage: relative error ~1e-7 of the largest value.
            prop_assert!((value - exact).abs() < 1e-5, "{value} vs {exact}");
            prop_assert!((gradient - slope).length() < 1e-3 * slope.length(),
                "{gradient} vs {slope}");
            prop_assert!((value - volume.sample(p)).abs() < 1e-5);
            prop_assert_eq!(gradient, volume.gradient(p));
        }

        #[test]
        fn samplers_never_panic_or_return_nan(
            x in proptest::num::f64::ANY, y in proptest::num::f64::ANY, z in proptest::num::f64::ANY,
        ) {
            let (volume, _, _) = linear_field();
            let (value, gradient) = volume.sample_with_gradient(DVec3::new(x, y, z));
            prop_assert!(value.is_finite());
            prop_assert!(gradient.is_finite());
        }
    }
}
