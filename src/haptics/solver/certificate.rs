//! The certificate of the exact solver: an upper bound on `|x - x*|`, the distance from a returned proxy
//! position to the true minimiser, that holds whatever dual values it is given and whatever rounding did.
//!
//! It sits at the end of every solve ([`super::Solver`]): every exit (certified, budget exhausted before or
//! after a sweep, stalled, no primitives) returns a point together with a bound from [`certify`]. The argument
//! is written out in the solver's module header ([`super`], "Why the bound never lies"); this file implements it.
//!
//! In short, for the floating-point point `x` and dual values `u_i` (any values, feasible or not):
//!
//! - every `u_i` is first projected onto its set `U_i` (`v_i`), so the dual behind the bound is feasible for this
//!   tick's primitives; what rounding leaves of infeasibility (a few ulps of `s_i`) is charged as a linear
//!   perturbation of the energy, `8 eps s_i / k` metres per primitive;
//! - two certificates are formed, B first; A only when B misses the tolerance (it never meets it with a
//!   primitive at its kink, where B is needed), and then the smaller is kept. **A** takes the gap at `x` with all `v_i`
//!   projected, each primitive's share computed without cancellation *plus* its own rounding error, so rounding
//!   only overstates it. **B** certifies a nearby exact point `x^`, which lies exactly on the kinks that `x` is
//!   within rounding of (the plane it rests on, the point it is held by): there those shares are exactly zero;
//!   primitives pulling with full strength off their kink take their exact subgradient at `x^`, whose share is
//!   exactly zero too; the rest keep their projected share plus what moving from `x` to `x^` can change it. What
//!   remains is the coupling residual `|k (x - y) + sum v_i|`, which bounds the distance linearly (`/k`),
//!   not through a square root, and `|x - x^|` counted twice.

use super::linalg::outer;
use super::{project, Item};
use crate::haptics::primitive::PrimitiveKind;
use glam::{DMat3, DVec3};

const EPS: f64 = f64::EPSILON;
/// A primitive is taken to be at its kink when `x` is within this many ulps (of the coordinates, of `y` and of
/// `sum s_i / k`, the scales of `x = y - U/k`) of it. Any threshold keeps the bound valid; this one is where
/// rounding alone can leave a converged point.
const KINK_ULPS: f64 = 16.0;
/// Relative eigenvalue threshold for the rank of the kinks' system.
const RANK_TOLERANCE: f64 = 1e-11;

/// A point and its certificate.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Certificate {
    /// Duality gap of the certificate that gave the bound (J); for certificate B, the gap at `x^`.
    pub gap_j: f64,
    /// The bound on `|x - x*|` (m).
    pub bound_m: f64,
    /// Whether the bound is certificate B's, whose dual gives saturated items their exact subgradient at `x`.
    pub by_kinks: bool,
}

/// The fixed data of one solve that the certificate needs besides the items.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame {
    pub y: DVec3,
    pub k: f64,
    /// An upper bound on the rounding of `y = probe + (sum of directed forces)/k` (m).
    pub y_error_m: f64,
    /// `sum s_i / k` over the items (m).
    pub strength_over_k_m: f64,
}

/// Neumaier's compensated sum of 3-vectors: the error is about 2 eps of the result plus n eps^2 of the sum of
/// magnitudes, instead of n eps of the sum of magnitudes. Each step's rounding error is computed exactly (by
/// Knuth's TwoSum, branch-free), so the sums, and the bounds built on them, are those of Neumaier's algorithm.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct CompensatedSum {
    sum: DVec3,
    compensation: DVec3,
}

/// A running sum of 3-vectors: [`CompensatedSum`] or [`PlainSum`] (the primal Newton passes pick one).
pub(crate) trait GradientSum: Default {
    fn add(&mut self, v: DVec3);
    fn value(&self) -> DVec3;
}

/// A plain running sum (error up to n eps of the sum of magnitudes).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PlainSum(DVec3);

impl GradientSum for PlainSum {
    #[inline]
    fn add(&mut self, v: DVec3) {
        self.0 += v;
    }

    #[inline]
    fn value(&self) -> DVec3 {
        self.0
    }
}

impl GradientSum for CompensatedSum {
    #[inline]
    fn add(&mut self, v: DVec3) {
        CompensatedSum::add(self, v);
    }

    #[inline]
    fn value(&self) -> DVec3 {
        CompensatedSum::value(self)
    }
}

impl CompensatedSum {
    #[inline]
    pub(crate) fn add(&mut self, v: DVec3) {
        // Knuth's TwoSum: `lost` is the rounding error of `t` exactly (as in Neumaier's branch on the larger
        // magnitude, which gives the same value), in six operations per coordinate and no comparison.
        let t = self.sum + v;
        let v_part = t - self.sum;
        let sum_part = t - v_part;
        let lost = (self.sum - sum_part) + (v - v_part);
        self.compensation += lost;
        self.sum = t;
    }

    pub(crate) fn value(&self) -> DVec3 {
        self.sum + self.compensation
    }
}

/// The distance from `x` to an item's kink set, with an upper bound on its rounding error.
#[inline]
fn kink_distance(item: &Item, r: DVec3) -> (f64, f64) {
    let rounding = 4.0 * EPS * r.length();
    match item.kind {
        PrimitiveKind::Point => (r.length(), rounding),
        PrimitiveKind::Line => {
            let q = item.direction;
            ((r - q * q.dot(r)).length(), rounding)
        }
        PrimitiveKind::Plane => (item.direction.dot(r).abs(), rounding),
        PrimitiveKind::Directed => (f64::INFINITY, 0.0),
    }
}

/// The exact subgradient of an off-kink item at `x` (as computed; its rounding is charged separately), if the
/// item pulls with full strength: the value its dual takes at the answer.
#[inline]
fn saturated_subgradient(item: &Item, r: DVec3, v: DVec3) -> Option<DVec3> {
    let s = item.strength_n;
    match item.kind {
        PrimitiveKind::Point | PrimitiveKind::Line => {
            if v.length() < (1.0 - 1e-6) * s {
                return None;
            }
            let q = item.direction;
            let perpendicular = if item.kind == PrimitiveKind::Line {
                r - q * q.dot(r)
            } else {
                r
            };
            Some(perpendicular.normalize_or_zero() * s)
        }
        PrimitiveKind::Plane => {
            let sigma = item.direction.dot(r);
            let t = -item.direction.dot(v);
            if sigma < 0.0 && t >= (1.0 - 1e-6) * s {
                Some(-s * item.direction)
            } else if sigma > 0.0 && t <= 1e-6 * s {
                Some(DVec3::ZERO)
            } else {
                None
            }
        }
        PrimitiveKind::Directed => None,
    }
}

/// `s dist(x, C) - v.(x - c)` for a ball or disc of radius `s` and `|v| <= s`, written as two non-negative
/// terms so that nothing cancels: `(s - |v|) |r| + (|v| |r| - v.r)`.
fn ball_share(s: f64, v: DVec3, r: DVec3) -> f64 {
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
fn projected_share(item: &Item, v: DVec3, r: DVec3) -> f64 {
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

/// The kinks of certificate B: how far `x` may be from the exact point `x^` on all of them.
struct Kinks {
    count: usize,
    /// Sum of upper bounds on the distances from `x` to each kink set.
    distance_sum_m: f64,
    /// Sum over the kinks of each set's codimension (point 3, line 2, plane 1).
    codimension: usize,
    /// A point among the kinks, if any: then `x^` can only be that point.
    point: Option<usize>,
    /// The kinks' indices, when there are at most [`LISTED_KINKS`] of them (the consistency checks then visit
    /// only these instead of every item).
    listed: [u32; LISTED_KINKS],
}

/// Kinks remembered by index in one certificate; beyond that the consistency checks scan every item.
const LISTED_KINKS: usize = 8;

impl Kinks {
    /// `sum P_i` and `sum P_i c_i` over the kinks (only the general case of [`kink_shift_m`] needs them).
    fn system(&self, items: &[Item], x: DVec3, scale: f64) -> (DMat3, DVec3) {
        let mut system = DMat3::ZERO;
        let mut rhs = DVec3::ZERO;
        let mut add = |item: &Item| {
            let projector = match item.kind {
                PrimitiveKind::Point => DMat3::IDENTITY,
                PrimitiveKind::Line => DMat3::IDENTITY - outer(item.direction, item.direction),
                _ => outer(item.direction, item.direction),
            };
            system += projector;
            rhs += projector * item.position_m;
        };
        if self.count <= LISTED_KINKS {
            for &i in &self.listed[..self.count] {
                add(&items[i as usize]);
            }
        } else {
            for item in items {
                let (d, _) = kink_distance(item, x - item.position_m);
                if item.strength_n != 0.0 && d <= kink_threshold_m(scale, item) {
                    add(item);
                }
            }
        }
        (system, rhs)
    }

    /// Whether every kink set passes within rounding of `point` (the kinks are those items within their
    /// threshold of `x`).
    fn all_pass_through(&self, items: &[Item], x: DVec3, point: DVec3, scale: f64) -> bool {
        let passes = |item: &Item| {
            let (at_point, rounding) = kink_distance(item, point - item.position_m);
            at_point <= kink_threshold_m(scale, item) + rounding
        };
        if self.count <= LISTED_KINKS {
            return self.listed[..self.count]
                .iter()
                .all(|&i| passes(&items[i as usize]));
        }
        items.iter().all(|item| {
            let (d, _) = kink_distance(item, x - item.position_m);
            item.strength_n == 0.0 || d > kink_threshold_m(scale, item) || passes(item)
        })
    }
}

/// Certifies the pair `(x, dual)`. `dual` may be anything (it is projected here); the result is a valid bound on
/// `|x - x*|` for the exact problem.
///
/// Certificate B is formed first; when it is at most `enough_m` it is returned as it is, and A (which needs a
/// second pass over the items) is not formed. Otherwise the smaller of the two is returned. Either way the
/// bound is valid; `enough_m` only decides how much work is spent making it small.
pub(crate) fn certify(
    items: &[Item],
    dual: &[DVec3],
    frame: &Frame,
    x: DVec3,
    enough_m: f64,
) -> Certificate {
    let Frame { y, k, .. } = *frame;
    let scale = x.abs().max_element() + y.abs().max_element() + frame.strength_over_k_m;
    let mut kinks = Kinks {
        count: 0,
        distance_sum_m: 0.0,
        codimension: 0,
        point: None,
        listed: [0; LISTED_KINKS],
    };
    // Certificate B: kinks zero, saturated items their subgradient, the rest projected.
    let mut shares_b = 0.0;
    let mut total_b = CompensatedSum::default();
    // B's shares grow by at most (s + |v|) |x - x^| for projected items: sum of s + |v| here.
    let mut moved_share_weight = 0.0;
    // B's subgradients move by at most 2 s |x - x^| / margin for points and lines: sum of 2 s / margin here,
    // and the smallest margin (distance to the kink less rounding) over items given their subgradient.
    let mut subgradient_sensitivity = 0.0;
    let mut smallest_margin_m = f64::INFINITY;
    let mut direction_rounding_n = 0.0;
    let mut strength_sum = 0.0;
    for (i, (item, &u)) in items.iter().zip(dual).enumerate() {
        let s = item.strength_n;
        if s == 0.0 {
            continue;
        }
        strength_sum += s;
        let v = project(item, u);
        let r = x - item.position_m;
        let (distance, rounding) = kink_distance(item, r);
        if distance <= kink_threshold_m(scale, item) {
            if kinks.count < LISTED_KINKS {
                kinks.listed[kinks.count] = i as u32;
            }
            kinks.count += 1;
            kinks.distance_sum_m += distance + rounding;
            kinks.codimension += match item.kind {
                PrimitiveKind::Point => {
                    kinks.point.get_or_insert(i);
                    3
                }
                PrimitiveKind::Line => 2,
                _ => 1,
            };
            total_b.add(v);
        } else if let Some(g) = saturated_subgradient(item, r, v) {
            let margin = distance - rounding;
            smallest_margin_m = smallest_margin_m.min(margin);
            if item.kind != PrimitiveKind::Plane {
                let inverse_margin = 1.0 / margin.max(f64::MIN_POSITIVE);
                subgradient_sensitivity += 2.0 * s * inverse_margin;
                // The direction of the computed offset is off by at most 2 rounding / margin.
                direction_rounding_n += 2.0 * s * rounding * inverse_margin;
            }
            total_b.add(g);
        } else {
            shares_b += projected_share(item, v, r);
            moved_share_weight += s + v.length();
            total_b.add(v);
        }
    }
    // Rounding of the dual values themselves, charged as a linear perturbation (module header): the projection
    // and the subgradients are exact to a few ulps of s.
    let dual_rounding_n = 8.0 * EPS * strength_sum;
    let n = items.len() as f64;
    // Every term of either sum (a projected dual or a subgradient) is at most s (1 + 4 eps) long, so twice the
    // strength sum bounds the sum of their magnitudes in the compensated sum's error.
    let magnitude_bound_n = 2.0 * strength_sum;
    let residual_bound = |total: &CompensatedSum| {
        let t = total.value();
        let coupling = k * (x - y);
        let residual = (coupling + t).length();
        residual * (1.0 + 8.0 * EPS)
            + 8.0 * EPS * (coupling.length() + t.length())
            + 4.0 * n * EPS * EPS * magnitude_bound_n
    };
    let linear_m = frame.y_error_m + dual_rounding_n / k;

    let mut best = Certificate {
        gap_j: f64::INFINITY,
        bound_m: f64::INFINITY,
        by_kinks: false,
    };
    if let Some(shift_m) = kink_shift_m(items, &kinks, x, scale) {
        if smallest_margin_m > 2.0 * shift_m {
            let shares = shares_b + moved_share_weight * shift_m;
            let residual = residual_bound(&total_b) + k * shift_m;
            let bound_b = 2.0 * shift_m
                + (2.0 * shares / k).sqrt()
                + residual / k
                + linear_m
                + (subgradient_sensitivity * shift_m + direction_rounding_n) / k;
            best = Certificate {
                gap_j: shares + residual * residual / (2.0 * k),
                bound_m: rounded_up(bound_b),
                by_kinks: true,
            };
        }
    }
    if best.bound_m <= enough_m {
        return best;
    }

    // Certificate A: all projected, at x.
    let mut shares_a = 0.0;
    let mut total_a = CompensatedSum::default();
    for (item, &u) in items.iter().zip(dual) {
        if item.strength_n == 0.0 {
            continue;
        }
        let v = project(item, u);
        shares_a += projected_share(item, v, x - item.position_m);
        total_a.add(v);
    }
    let residual_a = residual_bound(&total_a);
    let bound_a = rounded_up((2.0 * shares_a / k).sqrt() + residual_a / k + linear_m);
    if bound_a < best.bound_m || best.bound_m.is_nan() {
        best = Certificate {
            gap_j: shares_a + residual_a * residual_a / (2.0 * k),
            bound_m: bound_a,
            by_kinks: false,
        };
    }
    best
}

/// Below this distance from its kink set an item counts as on it (`scale` is `|x| + |y| + sum s_i / k`).
fn kink_threshold_m(scale: f64, item: &Item) -> f64 {
    KINK_ULPS * EPS * (scale + item.position_m.abs().max_element())
}

/// A bound computed from a few rounded operations, nudged up past their rounding.
fn rounded_up(bound: f64) -> f64 {
    bound * (1.0 + 16.0 * EPS)
}

/// An upper bound on `|x - x^|`, where `x^` is the exact point nearest `x` on all the kink sets, or `None` when
/// the kinks have no common point (within rounding) or are too degenerate to bound.
fn kink_shift_m(items: &[Item], kinks: &Kinks, x: DVec3, scale: f64) -> Option<f64> {
    match kinks.count {
        0 => return Some(0.0),
        1 => return Some(kinks.distance_sum_m),
        _ => {}
    }
    if let Some(p) = kinks.point {
        // x^ is that point: every other kink must pass through it (checked at the rounding threshold).
        let c = items[p].position_m;
        if !kinks.all_pass_through(items, x, c, scale) {
            return None;
        }
        let (d, rounding) = kink_distance(&items[p], x - c);
        return Some(d + rounding);
    }
    // One eigen-decomposition gives both the smallest positive eigenvalue and, when needed, the pseudo-inverse.
    let (system, rhs) = kinks.system(items, x, scale);
    let eigen = super::linalg::symmetric_eigen3(system);
    let max = eigen.values.max_element();
    let mut smallest_positive = f64::INFINITY;
    let mut rank = 0;
    for l in eigen.values.to_array() {
        if max > 0.0 && l > RANK_TOLERANCE * max {
            smallest_positive = smallest_positive.min(l);
            rank += 1;
        }
    }
    if !smallest_positive.is_finite() || rank == 0 {
        return None;
    }
    if kinks.codimension != rank {
        // Not transversal: the sets meet only if they happen to pass through a common point. Check that the
        // least-squares point lies on all of them to within rounding.
        let pinv = super::linalg::pseudo_inverse_from(&eigen, RANK_TOLERANCE);
        let x_hat = x + pinv * (rhs - system * x);
        if !kinks.all_pass_through(items, x, x_hat, scale) {
            return None;
        }
    }
    // |M^+ sum_i P_i r_i| <= sum_i |P_i r_i| / sqrt(lambda_min^+), since P_i <= M; with a margin for the
    // eigenvalue's own rounding.
    Some(kinks.distance_sum_m / (smallest_positive * (1.0 - 1e-9)).sqrt())
}
