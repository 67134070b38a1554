//! The active-set finish of the exact solver (docs/solver.md, "The maths": "Active-set finish").
//!
//! Plain dual sweeps converge slowly when constraints are nearly parallel (a 1 degree wedge of planes behaves like
//! alternating projections). This step guesses the answer's combinatorial structure instead and solves for it:
//!
//! 1. Give every primitive a status from the current primal/dual pair: a point or line is at its kink or off it; a
//!    plane is off (not pushing), on (the proxy lies on it, pushing with some force in `[0, s]`) or full (pushing
//!    with all of `s`). Zero-strength primitives are inactive.
//! 2. The kinks define an affine set `{x : P_i (x - x_i) = 0}` with `P_i` = I (point), `I - q q^T` (line) or
//!    `q q^T` (plane on). Project onto it (least squares through the pseudo-inverse of `M = sum P_i`).
//! 3. Minimise the smooth model (coupling, off points and lines as distances, full planes as linear terms) on that
//!    set with Newton steps restricted to the null space of `M` (x is in R^3, so a 3x3 solve), with Armijo
//!    backtracking. A step that would carry an off primitive across its kink, or a full plane out of its
//!    half-space, is a primal violation: the step stops where the first one is crossed, that primitive joins
//!    the kinks, and the round goes on (a classical primal active-set step; flipping every violation at once
//!    makes the kink set inconsistent in crowded scenes).
//! 4. Recover the kink multipliers by least squares, `u_i = P_i M^+ (-g)` (the minimum-norm split of the force the
//!    kinks must supply). A multiplier outside its bound is a dual violation: the worst one flips (point/line off,
//!    plane off or full) and the round restarts.
//!
//! On success the caller gets the point and a feasible dual, and accepts them only if the duality gap certifies
//! them (the guess can be wrong; the verification is not optional). Everything is allocation-free once the
//! workspace has grown to the scene size.

use super::certificate::Frame;
use super::linalg::{outer, psd_pseudo_inverse};
use crate::item::{multiplier_excess, project, Item};
use crate::primitive::PrimitiveKind;
use crate::storage::{Buffer, Storage};
use glam::{DMat3, DVec3};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum Status {
    /// Zero strength: exerts nothing.
    #[default]
    Inactive,
    /// At the kink: on the point, on the line, or on the plane with a force in `[0, s]`.
    Kink,
    /// Off the kink: a point or line pulling with all of `s`, or a plane not pushing.
    Off,
    /// A plane pushing with all of `s` (the proxy is behind it).
    Full,
    /// A guessed kink not yet checked against the others (only inside `keep_consistent_kinks`).
    Candidate,
}

/// Per-primitive statuses, kept between solves so that no allocation happens on the servo path.
#[derive(Debug, Clone)]
pub(crate) struct Workspace<S: Storage> {
    status: S::Buf<Status>,
    /// Dual flips of each primitive in the current attempt (cycle guard).
    flips: S::Buf<u8>,
}

/// Relative tolerance when deciding a dual variable is strictly inside its bound.
const STATUS_SLACK: f64 = 1e-9;
/// Relative eigenvalue threshold for the rank of `M`.
const RANK_TOLERANCE: f64 = 1e-11;
const MAX_NEWTON_STEPS: usize = 40;
const MAX_SPLIT_SWEEPS: usize = 64;
/// Guessed kinks tried, nearest first, before the rest are labelled by side.
const MAX_KINK_CANDIDATES: usize = 12;
/// Dual flips one primitive may make in one attempt before the attempt is abandoned as cycling.
const MAX_FLIPS_PER_PRIMITIVE: u8 = 2;

impl<S: Storage> Workspace<S> {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            status: Buffer::with_capacity(n),
            flips: Buffer::with_capacity(n),
        }
    }

    /// One active-set attempt from `x_start` (of the coupling `frame.k` to `frame.y`). On success writes a
    /// feasible dual into `dual` and returns the point.
    pub fn solve(
        &mut self,
        items: &[Item],
        frame: &Frame,
        x_start: DVec3,
        max_flips: u32,
        dual: &mut [DVec3],
    ) -> Option<DVec3> {
        let Frame { y, k, .. } = *frame;
        self.flips.clear();
        self.flips.resize(items.len(), 0);
        self.status.clear();
        self.status.extend_iter(
            items
                .iter()
                .zip(dual.iter())
                .map(|(item, &u)| guess_status(item, x_start, u)),
        );
        let mut x = x_start;
        let scale = 1.0 + x.abs().max_element() + y.abs().max_element();
        let strength_sum: f64 = items.iter().map(|item| item.strength_n).sum();
        // Below this the gradient is rounding noise: 8 ulps of its largest contributions.
        let gradient_floor = 8.0 * f64::EPSILON * (k * scale + strength_sum);
        self.keep_consistent_kinks(items, x, scale);
        for flip in 0..=max_flips {
            // 2. The affine set of the kinks.
            let (m, b) = self.kink_system(items);
            let (pinv, null, rank) = psd_pseudo_inverse(m, RANK_TOLERANCE);
            if rank > 0 {
                x += pinv * (b - m * x);
            }
            let consistent = items.iter().zip(self.status.iter()).all(|(item, status)| {
                *status != Status::Kink
                    || (kink_projector(item) * (x - item.position_m)).length() <= 1e-12 * scale
            });
            if !consistent {
                return None;
            }
            if flip == 0 {
                // Afterwards the labels stay true by construction: steps stop at plane crossings, and a plane
                // released from its kink is labelled by the way its multiplier says it goes.
                self.match_plane_sides(items, x, 8.0 * f64::EPSILON * scale);
            }

            // 3. Newton on the smooth model, restricted to the affine set; a step stops at the first kink it
            //    would cross, and that primitive joins the kinks.
            let mut blocked = false;
            let mut previous_gradient = f64::INFINITY;
            let mut slow_steps = 0;
            let (mut g, mut h) = self.smooth_model(items, y, k, x);
            for _ in 0..MAX_NEWTON_STEPS {
                let gradient = (null * g).length();
                // Newton converges quadratically near the answer: three steps in a row that do not halve the
                // gradient mean it has stalled (rounding, or a distance term nearly at its kink). Stop there and
                // let the multiplier check and the certificate judge the point.
                slow_steps = if gradient > 0.5 * previous_gradient {
                    slow_steps + 1
                } else {
                    0
                };
                if gradient <= gradient_floor || slow_steps >= 3 {
                    break;
                }
                previous_gradient = gradient;
                let reduced = null * h * null + (DMat3::IDENTITY - null);
                let d = -(reduced.inverse() * (null * g));
                if !d.is_finite() {
                    return None;
                }
                if d.length() <= 4.0 * f64::EPSILON * scale {
                    break;
                }
                if let Some((i, tau)) = self.first_crossing(items, x, d) {
                    x += tau * d;
                    self.status[i] = Status::Kink;
                    blocked = true;
                    break;
                }
                // Take the full Newton step when it reduces the gradient (cheap, and immune to the energy's
                // rounding near the answer); otherwise backtrack on the energy (Armijo).
                let (g_full, h_full) = self.smooth_model(items, y, k, x + d);
                if (null * g_full).length() < gradient {
                    x += d;
                    (g, h) = (g_full, h_full);
                    continue;
                }
                let f0 = self.model_energy(items, y, k, x);
                let slope = g.dot(d);
                let mut t = 0.5;
                while self.model_energy(items, y, k, x + t * d) > f0 + 1e-4 * t * slope {
                    t *= 0.5;
                    if t < 1e-10 {
                        break;
                    }
                }
                if t < 1e-10 {
                    break;
                }
                x += t * d;
                (g, h) = self.smooth_model(items, y, k, x);
            }
            if blocked {
                continue;
            }

            // 4. Kink multipliers: the minimum-norm split of the force the kinks must supply. When kinks are
            //    linearly dependent the split is not unique, so before calling a bound violated, look for a
            //    feasible split by projected sweeps over the kinks alone (the same block update as the solver's).
            let (g, _) = self.smooth_model(items, y, k, x);
            let w = pinv * (-g);
            let mut worst: Option<(usize, f64, Status, DVec3)> = None;
            for (i, (item, status)) in items.iter().zip(self.status.iter()).enumerate() {
                if *status != Status::Kink {
                    continue;
                }
                let u = kink_projector(item) * w;
                dual[i] = u;
                let s = item.strength_n;
                let (violation, full) = multiplier_excess(item, u);
                let flip_to = if full { Status::Full } else { Status::Off };
                let relative = violation / s.max(f64::MIN_POSITIVE);
                if violation > STATUS_SLACK * s && worst.is_none_or(|(_, v, _, _)| relative > v) {
                    worst = Some((i, relative, flip_to, u));
                }
            }
            if worst.is_some() && self.feasible_split(items, g, gradient_floor, dual) {
                worst = None;
            }
            if let Some((i, _, flip_to, u)) = worst {
                self.flips[i] = self.flips[i].saturating_add(1);
                if self.flips[i] > MAX_FLIPS_PER_PRIMITIVE {
                    // The same primitive keeps changing its mind: the guess cycles. Give up this round.
                    return None;
                }
                self.status[i] = flip_to;
                let item = &items[i];
                if flip_to == Status::Off && item.kind != PrimitiveKind::Plane {
                    // Leave the kink in the direction the excess force pushes, so the distance term is smooth.
                    let excess = u.length() - item.strength_n;
                    x += u.normalize_or_zero() * (excess / k).max(1e-9 * scale);
                }
                continue;
            }

            for ((item, status), u) in items.iter().zip(self.status.iter()).zip(dual.iter_mut()) {
                *u = match status {
                    Status::Inactive | Status::Candidate => DVec3::ZERO,
                    Status::Kink => project(item, *u),
                    Status::Off => match item.kind {
                        PrimitiveKind::Plane => DVec3::ZERO,
                        _ => project(
                            item,
                            perpendicular(item, x - item.position_m).normalize_or_zero()
                                * item.strength_n,
                        ),
                    },
                    Status::Full => -item.strength_n * item.direction,
                };
            }
            return Some(x);
        }
        None
    }

    /// Looks for kink forces `u_i` in their sets `U_i` that sum to `-g`, starting from the values in `dual`,
    /// by projected block sweeps over the kinks. Returns true (with the split in `dual`) when it finds one.
    fn feasible_split(&self, items: &[Item], g: DVec3, tolerance: f64, dual: &mut [DVec3]) -> bool {
        let mut sum = DVec3::ZERO;
        for ((item, status), u) in items.iter().zip(self.status.iter()).zip(dual.iter_mut()) {
            if *status == Status::Kink {
                *u = project(item, *u);
                sum += *u;
            }
        }
        for _ in 0..MAX_SPLIT_SWEEPS {
            if (sum + g).length() <= tolerance {
                return true;
            }
            for ((item, status), u) in items.iter().zip(self.status.iter()).zip(dual.iter_mut()) {
                if *status == Status::Kink {
                    let others = sum - *u;
                    *u = project(item, -g - others);
                    sum = others + *u;
                }
            }
        }
        (sum + g).length() <= tolerance
    }

    /// Trims the guessed kinks to a set whose affine constraints can all hold at once. A guess taken from an
    /// unconverged dual can name more kinks than R^3 has room for (four planes through no common point). The
    /// kinks nearest `x` are kept first; one that would make the set inconsistent is labelled by side instead.
    fn keep_consistent_kinks(&mut self, items: &[Item], x: DVec3, scale: f64) {
        for status in self.status.iter_mut() {
            if *status == Status::Kink {
                *status = Status::Candidate;
            }
        }
        let mut m = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        let mut tried = 0;
        loop {
            if tried == MAX_KINK_CANDIDATES {
                // R^3 holds few independent kinks: the nearest ones were tried; the rest are labelled by side
                // (keeping the guess O(N) in crowded scenes, where an unconverged dual names hundreds).
                for (item, status) in items.iter().zip(self.status.iter_mut()) {
                    if *status == Status::Candidate {
                        *status = side_status(item, x);
                    }
                }
                break;
            }
            tried += 1;
            let nearest = items
                .iter()
                .zip(self.status.iter())
                .enumerate()
                .filter(|(_, (_, status))| **status == Status::Candidate)
                .map(|(i, (item, _))| (i, (kink_projector(item) * (x - item.position_m)).length()))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let Some((i, _)) = nearest else { break };
            let item = &items[i];
            let p = kink_projector(item);
            let (m_try, b_try) = (m + p, b + p * item.position_m);
            let (pinv, _, _) = psd_pseudo_inverse(m_try, RANK_TOLERANCE);
            let projected = x + pinv * (b_try - m_try * x);
            self.status[i] = Status::Kink;
            let consistent = items.iter().zip(self.status.iter()).all(|(item, status)| {
                *status != Status::Kink
                    || (kink_projector(item) * (projected - item.position_m)).length()
                        <= 1e-12 * scale
            });
            if consistent {
                (m, b) = (m_try, b_try);
            } else {
                self.status[i] = side_status(item, x);
            }
        }
    }

    /// `M = sum P_i` and `b = sum P_i x_i` over the kinks.
    fn kink_system(&self, items: &[Item]) -> (DMat3, DVec3) {
        let mut m = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        for (item, status) in items.iter().zip(self.status.iter()) {
            if *status == Status::Kink {
                let p = kink_projector(item);
                m += p;
                b += p * item.position_m;
            }
        }
        (m, b)
    }

    /// Gradient and Hessian of the smooth model at `x`.
    fn smooth_model(&self, items: &[Item], y: DVec3, k: f64, x: DVec3) -> (DVec3, DMat3) {
        let mut g = k * (x - y);
        let mut h = DMat3::from_diagonal(DVec3::splat(k));
        for (item, status) in items.iter().zip(self.status.iter()) {
            match (status, item.kind) {
                (Status::Off, PrimitiveKind::Point | PrimitiveKind::Line) => {
                    let r = perpendicular(item, x - item.position_m);
                    let rho = r.length();
                    if rho > 0.0 {
                        let n = r / rho;
                        g += item.strength_n * n;
                        let tangent = kink_projector(item) - outer(n, n);
                        h += tangent * (item.strength_n / rho);
                    }
                }
                (Status::Full, _) => g -= item.strength_n * item.direction,
                _ => {}
            }
        }
        (g, h)
    }

    /// The smooth model's energy (the kink terms are zero on the affine set).
    fn model_energy(&self, items: &[Item], y: DVec3, k: f64, x: DVec3) -> f64 {
        let mut e = 0.5 * k * (x - y).length_squared();
        for (item, status) in items.iter().zip(self.status.iter()) {
            match (status, item.kind) {
                (Status::Off, PrimitiveKind::Point | PrimitiveKind::Line) => {
                    e += item.strength_n * perpendicular(item, x - item.position_m).length();
                }
                (Status::Full, _) => e -= item.strength_n * item.direction.dot(x - item.position_m),
                _ => {}
            }
        }
        e
    }

    /// The first off or full primitive that the step `x -> x + d` carries across its kink, with the step
    /// fraction at which it does: a plane's signed distance changing sign, or a point or line passed by (its
    /// offset turning round), where the fraction is the closest approach.
    fn first_crossing(&self, items: &[Item], x: DVec3, d: DVec3) -> Option<(usize, f64)> {
        let mut first: Option<(usize, f64)> = None;
        for (i, (item, status)) in items.iter().zip(self.status.iter()).enumerate() {
            let tau = match (*status, item.kind) {
                (Status::Off, PrimitiveKind::Plane) | (Status::Full, PrimitiveKind::Plane) => {
                    let before = item.direction.dot(x - item.position_m);
                    let after = item.direction.dot(x + d - item.position_m);
                    let crosses = if *status == Status::Off {
                        after < 0.0
                    } else {
                        after > 0.0
                    };
                    if !crosses {
                        continue;
                    }
                    (before / (before - after)).clamp(0.0, 1.0)
                }
                (Status::Off, _) => {
                    // Passing a point or line at a distance is not crossing it: only a step that turns the offset
                    // round and comes within a tenth of the starting distance is blocked (Newton's overshoot
                    // through a kink the answer sits on). Other near passes are left to the line search.
                    let before = perpendicular(item, x - item.position_m);
                    let step = perpendicular(item, d);
                    if before.dot(before + step) > 0.0 {
                        continue;
                    }
                    let tau = (-before.dot(step) / step.length_squared()).clamp(0.0, 1.0);
                    if (before + tau * step).length() > 0.1 * before.length() {
                        continue;
                    }
                    tau
                }
                _ => continue,
            };
            if first.is_none_or(|(_, best)| tau < best) {
                first = Some((i, tau));
            }
        }
        first
    }

    /// Re-labels off and full planes by the side of them `x` is on (the smooth model must match `x`). A plane
    /// that `x` lies on, to within `tolerance_m`, keeps its label: it was just released from its kink, and the
    /// label says which way.
    fn match_plane_sides(&mut self, items: &[Item], x: DVec3, tolerance_m: f64) {
        for (item, status) in items.iter().zip(self.status.iter_mut()) {
            if item.kind == PrimitiveKind::Plane && matches!(*status, Status::Off | Status::Full) {
                let sigma = item.direction.dot(x - item.position_m);
                if sigma > tolerance_m {
                    *status = Status::Off;
                } else if sigma < -tolerance_m {
                    *status = Status::Full;
                }
            }
        }
    }
}

/// The status of a primitive left off the kinks: a plane by the side of it `x` is on, a point or line off.
fn side_status(item: &Item, x: DVec3) -> Status {
    match item.kind {
        PrimitiveKind::Plane if item.direction.dot(x - item.position_m) < 0.0 => Status::Full,
        _ => Status::Off,
    }
}

/// The status suggested by a primal point and a dual variable.
fn guess_status(item: &Item, x: DVec3, u: DVec3) -> Status {
    let s = item.strength_n;
    if s == 0.0 {
        return Status::Inactive;
    }
    let r = x - item.position_m;
    match item.kind {
        PrimitiveKind::Plane => {
            let t = -item.direction.dot(u);
            let sigma = item.direction.dot(r);
            if t > STATUS_SLACK * s && t < (1.0 - STATUS_SLACK) * s || sigma == 0.0 {
                Status::Kink
            } else if sigma > 0.0 {
                Status::Off
            } else {
                Status::Full
            }
        }
        _ => {
            if perpendicular(item, u).length() < (1.0 - STATUS_SLACK) * s {
                Status::Kink
            } else {
                Status::Off
            }
        }
    }
}

/// The part of `v` that the kink constrains: all of it (point), its part orthogonal to the line, or its part
/// along the plane normal.
pub(crate) fn kink_projector(item: &Item) -> DMat3 {
    let q = item.direction;
    match item.kind {
        PrimitiveKind::Point => DMat3::IDENTITY,
        PrimitiveKind::Line => DMat3::IDENTITY - outer(q, q),
        PrimitiveKind::Plane => outer(q, q),
        PrimitiveKind::Directed => DMat3::ZERO,
    }
}

/// `v` itself for a point, its part orthogonal to the line for a line.
fn perpendicular(item: &Item, v: DVec3) -> DVec3 {
    match item.kind {
        PrimitiveKind::Line => v - item.direction * item.direction.dot(v),
        _ => v,
    }
}
