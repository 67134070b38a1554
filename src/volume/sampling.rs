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

use super::Grid;
use glam::DVec3;
use std::ops::{Add, Mul, Sub};

/// Values the kernels can interpolate.
pub(crate) trait Interpolate:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<f64, Output = Self>
{
}
impl Interpolate for f64 {}
impl Interpolate for DVec3 {}

/// Where a position falls in the grid after clamping.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cell {
    /// Lower corner voxel index per axis.
    lower: [usize; 3],
    /// Upper corner voxel index per axis (`lower + 1`, or `lower` on a one-voxel axis).
    upper: [usize; 3],
    /// Fractions in `[0, 1]` per axis.
    fraction: [f64; 3],
    /// Per axis: 1.0 where the position was inside the grid's extent, 0.0 where it was clamped.
    /// Derivatives along clamped axes are multiplied by this.
    inside: [f64; 3],
}

/// Locates `p_world` in the grid, applying clamp-to-edge. `None` for non-finite positions.
#[inline]
pub(crate) fn locate(grid: &Grid, p_world: DVec3) -> Option<Cell> {
    let index = grid.world_to_index(p_world);
    if !index.is_finite() {
        return None;
    }
    let dims = grid.dims();
    let mut cell = Cell {
        lower: [0; 3],
        upper: [0; 3],
        fraction: [0.0; 3],
        inside: [1.0; 3],
    };
    for axis in 0..3 {
        let n = dims[axis];
        let last = (n - 1) as f64;
        let u = index[axis];
        if !(0.0..=last).contains(&u) {
            cell.inside[axis] = 0.0;
        }
        if n == 1 {
            continue;
        }
        let u = u.clamp(0.0, last);
        // `u` is in [0, n-1]; the cast is exact for any grid that fits in memory.
        let lower = (u.floor() as usize).min(n - 2);
        cell.lower[axis] = lower;
        cell.upper[axis] = lower + 1;
        cell.fraction[axis] = u - lower as f64;
    }
    Some(cell)
}

/// Trilinear interpolation of `fetch(i, j, k)` over the cell.
#[inline]
pub(crate) fn trilinear<T: Interpolate>(
    cell: &Cell,
    fetch: impl Fn(usize, usize, usize) -> T,
) -> T {
    let [i0, j0, k0] = cell.lower;
    let [i1, j1, k1] = cell.upper;
    let [tx, ty, tz] = cell.fraction;
    let lerp = |a: T, b: T, t: f64| a + (b - a) * t;
    let c00 = lerp(fetch(i0, j0, k0), fetch(i1, j0, k0), tx);
    let c10 = lerp(fetch(i0, j1, k0), fetch(i1, j1, k0), tx);
    let c01 = lerp(fetch(i0, j0, k1), fetch(i1, j0, k1), tx);
    let c11 = lerp(fetch(i0, j1, k1), fetch(i1, j1, k1), tx);
    let c0 = lerp(c00, c10, ty);
    let c1 = lerp(c01, c11, ty);
    lerp(c0, c1, tz)
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
/// trilinearly, zeroed along clamped axes.
#[inline]
pub(crate) fn index_derivatives<T: Interpolate>(
    grid: &Grid,
    cell: &Cell,
    fetch: impl Fn(usize, usize, usize) -> T,
) -> [T; 3] {
    let [nx, ny, nz] = grid.dims();
    let d_di = trilinear(cell, |i, j, k| {
        let (minus, plus, scale) = difference_stencil(i, nx);
        (fetch(plus, j, k) - fetch(minus, j, k)) * scale
    });
    let d_dj = trilinear(cell, |i, j, k| {
        let (minus, plus, scale) = difference_stencil(j, ny);
        (fetch(i, plus, k) - fetch(i, minus, k)) * scale
    });
    let d_dk = trilinear(cell, |i, j, k| {
        let (minus, plus, scale) = difference_stencil(k, nz);
        (fetch(i, j, plus) - fetch(i, j, minus)) * scale
    });
    [
        d_di * cell.inside[0],
        d_dj * cell.inside[1],
        d_dk * cell.inside[2],
    ]
}
