//! The per-item terms of the exact solver's certificate ([`super::certificate`]): the distance to a primitive's
//! kink set and whether one kink set contains another, the share of the gap a projected dual value leaves, how far
//! a dual value lies inside its set, and the rounding bound of an eigenvalue. Pure functions of one item (or two),
//! each with its rounding accounted for as docs/solver.md ("Why the bound never lies") says.

use super::linalg::outer;
use crate::item::Item;
use crate::primitive::PrimitiveKind;
use glam::{DMat3, DVec3};

const EPS: f64 = f64::EPSILON;

/// The distance from `x` to an item's kink set, with an upper bound on its rounding error (`4 eps |r|`, with
/// `|r|` itself for a point and the upper bound `|r|_1 >= |r|` for a line or a plane, which needs no square root).
#[inline]
pub(crate) fn kink_distance(item: &Item, r: DVec3) -> (f64, f64) {
    match item.kind {
        PrimitiveKind::Point => {
            let distance = r.length();
            (distance, 4.0 * EPS * distance)
        }
        PrimitiveKind::Line => {
            let q = item.direction;
            (
                (r - q * q.dot(r)).length(),
                4.0 * EPS * r.abs().element_sum(),
            )
        }
        PrimitiveKind::Plane => (
            item.direction.dot(r).abs(),
            4.0 * EPS * r.abs().element_sum(),
        ),
        PrimitiveKind::Directed => (f64::INFINITY, 0.0),
    }
}

/// `s dist(x, C) - v.(x - c)` for a ball or disc of radius `s` and `|v| <= s`, written as two non-negative
/// terms so that nothing cancels: `(s - |v|) |r| + (|v| |r| - v.r)`.
pub(crate) fn ball_share(s: f64, v: DVec3, r: DVec3) -> f64 {
    let rho = r.length();
    let a = v.length();
    let dot = v.dot(r);
    // |v||r| - v.r, without cancellation: |v x r|^2 / (|v||r| + v.r) when v.r > 0.
    let angle_term = if dot > 0.0 {
        v.cross(r).length_squared() / (a * rho + dot)
    } else {
        a * rho - dot
    };
    (s - a).max(0.0) * rho + angle_term
}

/// One item's share of the gap at `x`, `s dist(x, C) - v.(x - c) >= 0` for a feasible `v`, computed without
/// cancellation, plus an upper bound on its rounding error.
pub(crate) fn projected_share(item: &Item, v: DVec3, r: DVec3) -> f64 {
    let s = item.strength_n;
    let share = match item.kind {
        PrimitiveKind::Point => ball_share(s, v, r),
        PrimitiveKind::Line => {
            let q = item.direction;
            ball_share(s, v - q * q.dot(v), r - q * q.dot(r))
        }
        PrimitiveKind::Plane => {
            let q = item.direction;
            let sigma = q.dot(r);
            let t = -q.dot(v);
            if sigma >= 0.0 {
                t.max(0.0) * sigma
            } else {
                (s - t).max(0.0) * -sigma
            }
        }
        PrimitiveKind::Directed => 0.0,
    };
    // The share is a handful of products of r (rounded to eps/2 per coordinate) with numbers bounded by s + |v|.
    share * (1.0 + 16.0 * EPS) + 16.0 * EPS * (s + v.length()) * r.length()
}

/// The codimension of an item's kink set (point 3, line 2, plane 1).
pub(crate) fn codimension(item: &Item) -> usize {
    match item.kind {
        PrimitiveKind::Point => 3,
        PrimitiveKind::Line => 2,
        _ => 1,
    }
}

/// Whether kink set `small` lies inside kink set `big`, decided exactly, without rounding, by a sufficient rule
/// that holds for coordinate-aligned geometry (a line along x in the plane z = 0, a friction point on such a
/// plane, two planes with one normal and offset): coordinate by coordinate, anchors that are equal or differ
/// only where the set extends (a zero normal component of a plane, the one non-zero component of an axis-aligned
/// line), and directions that are equal, or orthogonal with no coordinate where both are non-zero. Sets that
/// are inside one another only to within rounding are not found: the caller then treats them as distinct.
pub(crate) fn kink_set_contains(big: &Item, small: &Item) -> bool {
    let (a, p) = (small.position_m, big.position_m);
    let (d, n) = (small.direction, big.direction);
    match big.kind {
        PrimitiveKind::Point => small.kind == PrimitiveKind::Point && a == p,
        PrimitiveKind::Line => {
            let along = |j: usize| (0..3).all(|i| i == j || n[i] == 0.0);
            let on_line = (0..3).all(|j| a[j] == p[j] || along(j));
            match small.kind {
                PrimitiveKind::Point => on_line,
                PrimitiveKind::Line => on_line && d == n,
                _ => false,
            }
        }
        PrimitiveKind::Plane => {
            let on_plane = (0..3).all(|j| a[j] == p[j] || n[j] == 0.0);
            match small.kind {
                PrimitiveKind::Point => on_plane,
                PrimitiveKind::Line => on_plane && (0..3).all(|j| d[j] == 0.0 || n[j] == 0.0),
                PrimitiveKind::Plane => on_plane && d == n,
                PrimitiveKind::Directed => false,
            }
        }
        PrimitiveKind::Directed => false,
    }
}

/// The projector onto the normal space of an item's kink set (point: all of R^3; line: the plane orthogonal to
/// it; plane: its normal).
pub(crate) fn normal_projector(item: &Item) -> DMat3 {
    match item.kind {
        PrimitiveKind::Point => DMat3::IDENTITY,
        PrimitiveKind::Line => DMat3::IDENTITY - outer(item.direction, item.direction),
        _ => outer(item.direction, item.direction),
    }
}

/// A lower bound on how far a projected dual value lies inside its set, in the directions normal to the kink
/// set (ball or disc: `s - |v|`; segment `{-t q : 0 <= t <= s}`: `min(t, s - t)`), less its rounding and the
/// few ulps of `s` by which a rounded projection may lie off the set (docs/solver.md, 2 (a)).
pub(crate) fn dual_margin(item: &Item, v: DVec3) -> f64 {
    let s = item.strength_n;
    let inside = match item.kind {
        PrimitiveKind::Point | PrimitiveKind::Line => s - v.length() * (1.0 + 4.0 * EPS),
        PrimitiveKind::Plane => {
            let t = -item.direction.dot(v);
            t.min(s - t) - 4.0 * EPS * s
        }
        PrimitiveKind::Directed => 0.0,
    };
    inside * (1.0 - 4.0 * EPS) - 8.0 * EPS * s
}

/// An upper bound on the error of [`super::linalg::symmetric_eigen3`]'s eigenvalues of a positive
/// semi-definite sum of `count` weighted projectors: each entry of the sum is rounded at most `count` times, and
/// each of at most 96 Jacobi rotations is backward stable to a few ulps of the matrix's norm, which the trace
/// bounds.
pub(crate) fn eigenvalue_error(m: DMat3, count: usize) -> f64 {
    let trace = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    (4e-13 + 8.0 * EPS * count as f64) * trace.abs()
}
