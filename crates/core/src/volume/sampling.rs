//! Shared sampling kernels: cell location with the clamp-to-edge rule, trilinear interpolation and
//! interpolated central differences, generic over the value type (`f64` for scalar volumes, `DVec3`
//! for vector volumes). Used by [`super::scalar`] and [`super::vector`] on the servo thread: no
//! allocation, no panics (every index is clamped into the grid before it is used).
//!
//! Maths. In index space, with the cell corner `c = floor(u)` and fractions `t = u - c`,
//!
//! ```text
//! V(u) = Σ_{a,b,g ∈ {0,1}} w_a(t_x) w_b(t_y) w_g(t_z) V[c + (a, b, g)],   w_0(t) = 1 - t, w_1(t) = t
//! ```
//!
//! The derivative along axis `a` at voxel `v` is `(V[v + e_a] - V[v - e_a]) / 2`, or the one-sided
//! difference `V[v + e_a] - V[v]` / `V[v] - V[v - e_a]` on the first / last voxel of the axis; these
//! per-voxel derivatives are interpolated with the same trilinear weights. Both steps reproduce a
//! linear field exactly. For an axis with one voxel the derivative is zero.

use super::grid::Grid;
use glam::DVec3;
use std::ops::{Add, Mul, Sub};

/// Values the kernels can interpolate.
pub(crate) trait Interpolate:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<f64, Output = Self>
{
}
impl Interpolate for f64 {}
impl Interpolate for DVec3 {}

/// Where a position falls in the grid after clamping, as offsets into the data array.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cell {
    /// Offset of the lower corner voxel.
    base: usize,
    /// Per axis: offset from a lower-corner voxel to its upper neighbour (the axis stride, or 0 on a
    /// one-voxel axis).
    step: [usize; 3],
    /// Fractions in `[0, 1]` per axis.
    fraction: [f64; 3],
    /// Lower corner voxel index per axis.
    lower: [usize; 3],
    /// Voxels per axis.
    dims: [usize; 3],
    /// Per axis: 1.0 where the position was inside the grid's extent, 0.0 where it was clamped.
    /// Derivatives along clamped axes are multiplied by this.
    inside: [f64; 3],
}

/// Locates `p_world` in the grid, applying clamp-to-edge. `None` for non-finite positions.
///
/// Written for the servo thread: the float/index conversions go through `i64` (one instruction each
/// on x86-64, where `usize` <-> `f64` takes several) and the per-axis limits are precomputed in the grid.
#[inline(always)]
pub(crate) fn locate(grid: &Grid, p_world: DVec3) -> Option<Cell> {
    let index = grid.world_to_index(p_world);
    if !index.is_finite() {
        return None;
    }
    let dims = grid.dims();
    let last_index = grid.last_index();
    let strides = grid.strides();
    let mut cell = Cell {
        base: 0,
        step: [0; 3],
        fraction: [0.0; 3],
        lower: [0; 3],
        dims,
        inside: [1.0; 3],
    };
    for axis in 0..3 {
        let last = last_index[axis];
        let u = index[axis];
        if !(u >= 0.0 && u <= last) {
            cell.inside[axis] = 0.0;
        }
        if dims[axis] == 1 {
            continue;
        }
        let u = u.clamp(0.0, last);
        // `u` is in [0, n-1]: truncation is floor. The upper cell is reused at u = n-1.
        let lower = (u as i64).min(last as i64 - 1);
        cell.fraction[axis] = u - lower as f64;
        let lower = lower as usize;
        cell.base += lower * strides[axis];
        cell.step[axis] = strides[axis];
        cell.lower[axis] = lower;
    }
    Some(cell)
}

/// Trilinear interpolation of `fetch(offset)` over the cell's 8 corners.
#[inline]
pub(crate) fn trilinear<T: Interpolate>(cell: &Cell, fetch: impl Fn(usize) -> T) -> T {
    let [sx, sy, sz] = cell.step;
    let [tx, ty, tz] = cell.fraction;
    let lerp = |a: T, b: T, t: f64| a + (b - a) * t;
    let o = cell.base;
    let c00 = lerp(fetch(o), fetch(o + sx), tx);
    let c10 = lerp(fetch(o + sy), fetch(o + sx + sy), tx);
    let c01 = lerp(fetch(o + sz), fetch(o + sx + sz), tx);
    let c11 = lerp(fetch(o + sy + sz), fetch(o + sx + sy + sz), tx);
    lerp(lerp(c00, c10, ty), lerp(c01, c11, ty), tz)
}

/// The neighbours and step used for the difference at voxel `i` of an axis with `n` voxels:
/// `(minus, plus, 1/step)`.
#[inline]
fn difference_stencil(i: usize, n: usize) -> (usize, usize, f64) {
    if n == 1 {
        (0, 0, 0.0)
    } else if i == 0 {
        (0, 1, 1.0)
    } else if i + 1 >= n {
        (n - 2, n - 1, 1.0)
    } else {
        (i - 1, i + 1, 0.5)
    }
}

/// Index-space derivatives `[∂/∂i, ∂/∂j, ∂/∂k]` of the field, central differences interpolated
/// trilinearly, zeroed along clamped axes. One pass over the 8 corners computes all three.
#[inline]
pub(crate) fn index_derivatives<T: Interpolate>(cell: &Cell, fetch: impl Fn(usize) -> T) -> [T; 3] {
    // The stencil along an axis depends only on the corner's side (lower/upper) along that axis:
    // (offset back to the minus voxel, offset forward to the plus voxel, weight).
    let stencil = |axis: usize, side: usize| {
        let n = cell.dims[axis];
        let stride = cell.step[axis];
        let voxel = (cell.lower[axis] + side).min(n - 1);
        let (minus, plus, scale) = difference_stencil(voxel, n);
        (
            (voxel - minus) * stride,
            (plus - voxel) * stride,
            scale * cell.inside[axis],
        )
    };
    let stencils = [
        [stencil(0, 0), stencil(0, 1)],
        [stencil(1, 0), stencil(1, 1)],
        [stencil(2, 0), stencil(2, 1)],
    ];
    let difference = |offset: usize, (back, forward, weight): (usize, usize, f64)| {
        (fetch(offset + forward) - fetch(offset - back)) * weight
    };
    let corner = |offset: usize, x: usize, y: usize, z: usize| {
        [
            difference(offset, stencils[0][x]),
            difference(offset, stencils[1][y]),
            difference(offset, stencils[2][z]),
        ]
    };
    let [sx, sy, sz] = cell.step;
    let [tx, ty, tz] = cell.fraction;
    let o = cell.base;
    let lerp = |a: [T; 3], b: [T; 3], t: f64| {
        [
            a[0] + (b[0] - a[0]) * t,
            a[1] + (b[1] - a[1]) * t,
            a[2] + (b[2] - a[2]) * t,
        ]
    };
    let c00 = lerp(corner(o, 0, 0, 0), corner(o + sx, 1, 0, 0), tx);
    let c10 = lerp(corner(o + sy, 0, 1, 0), corner(o + sx + sy, 1, 1, 0), tx);
    let c01 = lerp(corner(o + sz, 0, 0, 1), corner(o + sx + sz, 1, 0, 1), tx);
    let c11 = lerp(
        corner(o + sy + sz, 0, 1, 1),
        corner(o + sx + sy + sz, 1, 1, 1),
        tx,
    );
    lerp(lerp(c00, c10, ty), lerp(c01, c11, ty), tz)
}
