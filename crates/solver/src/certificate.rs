//! The certificate of the exact solver: an upper bound on `|x - x*|`, the distance from a returned proxy
//! position to the true minimiser, that holds whatever dual values it is given and whatever rounding did.
//!
//! It sits at the end of every solve ([`super::Solver`]): every exit (certified, budget exhausted before or
//! after a sweep, stalled, no primitives) returns a point together with a bound from [`certify`]. The argument
//! is written out in docs/solver.md ("Why the bound never lies"); this file implements it.
//!
//! In short, for the floating-point point `x` and dual values `u_i` (any values, feasible or not):
//!
//! - every `u_i` is first projected onto its set `U_i` (`v_i`), so the dual behind the bound is feasible for this
//!   tick's primitives; what rounding leaves of infeasibility (a few ulps of `s_i`) is charged as a linear
//!   perturbation of the energy, `8 eps s_i / k` metres per primitive;
//! - two certificates are formed, B first (a second time with a balancing dual when it misses the tolerance,
//!   unless `SolverConfig::rebalance_certificate` is off); A only when B misses the tolerance, and then the
//!   smaller is kept.
//!   **B** certifies a nearby exact point `x^`, which lies exactly on the kinks that `x` is within rounding of
//!   (the plane it rests on, the line it is held by): there those shares are exactly zero; primitives pulling
//!   with full strength off their kink take their exact subgradient at `x^`, whose share is exactly zero too;
//!   the rest keep their projected share plus what moving from `x` to `x^` can change it. What remains is the
//!   coupling residual `|k (x - y) + sum v_i|`, which bounds the distance linearly (`/k`), not through a square
//!   root, and `|x - x^|` counted twice. `x^` must exist, so B takes only kinks whose sets certainly meet:
//!   transversal ones, or ones that meet exactly by construction ([`kink_set_contains`]).
//! - **A** takes the gap at `x` with all `v_i` projected, each primitive's share computed without cancellation
//!   *plus* its own rounding error, so rounding only overstates it, and the kinks' *sharpness*: a kink whose
//!   dual lies strictly inside its set holds the proxy like a spring with no give, and turns the square root of
//!   the shares into a linear bound ([`sharp_distance_m`]; the argument is in docs/solver.md, "Certificate A"). A
//!   needs no common point of the kinks, so it certifies what B must refuse: a proxy stuck on a friction point
//!   that lies only within rounding of a tilted plane.

use crate::certificate_terms::{
    codimension, dual_margin, eigenvalue_error, kink_distance, kink_set_contains, normal_projector,
    projected_share,
};
use crate::item::{project, Item};
use crate::math::sqrt;
use crate::primitive::PrimitiveKind;
use crate::sum::CompensatedSum;
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
    /// Form certificate B a second time with a balancing dual when it misses the tolerance
    /// ([`SolverConfig::rebalance_certificate`](crate::SolverConfig::rebalance_certificate)).
    pub rebalance: bool,
}

/// What certificate B's first loop sees of one item at `x`: on its kink, pulling with full strength off it
/// (with its exact subgradient), or neither.
enum Look {
    /// Within [`kink_threshold_m`] of its kink set: `distance` and its rounding bound, as [`kink_distance`].
    Kink { distance: f64, rounding: f64 },
    /// Off its kink and pulling with full strength: `g` its exact subgradient at `x` (as computed; its rounding
    /// is charged separately), `margin` its distance to the kink less rounding, `rounding` the distance's
    /// rounding bound; `curved` for a point or line, whose subgradient turns as `x` moves.
    Saturated {
        g: DVec3,
        margin: f64,
        rounding: f64,
        curved: bool,
    },
    /// Neither: its dual is projected and its share of the gap computed.
    Projected,
}

/// One item's [`Look`] at `x` (`r = x - c`), with one `match` on its kind: its [`kink_distance`], then, off the
/// kink, whether it pulls with full strength. `u` is the dual as given, unprojected: the test reads the
/// projection's length (or a plane's magnitude) from it without forming the projection, whose square root and
/// division only the other branches of [`certify`] need (`|proj u|^2 = min(|P u|^2, s^2)` for a ball or disc, `P`
/// the projector across a line; a plane's clamped magnitude passes or fails both tests as its unclamped one
/// does). A point's or line's subgradient is its offset scaled by `s / distance`: the offset's length is
/// `distance`, computed the same way, so this is length `s` to a few ulps (charged with the dual rounding), one
/// division instead of a normalisation.
#[inline]
fn look(item: &Item, r: DVec3, u: DVec3, threshold_m: f64) -> Look {
    let s = item.strength_n;
    match item.kind {
        PrimitiveKind::Point => {
            let distance = r.length();
            let rounding = 4.0 * EPS * distance;
            look_curved(s, r, distance, rounding, threshold_m, || u)
        }
        PrimitiveKind::Line => {
            let q = item.direction;
            let perpendicular = r - q * q.dot(r);
            let distance = perpendicular.length();
            let rounding = 4.0 * EPS * r.abs().element_sum();
            look_curved(s, perpendicular, distance, rounding, threshold_m, || {
                u - q * q.dot(u)
            })
        }
        PrimitiveKind::Plane => {
            let q = item.direction;
            let sigma = q.dot(r);
            let distance = sigma.abs();
            let rounding = 4.0 * EPS * r.abs().element_sum();
            let t = -q.dot(u);
            let g = if distance <= threshold_m {
                return Look::Kink { distance, rounding };
            } else if sigma < 0.0 && t >= (1.0 - 1e-6) * s {
                -s * q
            } else if sigma > 0.0 && t <= 1e-6 * s {
                DVec3::ZERO
            } else {
                return Look::Projected;
            };
            Look::Saturated {
                g,
                margin: distance - rounding,
                rounding,
                curved: false,
            }
        }
        // Not among the items (directed forces are folded into `y`); as a kinkless item, projected to zero.
        PrimitiveKind::Directed => Look::Projected,
    }
}

/// [`look`] for a point or a line of strength `s`: `offset` is `r` across its kink set (for a point, `r`),
/// `distance` its length and `rounding` that length's rounding bound; `u_across` the part of `u` in the span of
/// its dual set (for a point, `u`), formed only off the kink.
#[inline(always)]
fn look_curved(
    s: f64,
    offset: DVec3,
    distance: f64,
    rounding: f64,
    threshold_m: f64,
    u_across: impl FnOnce() -> DVec3,
) -> Look {
    if distance <= threshold_m {
        Look::Kink { distance, rounding }
    } else if u_across().length_squared() < (1.0 - 2e-6) * s * s {
        Look::Projected
    } else {
        Look::Saturated {
            g: offset * (s / distance),
            margin: distance - rounding,
            rounding,
            curved: true,
        }
    }
}

/// The kinks: the items `x` is within [`kink_threshold_m`] of. Certificate B moves to an exact point `x^` on
/// all of them; certificate A uses their sharpness.
struct Kinks {
    count: usize,
    /// Sum of upper bounds on the distances from `x` to each kink set.
    distance_sum_m: f64,
    /// Sum over the kinks of each set's codimension (point 3, line 2, plane 1).
    codimension: usize,
    /// Whether a point is among the kinks.
    point: bool,
    /// The kinks' indices, when there are at most [`LISTED_KINKS`] of them (the later passes then visit only
    /// these instead of every item).
    listed: [u32; LISTED_KINKS],
}

/// Kinks remembered by index in one certificate; beyond that the later passes scan every item.
const LISTED_KINKS: usize = 8;

impl Kinks {
    /// The codimension of the kinks' intersection if they are transversal once every kink set that exactly
    /// contains another is left out (it adds no constraint), and whether a point remains among them. Beyond
    /// [`LISTED_KINKS`] no set is left out.
    fn distinct(&self, items: &[Item]) -> (usize, bool) {
        if self.count > LISTED_KINKS {
            return (self.codimension, self.point);
        }
        let listed = &self.listed[..self.count];
        let mut codim = 0;
        let mut point = false;
        for (a, &i) in listed.iter().enumerate() {
            let big = &items[i as usize];
            // Left out if it contains another kink set; of two equal sets, the later one.
            let redundant = listed.iter().enumerate().any(|(b, &j)| {
                let small = &items[j as usize];
                b != a && kink_set_contains(big, small) && (b < a || !kink_set_contains(small, big))
            });
            if !redundant {
                codim += codimension(big);
                point |= big.kind == PrimitiveKind::Point;
            }
        }
        // Two lines in one coordinate plane that are not parallel cross at a point: their intersection has
        // codimension 3, not 4.
        if let [i, j] = listed {
            let (a, b) = (&items[*i as usize], &items[*j as usize]);
            if a.kind == PrimitiveKind::Line
                && b.kind == PrimitiveKind::Line
                && codim == 4
                // Not parallel, by far more than rounding (the rank test of the caller confirms it).
                && a.direction.cross(b.direction).length() > 1e-8
                && (0..3).any(|c| {
                    a.direction[c] == 0.0
                        && b.direction[c] == 0.0
                        && a.position_m[c] == b.position_m[c]
                })
            {
                codim = 3;
            }
        }
        (codim, point)
    }

    /// Calls `f` with the index of every kink.
    fn for_each(&self, items: &[Item], x: DVec3, scale: f64, mut f: impl FnMut(usize)) {
        if self.count <= LISTED_KINKS {
            for &i in &self.listed[..self.count] {
                f(i as usize);
            }
        } else {
            for (i, item) in items.iter().enumerate() {
                let (d, _) = kink_distance(item, x - item.position_m);
                if item.strength_n != 0.0 && d <= kink_threshold_m(scale, item) {
                    f(i);
                }
            }
        }
    }

    /// `sum P_i` over the kinks, `P_i` the projector onto the normal space of kink set `i` (only the general
    /// case of [`kink_shift_m`] needs it).
    fn system(&self, items: &[Item], x: DVec3, scale: f64) -> DMat3 {
        let mut system = DMat3::ZERO;
        self.for_each(items, x, scale, |i| system += normal_projector(&items[i]));
        system
    }

    /// Certificate A's sharpness at `x`: `(lambda, slack)` such that, for every `z`, the kinks' shares at `z`
    /// add up to at least `lambda |z - x| - slack` (docs/solver.md, "Certificate A"). Each kink contributes its
    /// margin `m_i`, how far its projected dual lies inside its set: `lambda` is a lower bound on the smallest
    /// eigenvalue of `sum m_i P_i`, and `slack` bounds `sum m_i dist(x, kink set i)`.
    fn sharpness(&self, items: &[Item], dual: &[DVec3], x: DVec3, scale: f64) -> (f64, f64) {
        let mut weighted = DMat3::ZERO;
        let mut point_margins = 0.0;
        let mut slack = 0.0;
        let mut rank = 0;
        self.for_each(items, x, scale, |i| {
            let item = &items[i];
            let margin = dual_margin(item, project(item, dual[i]));
            if margin <= 0.0 {
                return;
            }
            let (distance, rounding) = kink_distance(item, x - item.position_m);
            slack += margin * (distance + rounding);
            match item.kind {
                PrimitiveKind::Point => {
                    point_margins += margin;
                    rank += 3;
                }
                PrimitiveKind::Line => rank += 2,
                _ => rank += 1,
            }
            weighted += normal_projector(item) * margin;
        });
        // Every point adds its margin times the identity, and the other terms are positive semi-definite.
        let mut lambda = point_margins;
        if point_margins == 0.0 && rank >= 3 {
            let eigen = super::linalg::symmetric_eigen3(weighted);
            let smallest = eigen.values.min_element();
            lambda = lambda.max(smallest - eigenvalue_error(weighted, self.count));
        }
        (lambda.max(0.0), slack * (1.0 + 16.0 * EPS))
    }
}

/// Certificate B's first loop over the items at `x`: kinks found, saturated items given their exact
/// subgradient, the rest projected and their shares summed.
struct BPass {
    kinks: Kinks,
    shares: f64,
    total: CompensatedSum,
    /// B's shares grow by at most (s + |v|) |x - x^| for projected items: sum of s + |v| here.
    moved_share_weight: f64,
    /// B's subgradients move by at most 2 s |x - x^| / margin for points and lines: sum of 2 s / margin here.
    subgradient_sensitivity: f64,
    /// The smallest margin (distance to the kink less rounding) over items given their subgradient.
    smallest_margin_m: f64,
    direction_rounding_n: f64,
    strength_sum: f64,
    /// The point or line given its subgradient nearest its kink, and that subgradient.
    nearest_curved: Option<(usize, DVec3)>,
    /// The balanced item's share at `x^` exceeds its share at `x` by at most `first_order |x - x^| + curvature
    /// |x - x^|^2` while `|x - x^|` is at most half its margin: its share's gradient at `x` is `s r/|r| - v`, and
    /// its Hessian is at most `s / |w|` for `|w| >= margin / 2` along the way.
    balanced_first_order_n: f64,
    balanced_curvature_n_per_m: f64,
}

/// [`BPass`] over the items; `balanced` (an index and a value) gives that item, a point or line pulling with full
/// strength, that value projected onto its set instead of its subgradient, with its share counted and its
/// growth on the way to `x^` bounded ([`BPass::balanced_first_order_n`]). Writes the values used to `b_dual`
/// when given.
fn b_pass(
    items: &[Item],
    dual: &[DVec3],
    x: DVec3,
    scale: f64,
    balanced: Option<(usize, DVec3)>,
    mut b_dual: Option<&mut [DVec3]>,
) -> BPass {
    let mut pass = BPass {
        kinks: Kinks {
            count: 0,
            distance_sum_m: 0.0,
            codimension: 0,
            point: false,
            listed: [0; LISTED_KINKS],
        },
        shares: 0.0,
        total: CompensatedSum::default(),
        moved_share_weight: 0.0,
        subgradient_sensitivity: 0.0,
        smallest_margin_m: f64::INFINITY,
        direction_rounding_n: 0.0,
        strength_sum: 0.0,
        nearest_curved: None,
        balanced_first_order_n: 0.0,
        balanced_curvature_n_per_m: 0.0,
    };
    let mut nearest_margin = f64::INFINITY;
    let kinks = &mut pass.kinks;
    for (i, (item, &u)) in items.iter().zip(dual).enumerate() {
        let s = item.strength_n;
        if s == 0.0 {
            if let Some(out) = b_dual.as_deref_mut() {
                out[i] = DVec3::ZERO;
            }
            continue;
        }
        pass.strength_sum += s;
        let r = x - item.position_m;
        let look = look(item, r, u, kink_threshold_m(scale, item));
        if let (
            Some((j, balancing)),
            Look::Saturated {
                g,
                margin,
                rounding,
                curved: true,
            },
        ) = (balanced, &look)
        {
            if j == i {
                let v = project(item, balancing);
                pass.shares += projected_share(item, v, r);
                pass.smallest_margin_m = pass.smallest_margin_m.min(*margin);
                let inverse_margin = 1.0 / margin.max(f64::MIN_POSITIVE);
                // |s r/|r| - v| <= |g - v| (rounded up) + how far the computed g's direction can be off.
                pass.balanced_first_order_n += (*g - v).length() * (1.0 + 8.0 * EPS)
                    + 8.0 * EPS * (s + v.length())
                    + 2.0 * s * rounding * inverse_margin;
                pass.balanced_curvature_n_per_m += s * inverse_margin;
                pass.total.add(v);
                if let Some(out) = b_dual.as_deref_mut() {
                    out[i] = v;
                }
                continue;
            }
        }
        let used = match look {
            Look::Kink { distance, rounding } => {
                let v = project(item, u);
                if kinks.count < LISTED_KINKS {
                    kinks.listed[kinks.count] = i as u32;
                }
                kinks.count += 1;
                kinks.distance_sum_m += distance + rounding;
                kinks.codimension += codimension(item);
                kinks.point |= item.kind == PrimitiveKind::Point;
                v
            }
            Look::Saturated {
                g,
                margin,
                rounding,
                curved,
            } => {
                pass.smallest_margin_m = pass.smallest_margin_m.min(margin);
                if curved {
                    let inverse_margin = 1.0 / margin.max(f64::MIN_POSITIVE);
                    pass.subgradient_sensitivity += 2.0 * s * inverse_margin;
                    // The direction of the computed offset is off by at most 2 rounding / margin.
                    pass.direction_rounding_n += 2.0 * s * rounding * inverse_margin;
                    if margin < nearest_margin {
                        nearest_margin = margin;
                        pass.nearest_curved = Some((i, g));
                    }
                }
                g
            }
            Look::Projected => {
                let v = project(item, u);
                pass.shares += projected_share(item, v, r);
                pass.moved_share_weight += s + v.length();
                v
            }
        };
        pass.total.add(used);
        if let Some(out) = b_dual.as_deref_mut() {
            out[i] = used;
        }
    }
    pass
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
    certify_into(items, dual, frame, x, enough_m, None)
}

/// [`certify`], also writing certificate B's dual (the projected values, and the saturated items' subgradients)
/// to `b_dual` (one entry per item) when given: the dual the bound is about when `by_kinks` is set, for a caller
/// that adopts it without computing the subgradients again.
pub(crate) fn certify_into(
    items: &[Item],
    dual: &[DVec3],
    frame: &Frame,
    x: DVec3,
    enough_m: f64,
    mut b_dual: Option<&mut [DVec3]>,
) -> Certificate {
    let Frame { y, k, .. } = *frame;
    let scale = x.abs().max_element() + y.abs().max_element() + frame.strength_over_k_m;
    let pass = b_pass(items, dual, x, scale, None, b_dual.as_deref_mut());
    let n = items.len() as f64;
    // Every term of either sum (a projected dual or a subgradient) is at most s (1 + 4 eps) long, so twice the
    // strength sum bounds the sum of their magnitudes in the compensated sum's error.
    let magnitude_bound_n = 2.0 * pass.strength_sum;
    let residual_bound = |total: &CompensatedSum| {
        let t = total.value();
        let coupling = k * (x - y);
        let residual = (coupling + t).length();
        // The 1-norms bound the lengths from above (no square roots needed for a rounding term).
        residual * (1.0 + 8.0 * EPS)
            + 8.0 * EPS * (coupling.abs().element_sum() + t.abs().element_sum())
            + 4.0 * n * EPS * EPS * magnitude_bound_n
    };
    // Rounding of the dual values themselves, charged as a linear perturbation (docs/solver.md, 2 (a)): the
    // projection and the subgradients are exact to a few ulps of s.
    let dual_rounding_n = 8.0 * EPS * pass.strength_sum;
    let linear_m = frame.y_error_m + dual_rounding_n / k;
    let kinks = &pass.kinks;
    let shift = kink_shift_m(items, kinks, x, scale);
    let certificate_b = |pass: &BPass| {
        let shift_m = shift?;
        if pass.smallest_margin_m <= 2.0 * shift_m {
            return None;
        }
        // A sum of n non-negative terms is rounded by at most n eps of itself.
        let shares = pass.shares * (1.0 + (n + 2.0) * EPS)
            + (pass.moved_share_weight + pass.balanced_first_order_n) * shift_m
            + pass.balanced_curvature_n_per_m * shift_m * shift_m;
        let residual = residual_bound(&pass.total) + k * shift_m;
        let bound_b = 2.0 * shift_m
            + sqrt(2.0 * shares / k)
            + residual / k
            + linear_m
            + (pass.subgradient_sensitivity * shift_m + pass.direction_rounding_n) / k;
        Some(Certificate {
            gap_j: shares + residual * residual / (2.0 * k),
            bound_m: rounded_up(bound_b),
            by_kinks: true,
        })
    };
    let mut best = certificate_b(&pass).unwrap_or(Certificate {
        gap_j: f64::INFINITY,
        bound_m: f64::INFINITY,
        by_kinks: false,
    });
    // A point or line pulling with full strength from very near its kink turns its subgradient fast as `x`
    // moves to `x^` (`2 s / margin` per metre): a friction point 0.3 nm behind a proxy that slides along a
    // plane costs B about 1e-11 m that way. Its share is second order in that turn, though, so B is formed
    // once more with that item's dual chosen to balance the coupling (projected onto its set) and its share
    // counted like any projected item's; the smaller bound is kept. Both are B's argument, for two duals.
    if best.bound_m > enough_m && frame.rebalance {
        if let Some((j, g)) = pass.nearest_curved {
            let others = pass.total.value() - g;
            let balancing = project(&items[j], -(k * (x - y) + others));
            let again = b_pass(items, dual, x, scale, Some((j, balancing)), None);
            if let Some(balanced) = certificate_b(&again) {
                if balanced.bound_m < best.bound_m {
                    best = balanced;
                    if let Some(out) = b_dual {
                        out[j] = balancing;
                    }
                }
            }
        }
    }
    if best.bound_m <= enough_m {
        return best;
    }

    // Certificate A: all projected, at x, with the kinks' sharpness.
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
    // A sum of n non-negative terms is rounded by at most n eps of itself.
    shares_a *= 1.0 + (n + 2.0) * EPS;
    let residual_a = residual_bound(&total_a);
    let (sharpness, slack) = if kinks.count > 0 {
        kinks.sharpness(items, dual, x, scale)
    } else {
        (0.0, 0.0)
    };
    // The kinks' sharpness, or a point's own (whichever bounds tighter; both are valid).
    let distance_a = sharp_distance_m(k, sharpness, residual_a, shares_a + slack).min(
        point_sharpness_distance_m(items, dual, kinks, x, scale, k, residual_a, shares_a),
    );
    let bound_a = rounded_up(distance_a + linear_m);
    if bound_a < best.bound_m || best.bound_m.is_nan() {
        best = Certificate {
            gap_j: shares_a + residual_a * residual_a / (2.0 * k),
            bound_m: bound_a,
            by_kinks: false,
        };
    }
    best
}

/// A plane or a line among the kinks, as a partner of a point in [`point_sharpness_distance_m`]: its share is
/// at least `margin |P (z - x)| - slack` (docs/solver.md, "Certificate A").
#[derive(Debug, Clone, Copy, Default)]
struct Partner {
    line: bool,
    direction: DVec3,
    margin_n: f64,
    slack_j: f64,
}

/// Certificate A's distance with a point's own sharpness (docs/solver.md, "Certificate A"): the
/// smallest over the point items, alone or with one plane or line among the kinks, of the largest `d` with
/// `k d^2 + (lambda - residual) d <= shares + slack`.
///
/// For a point at `c` with projected dual `v`, at `w = z - x` its share is `s |w + e| - v.(w + e)` with
/// `e = x - c`, at least `s |w| - v.w - (s + |v|) |e|`; a plane kink with margin `m` adds at least
/// `m |q.w| - slack` (a line, `m |P w| - slack`). Their sum is the support function of `K = B(-v, s) + Z`,
/// `Z` the segment `{t q : |t| <= m}` (the line's disc of radius `m` across it; `{0}` alone), which is at
/// least `lambda |w|` for `lambda = s - dist(v, Z)`: the ball of that radius lies in `K`. A saturated point
/// (`|v| = s`) has no margin of its own, yet with a plane pushing with room to spare it is sharp unless it
/// pulls along the plane. A proxy resting on a tilted plane, held by a friction point 5.6e-17 m in front of it
/// with 18 % of its strength to spare (so the minimiser is on the plane 1e-16 m from the point, which pulls with
/// all of its strength) is certified at 2.5e-15 m this way, where the kinks' sharpness alone gives 2.8e-10 m (a
/// case in the friction property test's regression file). The point need not be among
/// the kinks; its offset `|e|` enters the slack.
#[allow(clippy::too_many_arguments)]
fn point_sharpness_distance_m(
    items: &[Item],
    dual: &[DVec3],
    kinks: &Kinks,
    x: DVec3,
    scale: f64,
    k: f64,
    residual_n: f64,
    shares_j: f64,
) -> f64 {
    let mut partners = [Partner::default(); LISTED_KINKS];
    let mut count = 0;
    if kinks.count > 0 {
        kinks.for_each(items, x, scale, |j| {
            let item = &items[j];
            if item.kind == PrimitiveKind::Point || count == LISTED_KINKS {
                return;
            }
            let margin_n = dual_margin(item, project(item, dual[j]));
            // A NaN margin is left out too: `clamp` below needs a number.
            if margin_n.is_nan() || margin_n <= 0.0 {
                return;
            }
            let (distance, rounding) = kink_distance(item, x - item.position_m);
            partners[count] = Partner {
                line: item.kind == PrimitiveKind::Line,
                direction: item.direction,
                margin_n,
                slack_j: margin_n * (distance + rounding) * (1.0 + 4.0 * EPS),
            };
            count += 1;
        });
    }
    let mut best = f64::INFINITY;
    for (item, &u) in items.iter().zip(dual) {
        if item.kind != PrimitiveKind::Point || item.strength_n == 0.0 {
            continue;
        }
        let s = item.strength_n;
        let v = project(item, u);
        // (s + |v|) |e| <= 2 s (1 + 4 eps) |e|, and the computed |e| is within 4 eps of itself.
        let own_slack_j = 2.0 * s * (x - item.position_m).length() * (1.0 + 16.0 * EPS);
        let distance = |lambda_n: f64, partner_slack_j: f64| {
            // Three non-negative terms: their sum rounds by at most 2 eps of itself.
            let slack_j = (shares_j + own_slack_j + partner_slack_j) * (1.0 + 4.0 * EPS);
            sharp_distance_m(k, lambda_n, residual_n, slack_j)
        };
        // Alone: `Z = {0}`, lambda = s - |v|, which is the point's margin.
        best = best.min(distance(dual_margin(item, v), 0.0));
        for partner in &partners[..count] {
            best = best.min(distance(point_lambda_n(s, v, partner), partner.slack_j));
        }
    }
    best
}

/// A lower bound on `s - dist(v, Z)`, `Z` the partner's segment `{t q : |t| <= m}` or, for a line, its disc of
/// radius `m` across the line. The distance is measured to a point of `Z` (as computed, so within a few ulps of
/// `|v| + m` of it), which can only overstate it; that rounding and the few ulps of `s` by which `v` may lie
/// off its ball (docs/solver.md, "Why the bound never lies", 2 (a)) are taken off.
fn point_lambda_n(s: f64, v: DVec3, partner: &Partner) -> f64 {
    let q = partner.direction;
    let m = partner.margin_n;
    let nearest = if partner.line {
        let across = v - q * q.dot(v);
        let length = across.length();
        if length > m {
            across * (m / length)
        } else {
            across
        }
    } else {
        q * q.dot(v).clamp(-m, m)
    };
    let distance = (v - nearest).length() * (1.0 + 4.0 * EPS) + 8.0 * EPS * (v.length() + m);
    (s - distance) * (1.0 - 4.0 * EPS) - 8.0 * EPS * s
}

/// The largest `d >= 0` with `k d^2 + (sharpness - residual) d <= shares` (docs/solver.md, "Certificate A"), from
/// the root's two forms that add only non-negative terms; the caller adds its rounding.
fn sharp_distance_m(k: f64, sharpness_n: f64, residual_n: f64, shares_j: f64) -> f64 {
    // A lower bound on sharpness - residual: d grows as it falls, so rounding it down only overstates d.
    let beta = (sharpness_n - residual_n) - 2.0 * EPS * (sharpness_n + residual_n);
    let root = sqrt(beta * beta + 4.0 * k * shares_j);
    if beta > 0.0 {
        2.0 * shares_j / (beta + root)
    } else {
        (root - beta) / (2.0 * k)
    }
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
/// the kink sets are not certain to meet (not transversal, and not meeting exactly by construction) or are too
/// degenerate to bound.
fn kink_shift_m(items: &[Item], kinks: &Kinks, x: DVec3, scale: f64) -> Option<f64> {
    match kinks.count {
        0 => return Some(0.0),
        1 => return Some(kinks.distance_sum_m),
        _ => {}
    }
    let (codimension, point) = kinks.distinct(items);
    if point {
        // Every other kink set exactly contains the point: `x^` is the point. A point with any other kink is not
        // transversal (docs/solver.md, "Certificate B"), and left to certificate A's sharpness.
        return (codimension == 3).then_some(kinks.distance_sum_m);
    }
    // One eigen-decomposition gives both the smallest positive eigenvalue and, when needed, the pseudo-inverse.
    let system = kinks.system(items, x, scale);
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
    if codimension != rank {
        // Not transversal: the sets meet only if they pass through a common point, which floating point
        // cannot confirm. Left to certificate A, whose sharpness needs no common point (docs/solver.md).
        return None;
    }
    // |M^+ sum_i P_i r_i| <= sum_i |P_i r_i| / sqrt(lambda_min^+), since P_i <= M; less what rounding can
    // have added to the eigenvalue.
    let lower = smallest_positive - eigenvalue_error(system, kinks.count);
    (lower > 0.0).then(|| kinks.distance_sum_m / sqrt(lower))
}
