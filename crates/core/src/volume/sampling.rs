//! Shared sampling kernels: cell location with the clamp-to-edge rule and the fade outside the grid,
//! trilinear interpolation, interpolated central differences and the cubic B-spline gradient, generic over
//! the value type (`f64` for scalar volumes, `DVec3` for vector volumes). Used by [`super::scalar`] and
//! [`super::vector`] on the servo thread: no allocation, no panics (every index is clamped into the grid
//! before it is used).
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
//!
//! The cubic B-spline gradient ([`bspline_derivatives`]) is the exact derivative of the uniform cubic
//! B-spline through the 4×4×4 voxels around the position, `Σ B'(t_x) B(t_y) B(t_z) V[...]` (and the two
//! other axes), with `B` the four cubic B-spline weights. It is C² across cell faces, smooths the grid's
//! staircase, and reproduces a linear field exactly: a voxel one step outside the grid (needed within a
//! voxel of the edge) is the linear extrapolation `2 V[0] - V[1]` (`2 V[n-1] - V[n-2]`), folded into the
//! weights of the two voxels it is made of.
//!
//! The fade ([`Cell::fade`]): with `o_a` the distance outside the grid along index axis `a` in voxels (0
//! inside) and `M` = [`FADE_MARGIN_VOXELS`], the field outside is the clamp-to-edge field times
//! `w = Π_a s(o_a / M)`, `s(t) = 1 - t²(3 - 2t)` for `t < 1` and 0 beyond: 1 on the grid, 0 from `M`
//! voxels out, continuous with a continuous derivative. Axes with a single voxel do not fade (a slice is
//! extruded). Samplers multiply values by `w` and add `value ⊗ ∇w` to derivatives (product rule), so the
//! gradient is that of the faded field.

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
    /// The fade weight `w` (module docs): 1 on the grid, 0 from [`FADE_MARGIN_VOXELS`] out.
    pub(crate) fade: f64,
    /// `∂w/∂u` along each index axis.
    pub(crate) fade_gradient: [f64; 3],
}

/// How far outside the grid (in voxels along each index axis) the sampled field fades to zero.
pub const FADE_MARGIN_VOXELS: f64 = 2.0;

/// `s(t) = 1 - t²(3 - 2t)` on `[0, 1)`, 0 beyond, and its derivative.
#[inline]
fn fade_step(t: f64) -> (f64, f64) {
    if t >= 1.0 {
        (0.0, 0.0)
    } else {
        (1.0 - t * t * (3.0 - 2.0 * t), -6.0 * t * (1.0 - t))
    }
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
        fade: 1.0,
        fade_gradient: [0.0; 3],
    };
    let mut steps = [(1.0, 0.0); 3];
    for axis in 0..3 {
        let last = last_index[axis];
        let u = index[axis];
        if !(u >= 0.0 && u <= last) {
            cell.inside[axis] = 0.0;
        }
        if dims[axis] == 1 {
            continue;
        }
        if u < 0.0 {
            let (s, ds) = fade_step(-u / FADE_MARGIN_VOXELS);
            steps[axis] = (s, -ds / FADE_MARGIN_VOXELS);
        } else if u > last {
            let (s, ds) = fade_step((u - last) / FADE_MARGIN_VOXELS);
            steps[axis] = (s, ds / FADE_MARGIN_VOXELS);
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
    cell.fade = steps[0].0 * steps[1].0 * steps[2].0;
    cell.fade_gradient = [
        steps[0].1 * steps[1].0 * steps[2].0,
        steps[0].0 * steps[1].1 * steps[2].0,
        steps[0].0 * steps[1].0 * steps[2].1,
    ];
    Some(cell)
}

impl Cell {
    /// The faded value `w V` and index derivatives `w dV + V ∇w` from the clamp-to-edge ones.
    #[inline]
    pub(crate) fn faded<T: Interpolate>(&self, value: T, derivatives: [T; 3]) -> (T, [T; 3]) {
        let w = self.fade;
        let g = self.fade_gradient;
        (
            value * w,
            [
                derivatives[0] * w + value * g[0],
                derivatives[1] * w + value * g[1],
                derivatives[2] * w + value * g[2],
            ],
        )
    }

    /// True where the field has faded to zero (more than the margin outside the grid).
    #[inline]
    pub(crate) fn faded_out(&self) -> bool {
        self.fade == 0.0
    }
}

/// Cubic B-spline weights and their derivatives at fraction `t` for the taps `-1, 0, 1, 2`.
#[inline]
fn bspline_weights(t: f64) -> ([f64; 4], [f64; 4]) {
    let t2 = t * t;
    let t3 = t2 * t;
    let u = 1.0 - t;
    (
        [
            u * u * u / 6.0,
            (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
            (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
            t3 / 6.0,
        ],
        [
            -u * u / 2.0,
            (3.0 * t2 - 4.0 * t) / 2.0,
            (-3.0 * t2 + 2.0 * t + 1.0) / 2.0,
            t2 / 2.0,
        ],
    )
}

/// One axis of the B-spline stencil: data offsets of the four taps and their value and derivative
/// weights, with the linear extrapolation outside the grid folded in (module docs).
#[inline]
fn bspline_axis(cell: &Cell, axis: usize) -> ([usize; 4], [f64; 4], [f64; 4]) {
    let n = cell.dims[axis];
    if n == 1 {
        return ([0; 4], [1.0, 0.0, 0.0, 0.0], [0.0; 4]);
    }
    let stride = cell.step[axis];
    let lower = cell.lower[axis];
    let (mut w, mut dw) = bspline_weights(cell.fraction[axis]);
    let mut index = [0usize; 4];
    for (m, slot) in index.iter_mut().enumerate() {
        // Tap m sits at voxel lower - 1 + m; taps 1 and 2 (lower, lower + 1) are always in the grid.
        *slot = (lower + m).saturating_sub(1).min(n - 1) * stride;
    }
    if lower == 0 {
        // Tap 0 is voxel -1 = 2 V[0] - V[1]: voxel 0 is tap 1, voxel 1 tap 2.
        for weights in [&mut w, &mut dw] {
            let ghost = weights[0];
            weights[1] += 2.0 * ghost;
            weights[2] -= ghost;
            weights[0] = 0.0;
        }
    }
    if lower + 2 >= n {
        // Tap 3 is voxel n = 2 V[n-1] - V[n-2]: voxel n-1 is tap 2, voxel n-2 tap 1.
        for weights in [&mut w, &mut dw] {
            let ghost = weights[3];
            weights[2] += 2.0 * ghost;
            weights[1] -= ghost;
            weights[3] = 0.0;
        }
    }
    for d in &mut dw {
        *d *= cell.inside[axis];
    }
    (index, w, dw)
}

/// The value and index-space derivatives `[∂/∂i, ∂/∂j, ∂/∂k]` of the cubic B-spline through the 4×4×4 voxels
/// around the cell (module docs), derivatives zeroed along clamped axes. 64 fetches.
#[inline]
pub(crate) fn bspline_derivatives<T: Interpolate>(
    cell: &Cell,
    fetch: impl Fn(usize) -> T,
) -> (T, [T; 3]) {
    let (ix, wx, dx) = bspline_axis(cell, 0);
    let (iy, wy, dy) = bspline_axis(cell, 1);
    let (iz, wz, dz) = bspline_axis(cell, 2);
    let zero = fetch(ix[1] + iy[1] + iz[1]) * 0.0;
    let mut out = [zero; 3];
    let mut value = zero;
    for c in 0..4 {
        for b in 0..4 {
            let (yz_offset, wyz, dyz, wdz) =
                (iy[b] + iz[c], wy[b] * wz[c], dy[b] * wz[c], wy[b] * dz[c]);
            if wyz == 0.0 && dyz == 0.0 && wdz == 0.0 {
                continue;
            }
            for a in 0..4 {
                let v = fetch(ix[a] + yz_offset);
                value = value + v * (wx[a] * wyz);
                out[0] = out[0] + v * (dx[a] * wyz);
                out[1] = out[1] + v * (wx[a] * dyz);
                out[2] = out[2] + v * (wx[a] * wdz);
            }
        }
    }
    (value, out)
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
