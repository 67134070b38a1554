//! A non-directed primitive as the solver's methods see it, and the operations on its dual set `U_i` that
//! the dual sweeps, the active-set attempt, the primal Newton method and the certificate share.

use crate::primitive::PrimitiveKind;
use glam::DVec3;

/// A non-directed primitive as the solver sees it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Item {
    pub kind: PrimitiveKind,
    pub position_m: DVec3,
    pub direction: DVec3,
    pub strength_n: f64,
}

/// What an unused slot of a fixed-size workspace holds: a primitive of no strength.
impl Default for Item {
    fn default() -> Self {
        Self {
            kind: PrimitiveKind::Directed,
            position_m: DVec3::ZERO,
            direction: DVec3::ZERO,
            strength_n: 0.0,
        }
    }
}

/// The dual block update of one item (the module header's block sweeps): the exact minimiser of the dual over `u_i`
/// with the others' sum `others` fixed, `proj_{U_i}(k (y - c_i) - others)`. Used by the dual sweeps and by the
/// primal method's cold start.
#[inline]
pub(crate) fn block_update(item: &Item, y: DVec3, k: f64, others: DVec3) -> DVec3 {
    project(item, k * (y - item.position_m) - others)
}

/// Euclidean projection of `v` onto the dual set `U_i` of an item.
#[inline]
pub(crate) fn project(item: &Item, v: DVec3) -> DVec3 {
    let s = item.strength_n;
    match item.kind {
        PrimitiveKind::Point => clamp_length(v, s),
        PrimitiveKind::Line => {
            let q = item.direction;
            clamp_length(v - q * q.dot(v), s)
        }
        PrimitiveKind::Plane => {
            let q = item.direction;
            let t = (-q.dot(v)).max(0.0).min(s);
            -t * q
        }
        PrimitiveKind::Directed => DVec3::ZERO,
    }
}

/// How far a kink's multiplier `u` lies outside the item's dual set `U_i` (N, at most 0 inside it), and
/// whether it lies past the set's full end, a plane's `-q.u` above `s`: the plane then leaves its kink pushing
/// with all of `s`. Past the other end (a plane's `-q.u` below 0, a point's or line's `|u|` above `s`) the item
/// leaves its kink to exert no more than `s` away from it.
#[inline]
pub(crate) fn multiplier_excess(item: &Item, u: DVec3) -> (f64, bool) {
    let s = item.strength_n;
    match item.kind {
        PrimitiveKind::Plane => {
            let t = -item.direction.dot(u);
            if t < 0.0 {
                (-t, false)
            } else {
                (t - s, true)
            }
        }
        _ => (u.length() - s, false),
    }
}

#[inline]
fn clamp_length(v: DVec3, max: f64) -> DVec3 {
    let length = v.length();
    if length > max {
        if max > 0.0 {
            v * (max / length)
        } else {
            DVec3::ZERO
        }
    } else {
        v
    }
}

/// A subgradient of `s dist(x, C)` at `x` (zero on the kink): the dual that is exact if `x` is the answer and the
/// item is off its kink.
pub(crate) fn subgradient(item: &Item, x: DVec3) -> DVec3 {
    let s = item.strength_n;
    let r = x - item.position_m;
    match item.kind {
        PrimitiveKind::Point => r.normalize_or_zero() * s,
        PrimitiveKind::Line => {
            let q = item.direction;
            (r - q * q.dot(r)).normalize_or_zero() * s
        }
        PrimitiveKind::Plane => {
            if item.direction.dot(r) < 0.0 {
                -s * item.direction
            } else {
                DVec3::ZERO
            }
        }
        PrimitiveKind::Directed => DVec3::ZERO,
    }
}
