//! The primal Newton method of the exact solver: an active-set Newton iteration on the proxy position itself
//! (x in R^3), with the dual (the primitives' forces) recovered at the end for the certificate.
//!
//! It is the solver's first attempt on every tick ([`super::Solver`]); the dual block sweeps and the dual
//! active-set finish ([`super::active_set`]) take over only if it does not certify within its pass budget.
//!
//! # The iteration
//!
//! The energy `P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)` is smooth except on the primitives' kink sets (the
//! point, the line, the plane). Off its kink a point or a line is a smooth distance term (gradient `s n`,
//! Hessian `s/rho (I - n n^T)` restricted to the line's normal plane); a plane is linear on each side (`-s q`
//! behind it, `0` in front). A *working set* W holds the kinks the proxy is kept on (at most a few: x is in
//! R^3). A cold start (the caller gives no start point: no previous proxy) begins at `x = y - U / k` for a dual sum
//! `U` ([`start_sum`]): up to 128 items the damped sum of each item's projection from zero alone
//! (`min(1, 2 / sqrt(m)) sum_i proj_{U_i}(k (y - x_i))`, no item waiting on another), beyond that one dual
//! block sweep from zero (`u_i = proj_{U_i}(k (y - x_i) - sum_{j < i} u_j)`, a chain of dependent square roots
//! and divisions, worth it only where it saves passes over many items): far from the answer either is the
//! better guess, since the pull of a point or line a few millimetres off is a poor quadratic, and Newton's first
//! step from `y` overshoots. The start's dual values are discarded (the first pass writes its own). One
//! iteration is:
//!
//! 1. One O(N) pass at `x`: gradient `g`, Hessian `H` and energy of the smooth terms, and each primitive's
//!    subgradient written as its dual value (points and lines `s n`, planes `-s q` or `0`).
//! 2. The Newton step restricted to the affine set of W: `d = -(Z H Z + I - Z)^-1 Z g`, `Z` the projector onto
//!    the null space of `M = sum_{i in W} P_i` (`P_i` = I, `I - q q^T`, `q q^T`); a 3x3 solve (with W empty,
//!    an LDL^T solve of the Hessian itself).
//! 3. A line search on the exact piecewise model along `d`: the smooth part as its quadratic, every plane
//!    crossed on the way as the jump `s |q.d|` it adds to the slope (sorted breakpoints). If the minimum lies
//!    at a plane's crossing, the step stops there and the plane joins W; a step that turns round a point or a
//!    line close to it stops at the closest approach and the primitive joins W, if (W being empty) the whole
//!    force the other terms' model puts on it there is at most twice its strength (not only its part along
//!    the step: without this, a point joined W with a multiplier 1 250 times its strength on the benchmark's
//!    1 000 scene, and leaving it threw the proxy half a metre off). Only items whose kink is within `|d|` of
//!    `x` (distances kept from the pass) are read. A step that does not lower the energy (checked by the next
//!    pass) is shortened to the minimiser of the parabola through the energy and slope at its start and the
//!    energy at its end, kept within a tenth and a half of it.
//! 4. With one kink in W (a plane or a line), every pass also predicts its multiplier at the face's minimiser
//!    (from `g + H d`); when that lies outside its set by more than a quarter of its strength, the kink leaves
//!    at once instead of after the passes that would converge on the face (on the benchmark's 1 000 scene a
//!    plane asked for 2.7 N against its 0.96 N three passes before the face had converged).
//!    When the step on the face is negligible, the kink multipliers are recovered: the minimum-norm split
//!    `u_i = P_i M^+ (-g)` or, when the kinks are dependent (a point on a plane), projected block sweeps over
//!    W alone. A multiplier outside its set means the kink is wrong: the worst one leaves W (a plane labelled by
//!    the way it wants to go, a point or line nudged off). When all are feasible, the pair is certified
//!    ([`super::certificate::certify`], over all primitives, independent of everything above).
//! 5. A full Newton step short enough that quadratic convergence puts its end within the tolerance
//!    (`|d|^2 <= 0.1 tolerance clearance`, compensated passes only; a step fraction within 1e-6 of 1 counts as
//!    full, as rounding leaves it) is certified at its end directly: the kink
//!    multipliers come from the gradient the model predicts there (`g + H d`), the other primitives' duals are
//!    the certificate's own exact subgradients there. This saves the pass that would only confirm the point;
//!    if the certificate misses, the pass runs as usual.
//!    *Third-order correction* (W empty): a full step that is short (`|d| <= clearance / 100`) but
//!    not short enough for that has Newton's error `C |d|^2` still to lose. Its leading term is removed by
//!    Chebyshev's correction `e = -H^-1 T[d, d] / 2`, `T` the third derivative of the smooth terms
//!    ([`Workspace::third_order`]: for a point `D^3 (s |r|)[d, d]` in closed form, for a line the same in its
//!    normal plane, planes linear), which leaves an error of about `|e|^2 / |d|`. The corrected step is
//!    certified at its end as above when `|e|^2 <= 0.1 tolerance |d|`. `T` costs about half a pass, so it is
//!    formed only when the last two full steps predict success (`C` estimated as `|d| / |d_last|^2`: the
//!    corrected error `|d|^5 / |d_last|^4` at most a tenth of the tolerance). Nothing here needs to be exact:
//!    the certificate checks the point from scratch, and a miss leaves the corrected point to the next pass.
//!
//! Nothing here has to be right for the answer to be honest: the certificate checks the returned pair from
//! scratch, and an attempt that does not certify hands its point and dual to the dual method.
//!
//! # Screening
//!
//! Strong convexity gives `|x - x*| <= |xi| / k` for any subgradient `xi` of `P` at `x`: at the end of a pass
//! with W empty, `xi = g`; with W, `xi = g + sum_W u_i` for feasible multipliers. So every pass proves a ball
//! `B(x, r)` around the answer (r is padded for rounding: 1 % plus `64 N eps` of the force scale). A plane
//! whose signed distance at `x` exceeds `r` (plus its own rounding) keeps its side on the whole ball, so at the
//! answer: one in front of it exerts nothing and is dropped from the passes; one behind it pushes with all of
//! `s` and becomes a constant term. This is the gap-safe screening of Fercoq, Gramfort and Salmon (2015) in its
//! primal form; it removes work, never changes the answer, and the certificate still runs over every
//! primitive. Scenes of at most 16 primitives in the passes are not screened: a screening costs about a pass
//! over the planes and saves nothing there (docs/solver.md, "Design notes and measurements").

use super::active_set::kink_projector;
use super::certificate::{certify, certify_into, Certificate, Frame};
use super::linalg::{psd_pseudo_inverse, SpdCofactors};
use crate::item::{block_update, multiplier_excess, project, Item};
use crate::math::sqrt;
use crate::primitive::PrimitiveKind;
use crate::storage::{Buffer, Storage};
use crate::sum::{CompensatedSum, GradientSum, PlainSum};
use glam::{DMat3, DVec3};

mod kinks;
mod pass;

const EPS: f64 = f64::EPSILON;
/// Most kinks held at once. R^3 has room for three independent ones; degenerate scenes (a pyramid's apex, a
/// point on a plane) need a few more.
const MAX_KINKS: usize = 8;
/// Relative eigenvalue threshold for the rank of `M`.
const RANK_TOLERANCE: f64 = 1e-11;
/// Relative slack when deciding that a multiplier lies outside its set.
const MULTIPLIER_SLACK: f64 = 1e-9;
/// Projected block sweeps over the kinks when the minimum-norm split is infeasible.
const MAX_SPLIT_SWEEPS: usize = 64;
/// Times one primitive may leave W in one solve before the attempt is abandoned as cycling.
const MAX_DROPS_PER_PRIMITIVE: u8 = 2;
/// Passes sum the gradient plainly until the reduced gradient is below this fraction of the force scale, then
/// with compensation (see `Workspace::pass`).
const COMPENSATE_BELOW: f64 = 1e-4;
/// A single kink whose multiplier predicted at the face's minimiser lies outside its set by more than this
/// fraction of its strength leaves W at once (`Workspace::early_leave`).
const EARLY_LEAVE: f64 = 0.25;
/// A point or line passed near joins W only if the other terms' modelled force on it there is at most this
/// many times its strength (`Workspace::could_hold`).
const NEAR_PASS_HOLD: f64 = 2.0;
/// A line-search step fraction this close to 1 counts as a full Newton step.
const FULL_STEP_SLACK: f64 = 1e-6;
/// Scenes with at most this many items in the passes are not screened (module header, "Screening").
const SCREEN_MIN_ITEMS: usize = 16;
/// Halvings of one step before the attempt is abandoned.
const MAX_HALVINGS: u32 = 30;
/// A full Newton step `d` with `|d|^2 <= SPECULATE_BELOW * tolerance * clearance` is certified at its end
/// without a confirming pass (Newton's error after the step is of order `|d|^2 / clearance`).
const SPECULATE_BELOW: f64 = 0.1;
/// A full Newton step with W empty and `|d| <= CORRECT_BELOW * clearance` may get its third-order correction
/// (module header, step 5), certified at its end when the correction `e` has
/// `|e|^2 <= SPECULATE_BELOW * tolerance * |d|`.
const CORRECT_BELOW: f64 = 1e-2;
/// Scenes of at most this many primitives run the iteration with the pass inlined ([`Workspace::solve`]).
const INLINE_PASS_MAX_ITEMS: usize = 16;

/// What a primitive is to the iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum State {
    /// Zero strength: exerts nothing, never in a pass.
    #[default]
    Inactive,
    /// A point or line off its kink.
    Smooth,
    /// A plane in front of the proxy (exerts nothing); also the label of a plane the proxy is on but that
    /// was released from W that way.
    Off,
    /// A plane behind the proxy (pushes with all of `s`).
    Full,
    /// In the working set W.
    Kink,
    /// Screened: provably in front of the answer; out of the passes.
    ScreenedOff,
    /// Screened: provably behind the answer; a constant term.
    ScreenedFull,
}

/// The result of one Newton attempt.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Outcome {
    /// The last point a pass accepted (a step that raised the energy is not: its start stays), and its
    /// certificate when one was computed there. `dual` holds the subgradients of the last pass, which may be at a
    /// rejected point.
    pub x: DVec3,
    pub certificate: Option<Certificate>,
    /// O(N) passes run (each counts as a sweep against the budget).
    pub passes: u32,
    /// Whether `certificate` met the tolerance.
    pub certified: bool,
}

/// One pass's smooth model at `x`.
#[derive(Debug, Clone, Copy)]
struct Model {
    gradient: DVec3,
    hessian: DMat3,
    energy_j: f64,
    /// Sum of the magnitudes of the energy's terms, for the rounding slack of energy comparisons.
    energy_scale_j: f64,
    /// Smallest distance from `x` to the kink set of a primitive outside W (for skipping the line search's
    /// breakpoint pass when the step is shorter).
    clearance_m: f64,
    /// A point or line that `x` sits exactly on but that is not in W (its gradient is undefined there).
    on_unlisted_kink: Option<usize>,
}

/// The affine set of the working set: `x` is kept on it, steps stay in its null space.
#[derive(Debug, Clone, Copy)]
struct Face {
    pinv: DMat3,
    null: DMat3,
    /// A point in W pins `x` to that point.
    point: Option<usize>,
}

/// A line search's answer: the step fraction and the primitive whose kink the step stops on, if any.
#[derive(Debug, Clone, Copy)]
struct Step {
    t: f64,
    kink: Option<usize>,
}

/// The last accepted point and the step taken from it, kept until the next pass has checked the step.
#[derive(Debug, Clone, Copy)]
struct Previous {
    x: DVec3,
    energy_j: f64,
    d: DVec3,
    /// The step fraction taken.
    t: f64,
    slope_j: f64,
    /// W before the step.
    kinks: [u32; MAX_KINKS],
    kink_count: usize,
}

/// The Newton attempt's workspace, kept between solves (allocation-free once grown to the scene size).
#[derive(Debug, Clone)]
pub(crate) struct Workspace<S: Storage> {
    state: S::Buf<State>,
    drops: S::Buf<u8>,
    /// Items that take part in passes: not inactive, not screened (W members included, skipped by state).
    active: S::Buf<u32>,
    /// Line-search breakpoints: (the bits of the step fraction, item). A plane's slope jump is recomputed when
    /// the walk reaches it, which keeps the sorted elements small.
    breakpoints: S::Buf<(u64, u32)>,
    /// Each item's distance to its kink set at the last pass's `x` (m), by item index: the line search skips
    /// every item farther than the step is long (it can neither cross nor pass near its kink).
    kink_distance_m: S::Buf<f64>,
    kinks: [u32; MAX_KINKS],
    kink_count: usize,
    /// Sum of the screened planes' constant gradients `-s q` (N).
    fixed_gradient_n: DVec3,
    /// Sum of the screened planes' `s q.c`: with `fixed_gradient_n . x` their energy (J).
    fixed_energy_j: f64,
    /// Certificate B's dual at a point certified ahead (`Self::certify_ahead`), adopted when B certifies.
    b_dual: S::Buf<DVec3>,
}

/// Budget and settings of one attempt.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    pub tolerance_m: f64,
    pub max_passes: u32,
    pub screening: bool,
}

/// What one attempt solves, and from where: the items, the frame they are solved in, the start point (`None`: a
/// cold start, module header) and the budget. It stays the same for the whole attempt; the dual values the
/// attempt writes and the deadline it polls go beside it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Attempt<'a> {
    pub items: &'a [Item],
    pub frame: &'a Frame,
    pub start: Option<DVec3>,
    pub limits: Limits,
}

impl<S: Storage> Workspace<S> {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            state: Buffer::with_capacity(n),
            drops: Buffer::with_capacity(n),
            active: Buffer::with_capacity(n),
            breakpoints: Buffer::with_capacity(n),
            kink_distance_m: Buffer::with_capacity(n),
            kinks: [0; MAX_KINKS],
            kink_count: 0,
            fixed_gradient_n: DVec3::ZERO,
            fixed_energy_j: 0.0,
            b_dual: Buffer::with_capacity(n),
        }
    }

    /// Runs the primal Newton iteration of `attempt` from its start point. `dual` (one entry per item) receives
    /// the dual values of the last point; `over_time` is polled before each pass.
    ///
    /// The iteration is compiled twice: with the pass inlined for scenes of up to [`INLINE_PASS_MAX_ITEMS`]
    /// primitives, with the pass out of line for larger ones ([`Self::pass_out_of_line`] says why).
    pub fn solve(
        &mut self,
        attempt: &Attempt,
        dual: &mut [DVec3],
        over_time: &mut dyn FnMut() -> bool,
    ) -> Outcome {
        if attempt.items.len() <= INLINE_PASS_MAX_ITEMS {
            self.solve_with::<true>(attempt, dual, over_time)
        } else {
            self.solve_with::<false>(attempt, dual, over_time)
        }
    }

    /// [`Self::solve`], with the pass inlined (`INLINE_PASS`) or called.
    #[inline(never)]
    fn solve_with<const INLINE_PASS: bool>(
        &mut self,
        attempt: &Attempt,
        dual: &mut [DVec3],
        over_time: &mut dyn FnMut() -> bool,
    ) -> Outcome {
        let Attempt {
            items,
            frame,
            start,
            limits,
        } = *attempt;
        let Frame { y, k, .. } = *frame;
        let n = items.len();
        // Length scale of the scene: thresholds for "on a kink" and rounding slack are relative to it.
        // No start given (no previous proxy): a cold start, from `y`.
        let x_start = start.unwrap_or(y);
        let mut position_scale: f64 = y.abs().max_element() + x_start.abs().max_element();
        let mut strength_sum = 0.0;
        self.state.clear();
        self.drops.clear();
        self.drops.resize(n, 0);
        self.kink_distance_m.clear();
        self.kink_distance_m.resize(n, f64::INFINITY);
        // Only its length matters: `certify_into` writes every entry before it is read.
        self.b_dual.resize(n, DVec3::ZERO);
        self.active.clear();
        self.kink_count = 0;
        self.fixed_gradient_n = DVec3::ZERO;
        self.fixed_energy_j = 0.0;
        // A cold start begins at `y - U/k`, `U` from `start_sum` (module header).
        let cold = start.is_none();
        // A cold start on a scene of at most `JACOBI_START_MAX_ITEMS` items sums `start_sum`'s Jacobi terms in
        // this loop (the same terms in the same order), saving a second visit of every item.
        let jacobi_here = cold && n <= JACOBI_START_MAX_ITEMS;
        let mut jacobi_sum = DVec3::ZERO;
        for (i, (item, u)) in items.iter().zip(dual.iter_mut()).enumerate() {
            *u = DVec3::ZERO;
            position_scale = position_scale.max(item.position_m.abs().max_element());
            strength_sum += item.strength_n;
            let state = if item.strength_n == 0.0 {
                State::Inactive
            } else {
                self.active.push(i as u32);
                if cold {
                    if jacobi_here {
                        jacobi_sum += block_update(item, y, k, DVec3::ZERO);
                    }
                    // The state is set at the start point, below (planes of a damped start: by the first pass).
                    State::Smooth
                } else {
                    start_state(item, x_start)
                }
            };
            self.state.push(state);
        }
        let mut x = x_start;
        if cold && !self.active.is_empty() {
            let sum = if jacobi_here {
                jacobi_sum * jacobi_damping(self.active.len())
            } else {
                start_sum(items, &self.active, y, k)
            };
            x = y - sum / k;
        }
        let scale = position_scale + frame.strength_over_k_m;
        // On a kink: within 16 ulps of the scene's coordinates (where rounding alone can leave a converged x).
        let on_kink_m = 16.0 * EPS * scale;
        // Below this a step is rounding noise.
        let step_floor_m = 4.0 * EPS * scale;
        let force_scale_n = k * scale + strength_sum;
        // Screening costs about a pass over the planes each time; it pays only where many passes over many
        // planes remain to be saved.
        let screening = limits.screening && self.active.len() > SCREEN_MIN_ITEMS;
        let gradient_floor_n = 8.0 * EPS * force_scale_n;
        // A face is done when its reduced gradient is below this (or its step below `step_floor_m`).
        let face_done_gradient_n = (0.25 * k * limits.tolerance_m).max(gradient_floor_n);
        let compensate_below_n = COMPENSATE_BELOW * force_scale_n;

        // Start on the kinks x already sits on (a warm start: the plane the proxy rests on, the friction point at
        // the previous proxy; a cold start: the one primitive the start pushed against, whose projection put x on
        // it). A damped Jacobi start (more than four items, damping below 1) stops short of every kink, and sits
        // on one only by coincidence, which the first pass handles (`Model::on_unlisted_kink`; a plane's side is
        // the pass's to label): it skips this visit, 5 % of a 10-primitive solve's instructions.
        let damped_start = jacobi_here && jacobi_damping(self.active.len()) < 1.0;
        let visited: &[u32] = if damped_start { &[] } else { &self.active };
        for &i in visited {
            let i = i as usize;
            if cold {
                // The state at the start point, set in the same visit.
                self.state[i] = start_state(&items[i], x);
            }
            if kink_distance_squared(&items[i], x) <= on_kink_m * on_kink_m
                && self.kink_count < MAX_KINKS
            {
                self.kinks[self.kink_count] = i as u32;
                self.kink_count += 1;
            }
        }
        for slot in 0..self.kink_count {
            self.state[self.kinks[slot] as usize] = State::Kink;
        }
        let mut face = self.face(items);
        if !self.project_onto_face(items, &face, &mut x, scale) {
            // Not consistent (several kinks through no common point): start off them all.
            for slot in 0..self.kink_count {
                let i = self.kinks[slot] as usize;
                self.state[i] = start_state(&items[i], x);
            }
            self.kink_count = 0;
            face = self.face(items);
        }

        let mut outcome = Outcome {
            x,
            certificate: None,
            passes: 0,
            certified: false,
        };
        // The last accepted point: its energy, the step taken from it, and W before the step.
        let mut previous: Option<Previous> = None;
        let mut halvings = 0;
        let mut screened_radius_m = f64::INFINITY;
        // Whether passes sum the gradient with compensation (see `pass`): from the first pass near the answer.
        let mut compensated = false;
        // The length of the last step if it was a full Newton step (no kink met), else infinite: with this
        // step's length it estimates the quadratic convergence constant.
        let mut last_full_step_m = f64::INFINITY;
        loop {
            if outcome.passes >= limits.max_passes || over_time() {
                return outcome;
            }
            let model = match (compensated, INLINE_PASS) {
                (true, true) => self.pass::<CompensatedSum>(attempt, x, dual),
                (false, true) => self.pass::<PlainSum>(attempt, x, dual),
                (true, false) => self.pass_out_of_line::<CompensatedSum>(attempt, x, dual),
                (false, false) => self.pass_out_of_line::<PlainSum>(attempt, x, dual),
            };
            outcome.passes += 1;
            outcome.x = x;
            outcome.certificate = None;

            // Check the last step against the energy: a step that raised it (beyond rounding) is halved.
            if let Some(last) = previous {
                let slack = 64.0 * EPS * (model.energy_scale_j + last.energy_j.abs());
                if model.energy_j > last.energy_j + slack {
                    halvings += 1;
                    if halvings > MAX_HALVINGS {
                        return outcome;
                    }
                    // Until a shorter step is accepted, the last accepted point is the iteration's answer
                    // (an exit here on the budget returns it, not the point of higher energy just checked).
                    outcome.x = last.x;
                    self.restore_kinks(items, last.kinks, last.kink_count, last.x);
                    face = self.face(items);
                    let curvature = (model.energy_j - last.energy_j - last.slope_j * last.t)
                        / (last.t * last.t);
                    let t = if curvature > 0.0 {
                        (-last.slope_j / (2.0 * curvature)).clamp(0.1 * last.t, 0.5 * last.t)
                    } else {
                        0.5 * last.t
                    };
                    x = last.x + t * last.d;
                    self.project_onto_face(items, &face, &mut x, scale);
                    previous = Some(Previous { t, ..last });
                    continue;
                }
            }
            halvings = 0;
            previous = None;

            if let Some(i) = model.on_unlisted_kink {
                // x landed exactly on a point or line: its gradient is undefined there, so it joins W (or, if
                // that is inconsistent, x moves off it by a rounding-sized step and the pass repeats).
                match self.try_add_kink(items, i, &mut x, scale) {
                    Some(added) => face = added,
                    None => x += DVec3::splat(on_kink_m),
                }
                continue;
            }

            // Newton step on the face.
            // With W empty, the Hessian's cofactors (kept for the third-order correction's solve, step 5).
            let newton_cofactors = (self.kink_count == 0).then(|| SpdCofactors::of(&model.hessian));
            let (reduced_gradient, d) = if let Some(cofactors) = newton_cofactors {
                // No kink: the plain Newton step, by a symmetric solve.
                (model.gradient, -cofactors.solve(model.gradient))
            } else {
                let reduced_gradient = face.null * model.gradient;
                let reduced_hessian =
                    face.null * model.hessian * face.null + (DMat3::IDENTITY - face.null);
                // The solve leaves a component off the face of the order of eps |g| (g is large where kinks hold
                // the proxy): project it away.
                (
                    reduced_gradient,
                    -(face.null * (reduced_hessian.inverse() * reduced_gradient)),
                )
            };
            if !d.is_finite() {
                return outcome;
            }
            // Lengths compared squared (no square root on the iteration's path).
            let gradient_squared = reduced_gradient.length_squared();
            let face_done = d.length_squared() <= step_floor_m * step_floor_m
                || gradient_squared <= face_done_gradient_n * face_done_gradient_n;
            if !compensated
                && !face_done
                && gradient_squared <= compensate_below_n * compensate_below_n
            {
                // Close to the answer: sum with compensation from now on.
                compensated = true;
            }
            if !face_done && self.kink_count == 1 {
                if let Some((i, u, label)) =
                    self.early_leave(items, &face, model.gradient + model.hessian * d)
                {
                    if !self.leave(items, i, u, label, &mut x, k, scale) {
                        return outcome;
                    }
                    face = self.face(items);
                    self.project_onto_face(items, &face, &mut x, scale);
                    continue;
                }
            }
            if face_done {
                match self.multipliers(items, &face, model.gradient, dual) {
                    Ok(()) => {
                        let certificate = certify(items, dual, frame, x, limits.tolerance_m);
                        outcome.certificate = Some(certificate);
                        if certificate.bound_m <= limits.tolerance_m {
                            outcome.certified = true;
                            return outcome;
                        }
                        if !compensated {
                            // The plain sum's rounding may be what keeps the certificate above the tolerance:
                            // check again at the same point with the compensated sum.
                            compensated = true;
                            continue;
                        }
                        if d.length() <= step_floor_m {
                            // Nothing left to gain on this face and the certificate is not met: rounding
                            // limits it here. Let the dual method try.
                            return outcome;
                        }
                        if screening {
                            // The certificate is a proven radius around the answer.
                            self.screen(
                                items,
                                x,
                                certificate.bound_m,
                                &mut screened_radius_m,
                                dual,
                            );
                        }
                    }
                    Err(worst) => {
                        let (i, u, label) = worst;
                        if !self.leave(items, i, u, label, &mut x, k, scale) {
                            return outcome;
                        }
                        face = self.face(items);
                        self.project_onto_face(items, &face, &mut x, scale);
                        continue;
                    }
                }
            } else if screening && self.kink_count == 0 && compensated {
                // With W empty every term is differentiable at x (or a plane exactly at zero distance, whose
                // value in the pass is one of its subgradients): g is a subgradient of P, and |x - x*| <= |g|/k.
                // Padded for the rounding of the (compensated) sum (N terms, each within eps of the force scale)
                // and of y. Plain-sum passes do not screen.
                let radius = (1.01 * model.gradient.length()
                    + 64.0 * (n as f64 + 4.0) * EPS * force_scale_n)
                    / k
                    + frame.y_error_m;
                self.screen(items, x, radius, &mut screened_radius_m, dual);
            }

            let step = self.line_search(items, x, d, reduced_gradient.dot(d), &model);
            let kinks_before = self.kinks;
            let count_before = self.kink_count;
            let mut x_next = x + step.t * d;
            if let Some(i) = step.kink {
                if let Some(added) = self.try_add_kink(items, i, &mut x_next, scale) {
                    face = added;
                } else {
                    x_next = x + step.t * d;
                    self.project_onto_face(items, &face, &mut x_next, scale);
                }
            } else {
                self.project_onto_face(items, &face, &mut x_next, scale);
            }
            // The step taken: `step.t d`, or (below) the full step with its third-order correction.
            let mut taken = d;
            let mut taken_t = step.t;
            // A full step, to rounding: `-slope / curvature` of an exact Newton step is 1 within a few ulps.
            let full_step = step.kink.is_none() && step.t >= 1.0 - FULL_STEP_SLACK;
            let full = compensated && full_step;
            let d_squared = d.length_squared();
            // A point to certify ahead, if any: the gradient the model predicts there and the step to it.
            let mut ahead = None;
            if full && d_squared <= SPECULATE_BELOW * limits.tolerance_m * model.clearance_m {
                // The step is so short that Newton's quadratic convergence puts x_next within the tolerance:
                // certify x_next now, without the pass that would confirm it (module header, step 5).
                ahead = Some((model.gradient + model.hessian * (step.t * d), step.t * d));
            } else if let (true, Some(cofactors)) = (
                full && d_squared
                    <= CORRECT_BELOW * CORRECT_BELOW * model.clearance_m * model.clearance_m
                    && chebyshev_may_certify(sqrt(d_squared), last_full_step_m, limits.tolerance_m),
                newton_cofactors,
            ) {
                // Short, but not short enough for Newton's error alone: the third-order (Chebyshev) correction
                // `e = -H^-1 T[d, d] / 2` takes Newton's leading error term away, leaving one of order
                // `|e|^2 / |d|` (module header, step 5).
                // W is empty (the cofactors exist): the Newton step's own, no second division.
                let correction = -0.5 * cofactors.solve(self.third_order(items, dual, d));
                let corrected = d + correction;
                if corrected.is_finite()
                    && correction.length_squared()
                        <= SPECULATE_BELOW * limits.tolerance_m * sqrt(d_squared)
                {
                    taken = corrected;
                    taken_t = 1.0;
                    x_next = x + corrected;
                    // With W empty no multipliers are recovered, so the predicted gradient is not read.
                    ahead = Some((model.gradient, corrected));
                }
            }
            if let Some((predicted_gradient, step_to_next)) = ahead {
                if let Some(certificate) = self.certify_ahead(
                    attempt,
                    &face,
                    predicted_gradient,
                    step_to_next,
                    x_next,
                    model.clearance_m,
                    scale,
                    dual,
                ) {
                    outcome.x = x_next;
                    outcome.certificate = Some(certificate);
                    outcome.certified = true;
                    return outcome;
                }
            }
            last_full_step_m = if full_step {
                taken.length()
            } else {
                f64::INFINITY
            };
            previous = Some(Previous {
                x,
                energy_j: model.energy_j,
                d: taken,
                t: taken_t,
                slope_j: reduced_gradient.dot(taken),
                kinks: kinks_before,
                kink_count: count_before,
            });
            x = x_next;
        }
    }

    /// Certifies `x_next = x + d` (on the current face) without a pass there: the kink multipliers are
    /// recovered from the gradient the model predicts at `x_next`, `g + H d`; the other items' duals at `x` are
    /// hints the certificate replaces by their exact subgradients at `x_next` (certificate B). On success by B,
    /// `dual` takes B's dual (what the bound is about: the points', lines' and planes' subgradients at `x_next`,
    /// the kinks' multipliers projected) and the certificate is returned; otherwise `dual` holds hints only,
    /// which the next pass overwrites.
    #[allow(clippy::too_many_arguments)]
    fn certify_ahead(
        &mut self,
        attempt: &Attempt,
        face: &Face,
        predicted_gradient: DVec3,
        d: DVec3,
        x_next: DVec3,
        clearance_m: f64,
        scale: f64,
        dual: &mut [DVec3],
    ) -> Option<Certificate> {
        let Attempt {
            items,
            frame,
            limits,
            ..
        } = *attempt;
        // No primitive outside W comes within the certificate's kink threshold of x_next, so the certificate
        // gives every point and line its exact subgradient there, the value the duals are brought to on success.
        if clearance_m <= d.length() + 64.0 * EPS * (scale + x_next.abs().max_element()) {
            return None;
        }
        self.multipliers(items, face, predicted_gradient, dual)
            .ok()?;
        let certificate = certify_into(
            items,
            dual,
            frame,
            x_next,
            limits.tolerance_m,
            Some(&mut self.b_dual),
        );
        if certificate.bound_m > limits.tolerance_m {
            return None;
        }
        if certificate.by_kinks {
            dual.copy_from_slice(&self.b_dual);
        }
        Some(certificate)
    }
}

/// Whether a full step of length `step_m` after a full step of `last_step_m`, with its third-order correction,
/// is expected to land within the tolerance. Quadratic convergence gives Newton's error after the step as about
/// `C step^2` with `C = step / last_step^2`; the corrected step's error is about the square of that over the
/// step, `step^5 / last_step^4`, asked to be a tenth of the tolerance (the bound is about ten times the error).
fn chebyshev_may_certify(step_m: f64, last_step_m: f64, tolerance_m: f64) -> bool {
    let ratio = step_m / last_step_m;
    let ratio_squared = ratio * ratio;
    step_m * ratio_squared * ratio_squared <= SPECULATE_BELOW * tolerance_m
}

/// Scenes with at most this many items in the passes start from a damped Jacobi sum, larger ones from a Gauss-Seidel
/// sweep ([`start_sum`]).
const JACOBI_START_MAX_ITEMS: usize = 128;

/// The dual sum `U` a cold start begins from (the start is `y - U / k`; module header, "The iteration").
///
/// Up to [`JACOBI_START_MAX_ITEMS`] items, each item's projection from zero, `proj_{U_i}(k (y - x_i))`, all
/// independent of each other, summed and damped by `min(1, 2 / sqrt(m))` for `m` items: each term is the force
/// the item would exert were it alone, and `m` of them pulling in unrelated directions add up to about
/// `sqrt(m)` times one, far more than the coupling balances at the answer. Beyond that, one Gauss-Seidel
/// sweep, where each projection sees the sum before it: a better start for many items, but a chain of
/// dependent square roots and divisions, which on ten primitives was a fifth of the solve. The limit and the
/// damping were chosen by pass counts and times over random scenes of 5 to 1 000 primitives (docs/solver.md,
/// "Design notes and measurements").
fn start_sum(items: &[Item], active: &[u32], y: DVec3, k: f64) -> DVec3 {
    let mut sum = DVec3::ZERO;
    if active.len() <= JACOBI_START_MAX_ITEMS {
        for &i in active {
            sum += block_update(&items[i as usize], y, k, DVec3::ZERO);
        }
        sum * jacobi_damping(active.len())
    } else {
        for &i in active {
            sum += block_update(&items[i as usize], y, k, sum);
        }
        sum
    }
}

/// The Jacobi start's damping for `m` items, `min(1, 2 / sqrt(m))` ([`start_sum`]).
fn jacobi_damping(m: usize) -> f64 {
    (2.0 / sqrt(m as f64)).min(1.0)
}

/// The state of an item off W at `x`.
fn start_state(item: &Item, x: DVec3) -> State {
    match item.kind {
        PrimitiveKind::Plane => {
            if item.direction.dot(x - item.position_m) < 0.0 {
                State::Full
            } else {
                State::Off
            }
        }
        _ => State::Smooth,
    }
}

/// How far a multiplier lies outside its set (relative to the strength), and the label its item leaves W with.
fn violation(item: &Item, u: DVec3) -> Option<(f64, State)> {
    let s = item.strength_n;
    let (amount, full) = multiplier_excess(item, u);
    let label = match item.kind {
        PrimitiveKind::Plane if full => State::Full,
        PrimitiveKind::Plane => State::Off,
        _ => State::Smooth,
    };
    (amount > MULTIPLIER_SLACK * s).then_some((amount / s, label))
}

/// The label of a kink leaving W with multiplier `u`.
fn leave_label(item: &Item, u: DVec3) -> State {
    match item.kind {
        PrimitiveKind::Plane => {
            if -item.direction.dot(u) > 0.5 * item.strength_n {
                State::Full
            } else {
                State::Off
            }
        }
        _ => State::Smooth,
    }
}

/// The squared distance from `x` to an item's kink set (no square root: for comparisons).
fn kink_distance_squared(item: &Item, x: DVec3) -> f64 {
    let r = x - item.position_m;
    let q = item.direction;
    match item.kind {
        PrimitiveKind::Point => r.length_squared(),
        PrimitiveKind::Line => (r - q * q.dot(r)).length_squared(),
        PrimitiveKind::Plane => q.dot(r) * q.dot(r),
        PrimitiveKind::Directed => f64::INFINITY,
    }
}

#[cfg(test)]
mod tests;
