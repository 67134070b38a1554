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
use super::certificate::{
    certify, certify_into, Certificate, CompensatedSum, Frame, GradientSum, PlainSum,
};
use super::linalg::{psd_pseudo_inverse, SpdCofactors};
use crate::item::{block_update, project, Item};
use crate::math::sqrt;
use crate::primitive::PrimitiveKind;
use crate::storage::{Buffer, Storage};
use glam::{DMat3, DVec3};

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

    /// Runs the primal Newton iteration from `start` (`None`: a cold start, module header). `dual` (one entry
    /// per item) receives the dual values of the last point; `over_time` is polled before each pass.
    ///
    /// The iteration is compiled twice: with the pass inlined for scenes of up to [`INLINE_PASS_MAX_ITEMS`]
    /// primitives, with the pass out of line for larger ones ([`Self::pass_out_of_line`] says why).
    pub fn solve(
        &mut self,
        items: &[Item],
        frame: &Frame,
        start: Option<DVec3>,
        limits: Limits,
        dual: &mut [DVec3],
        over_time: &mut dyn FnMut() -> bool,
    ) -> Outcome {
        if items.len() <= INLINE_PASS_MAX_ITEMS {
            self.solve_with::<true>(items, frame, start, limits, dual, over_time)
        } else {
            self.solve_with::<false>(items, frame, start, limits, dual, over_time)
        }
    }

    /// [`Self::solve`], with the pass inlined (`INLINE_PASS`) or called.
    #[inline(never)]
    fn solve_with<const INLINE_PASS: bool>(
        &mut self,
        items: &[Item],
        frame: &Frame,
        start: Option<DVec3>,
        limits: Limits,
        dual: &mut [DVec3],
        over_time: &mut dyn FnMut() -> bool,
    ) -> Outcome {
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
                (true, true) => self.pass::<CompensatedSum>(items, frame, x, dual),
                (false, true) => self.pass::<PlainSum>(items, frame, x, dual),
                (true, false) => self.pass_out_of_line::<CompensatedSum>(items, frame, x, dual),
                (false, false) => self.pass_out_of_line::<PlainSum>(items, frame, x, dual),
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
                    items,
                    frame,
                    &face,
                    predicted_gradient,
                    step_to_next,
                    x_next,
                    model.clearance_m,
                    scale,
                    limits,
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
        items: &[Item],
        frame: &Frame,
        face: &Face,
        predicted_gradient: DVec3,
        d: DVec3,
        x_next: DVec3,
        clearance_m: f64,
        scale: f64,
        limits: Limits,
        dual: &mut [DVec3],
    ) -> Option<Certificate> {
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

    /// [`Self::pass`] as a call, for scenes of more than [`INLINE_PASS_MAX_ITEMS`] primitives. Out of line, the
    /// pass's `Model` comes back through memory, and the iteration read parts of it with loads that span two of
    /// the pass's stores (its 3x3 Hessian's columns are 24 bytes), which the processor cannot forward from the
    /// stores and waits out: on ten primitives, three passes, the inlined pass was about 4 % faster in time
    /// (more instructions, fewer waits). On large scenes the loop's own code is what counts, and inlined it
    /// took more instructions (9 % on 100 random primitives, which were 4 % slower), so they call it.
    #[inline(never)]
    fn pass_out_of_line<G: GradientSum>(
        &mut self,
        items: &[Item],
        frame: &Frame,
        x: DVec3,
        dual: &mut [DVec3],
    ) -> Model {
        self.pass::<G>(items, frame, x, dual)
    }

    /// One O(N) pass: the smooth model at `x`, and every item's subgradient written to `dual` (W members are
    /// left to [`Self::multipliers`]). Inlined into the iteration for small scenes; see
    /// [`Self::pass_out_of_line`].
    /// `G` is how the gradient is summed: [`CompensatedSum`] near the answer, where the gradient is the small
    /// difference of many forces and a plain sum's rounding (about sqrt(N) eps of their magnitudes) would be
    /// what Newton converges to; [`PlainSum`] before that, where only the step's direction matters.
    #[inline(always)]
    fn pass<G: GradientSum>(
        &mut self,
        items: &[Item],
        frame: &Frame,
        x: DVec3,
        dual: &mut [DVec3],
    ) -> Model {
        let Frame { y, k, .. } = *frame;
        let offset = x - y;
        let mut gradient = G::default();
        gradient.add(k * offset);
        gradient.add(self.fixed_gradient_n);
        let mut energy =
            0.5 * k * offset.length_squared() + self.fixed_gradient_n.dot(x) + self.fixed_energy_j;
        let mut energy_scale = energy.abs();
        // Hessian of the distance terms: a I - B, with B symmetric (xx, xy, xz, yy, yz, zz).
        let mut a = 0.0;
        let mut b = [0.0f64; 6];
        let mut clearance = f64::INFINITY;
        let mut on_unlisted_kink = None;
        for &index in self.active.iter() {
            let i = index as usize;
            let item = &items[i];
            let state = self.state[i];
            if state == State::Kink {
                continue;
            }
            let s = item.strength_n;
            let r = x - item.position_m;
            match item.kind {
                PrimitiveKind::Plane => {
                    let q = item.direction;
                    let sigma = q.dot(r);
                    let full = sigma < 0.0 || (sigma == 0.0 && state == State::Full);
                    if full {
                        gradient.add(-s * q);
                        energy -= s * sigma;
                        energy_scale -= s * sigma;
                        dual[i] = -s * q;
                        self.state[i] = State::Full;
                    } else {
                        dual[i] = DVec3::ZERO;
                        self.state[i] = State::Off;
                    }
                    let distance = sigma.abs();
                    self.kink_distance_m[i] = distance;
                    // A comparison, not `f64::min` (whose NaN rule costs a few instructions per item): a NaN
                    // distance is skipped either way.
                    if distance < clearance {
                        clearance = distance;
                    }
                }
                PrimitiveKind::Point | PrimitiveKind::Line => {
                    let line = item.kind == PrimitiveKind::Line;
                    let q = item.direction;
                    let perpendicular = if line { r - q * q.dot(r) } else { r };
                    let rho_squared = perpendicular.length_squared();
                    if rho_squared == 0.0 {
                        on_unlisted_kink = Some(i);
                        dual[i] = DVec3::ZERO;
                        self.kink_distance_m[i] = 0.0;
                        clearance = 0.0;
                        continue;
                    }
                    let rho = sqrt(rho_squared);
                    self.kink_distance_m[i] = rho;
                    let inverse = 1.0 / rho;
                    let normal = perpendicular * inverse;
                    let force = s * normal;
                    gradient.add(force);
                    dual[i] = force;
                    energy += s * rho;
                    energy_scale += s * rho;
                    let w = s * inverse;
                    a += w;
                    b[0] += w * normal.x * normal.x;
                    b[1] += w * normal.x * normal.y;
                    b[2] += w * normal.x * normal.z;
                    b[3] += w * normal.y * normal.y;
                    b[4] += w * normal.y * normal.z;
                    b[5] += w * normal.z * normal.z;
                    if line {
                        b[0] += w * q.x * q.x;
                        b[1] += w * q.x * q.y;
                        b[2] += w * q.x * q.z;
                        b[3] += w * q.y * q.y;
                        b[4] += w * q.y * q.z;
                        b[5] += w * q.z * q.z;
                    }
                    if rho < clearance {
                        clearance = rho;
                    }
                }
                PrimitiveKind::Directed => {}
            }
        }
        let diagonal = k + a;
        let hessian = DMat3::from_cols(
            DVec3::new(diagonal - b[0], -b[1], -b[2]),
            DVec3::new(-b[1], diagonal - b[3], -b[4]),
            DVec3::new(-b[2], -b[4], diagonal - b[5]),
        );
        Model {
            gradient: gradient.value(),
            hessian,
            energy_j: energy,
            energy_scale_j: energy_scale,
            clearance_m: clearance,
            on_unlisted_kink,
        }
    }

    /// `T[d, d]`, the third derivative of the smooth terms at `x` applied twice to `d` (W empty): for a point at
    /// distance `rho` in direction `n` (for a line, `n` normal to it and `d` replaced by its part `d'` across the
    /// line), `D^3 (s |r|)[d, d] = -(s / rho^2) (2 a d' + (|d'|^2 - 3 a^2) n)` with `a = n.d'`; planes are
    /// linear. Read from the last pass at `x`: its force `f = s n` (`dual`) and `rho` (`kink_distance_m`), with
    /// `b = f.d'` that is `-(1 / rho^2) (2 b d' + |d'|^2 f) + 3 b^2 / (rho^2 s^2) f`, one division per item.
    fn third_order(&self, items: &[Item], dual: &[DVec3], d: DVec3) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for &index in self.active.iter() {
            let i = index as usize;
            if self.state[i] != State::Smooth {
                continue;
            }
            let item = &items[i];
            let along = if item.kind == PrimitiveKind::Line {
                let q = item.direction;
                d - q * q.dot(d)
            } else {
                d
            };
            let f = dual[i];
            let b = f.dot(along);
            let rho = self.kink_distance_m[i];
            let s_squared = item.strength_n * item.strength_n;
            // 1 / (rho^2 s^2); times s^2 it is 1 / rho^2.
            let inverse = 1.0 / (rho * rho * s_squared);
            sum += (3.0 * b * b * inverse) * f
                - (s_squared * inverse) * (2.0 * b * along + along.length_squared() * f);
        }
        sum
    }

    /// Minimises the piecewise model along `d` over `t in [0, 1]` (module header, step 3).
    /// `slope` is the derivative along `d` on the face (the reduced gradient's, free of the kinks' part).
    // Inlined by hand (the compiler moves it out of line); inlined or called measure the same on 1 000 random
    // primitives.
    #[inline(always)]
    fn line_search(
        &mut self,
        items: &[Item],
        x: DVec3,
        d: DVec3,
        slope: f64,
        model: &Model,
    ) -> Step {
        let curvature = d.dot(model.hessian * d).max(f64::MIN_POSITIVE);
        // `min(1, -slope / curvature)`, with the division (about 1 to rounding for a Newton step) off the
        // iteration's critical path: a comparison decides the common case. A NaN slope gives 1, as `min` did.
        let smooth_t = if -slope < curvature {
            -slope / curvature
        } else {
            1.0
        };
        if d.length_squared() < model.clearance_m * model.clearance_m {
            // No kink within reach of the step.
            return Step {
                t: smooth_t.max(0.0),
                kink: None,
            };
        }
        self.breakpoints.clear();
        // A plane crosses at t <= 1 only if |q.r| <= |q.d| <= |d|; a point or line turns round only if
        // rho^2 <= -r.step <= rho |d|. So items farther than |d| from their kink (measured by the pass at this same
        // x) are skipped unread; the margin covers the rounding of those comparisons.
        let reach_m = d.length() * (1.0 + 1e-9);
        for &index in self.active.iter() {
            let i = index as usize;
            if self.kink_distance_m[i] > reach_m {
                continue;
            }
            let item = &items[i];
            let state = self.state[i];
            let r = x - item.position_m;
            match (item.kind, state) {
                (PrimitiveKind::Plane, State::Off | State::Full) => {
                    let q = item.direction;
                    let qd = q.dot(d);
                    let crosses = if state == State::Off {
                        qd < 0.0
                    } else {
                        qd > 0.0
                    };
                    if !crosses {
                        continue;
                    }
                    let t = (-q.dot(r) / qd).max(0.0) + 0.0;
                    if t <= 1.0 {
                        self.breakpoints.push((t.to_bits(), index));
                    }
                }
                (PrimitiveKind::Point | PrimitiveKind::Line, State::Smooth) => {
                    // A step that turns the offset round and comes within a tenth of the starting distance
                    // passes close to the kink; whether it should stop there is decided in the walk below.
                    let line = item.kind == PrimitiveKind::Line;
                    let q = item.direction;
                    let before = if line { r - q * q.dot(r) } else { r };
                    let step = if line { d - q * q.dot(d) } else { d };
                    if before.dot(before + step) > 0.0 {
                        continue;
                    }
                    let tau = (-before.dot(step) / step.length_squared()).clamp(0.0, 1.0) + 0.0;
                    if (before + tau * step).length() > 0.1 * before.length() {
                        continue;
                    }
                    // A point or line marks a near pass rather than a slope change.
                    self.breakpoints.push((tau.to_bits(), index));
                }
                _ => {}
            }
        }
        // Every step fraction is >= +0.0 (pushed as `max(0.0) + 0.0`, which turns -0.0 into +0.0), and the bits of
        // non-negative floats order as the floats do: an integer key is cheaper to compare than `total_cmp`.
        self.breakpoints.sort_unstable_by_key(|b| b.0);
        let mut jumps = 0.0;
        // The planes crossed so far, as the change they make to the gradient (for the near-pass test).
        let mut jump_gradient = DVec3::ZERO;
        for &(t_bits, index) in self.breakpoints.iter() {
            let t = f64::from_bits(t_bits);
            let unconstrained = -(slope + jumps) / curvature;
            if unconstrained < t {
                return Step {
                    t: unconstrained.max(0.0),
                    kink: None,
                };
            }
            let item = &items[index as usize];
            if item.kind != PrimitiveKind::Plane {
                // A near pass of a point or line: stop on it if, along the step, the other terms' slope there
                // is within what the primitive can hold (`s |step|` either way): the minimum along the line
                // is at the kink. The model's slope there is corrected for the primitive's own share, which the
                // quadratic model spreads over the whole step.
                let line = item.kind == PrimitiveKind::Line;
                let q = item.direction;
                let r = x - item.position_m;
                let before = if line { r - q * q.dot(r) } else { r };
                let step = if line { d - q * q.dot(d) } else { d };
                let rho = before.length();
                let normal = before / rho;
                let s = item.strength_n;
                let own_slope = s * normal.dot(step);
                let along = normal.dot(step);
                let own_curvature = s / rho * (step.length_squared() - along * along);
                let others = slope - own_slope + t * (curvature - own_curvature) + jumps;
                if others.abs() <= s * step.length()
                    && (self.kink_count > 0
                        || self.could_hold(item, model, d, t, normal, step, rho, jump_gradient))
                {
                    return Step {
                        t,
                        kink: Some(index as usize),
                    };
                }
                continue;
            }
            let plane = item;
            jumps += plane.strength_n * plane.direction.dot(d).abs();
            jump_gradient += if self.state[index as usize] == State::Off {
                -plane.strength_n * plane.direction
            } else {
                plane.strength_n * plane.direction
            };
            if slope + t * curvature + jumps >= 0.0 {
                return Step {
                    t,
                    kink: Some(index as usize),
                };
            }
        }
        Step {
            t: (-(slope + jumps) / curvature).clamp(0.0, 1.0),
            kink: None,
        }
    }

    /// Whether a point or line passed near at step fraction `t` could hold the proxy there, W being empty: the
    /// whole force the other terms' model puts on it there (not only its part along the step) is within
    /// [`NEAR_PASS_HOLD`] times its strength. (Without this a point could join W with a multiplier a thousand
    /// times its strength, and leaving it again threw the proxy far off.) `normal`, `step` and `rho` are its
    /// offset's direction, the step's part across it and its distance, at `x`.
    #[allow(clippy::too_many_arguments)]
    fn could_hold(
        &self,
        item: &Item,
        model: &Model,
        d: DVec3,
        t: f64,
        normal: DVec3,
        step: DVec3,
        rho: f64,
        jump_gradient: DVec3,
    ) -> bool {
        let s = item.strength_n;
        let own_gradient = s * normal;
        let own_hessian_d = s / rho * (step - normal * normal.dot(step));
        let mut others =
            model.gradient - own_gradient + t * (model.hessian * d - own_hessian_d) + jump_gradient;
        if item.kind == PrimitiveKind::Line {
            let q = item.direction;
            others -= q * q.dot(others);
        }
        others.length() <= NEAR_PASS_HOLD * s
    }

    /// Recovers the kink multipliers (module header, step 4) into `dual`, each in its set. On failure returns
    /// the worst violation: the item, its multiplier, and the label it leaves W with.
    fn multipliers(
        &self,
        items: &[Item],
        face: &Face,
        gradient: DVec3,
        dual: &mut [DVec3],
    ) -> Result<(), (usize, DVec3, State)> {
        if self.kink_count == 0 {
            return Ok(());
        }
        let needed = -gradient;
        if face.point.is_none() {
            // The minimum-norm split.
            let w = face.pinv * needed;
            let mut worst: Option<(usize, f64, DVec3, State)> = None;
            for &index in &self.kinks[..self.kink_count] {
                let i = index as usize;
                let item = &items[i];
                let u = kink_projector(item) * w;
                dual[i] = project(item, u);
                if let Some((violation, label)) = violation(item, u) {
                    if worst.is_none_or(|(_, v, _, _)| violation > v) {
                        worst = Some((i, violation, u, label));
                    }
                }
            }
            match worst {
                None => return Ok(()),
                Some((i, _, u, label)) => {
                    if self.kink_count == 1 {
                        return Err((i, u, label));
                    }
                    // Dependent kinks can split the force another way: try the sweeps below.
                    let _ = (i, u, label);
                }
            }
        } else {
            for &index in &self.kinks[..self.kink_count] {
                dual[index as usize] = DVec3::ZERO;
            }
        }
        // Dependent kinks: look for a feasible split by projected block sweeps over W alone.
        let tolerance = 8.0 * EPS * needed.length().max(f64::MIN_POSITIVE);
        let mut sum = DVec3::ZERO;
        for &index in &self.kinks[..self.kink_count] {
            let i = index as usize;
            dual[i] = project(&items[i], dual[i]);
            sum += dual[i];
        }
        for _ in 0..MAX_SPLIT_SWEEPS {
            let sum_before = sum;
            let mut changed = false;
            for &index in &self.kinks[..self.kink_count] {
                let i = index as usize;
                let others = sum - dual[i];
                let u = project(&items[i], needed - others);
                changed |= u != dual[i];
                dual[i] = u;
                sum = others + u;
            }
            if (sum - needed).length() <= tolerance {
                return Ok(());
            }
            if !changed && sum == sum_before {
                // A fixed point (one kink reaches it in one sweep): further sweeps would repeat this one.
                break;
            }
        }
        // No feasible split found: the kink whose unconstrained share most exceeds its set leaves.
        let mut worst: Option<(usize, f64, DVec3, State)> = None;
        for &index in &self.kinks[..self.kink_count] {
            let i = index as usize;
            let others = sum - dual[i];
            let u = kink_projector(&items[i]) * (needed - others);
            if let Some((violation, label)) = violation(&items[i], u) {
                if worst.is_none_or(|(_, v, _, _)| violation > v) {
                    worst = Some((i, violation, u, label));
                }
            }
        }
        let (i, _, u, label) = worst.unwrap_or_else(|| {
            // Every share is feasible on its own yet they do not add up: drop the last kink added.
            let i = self.kinks[self.kink_count - 1] as usize;
            (i, 0.0, dual[i], leave_label(&items[i], dual[i]))
        });
        Err((i, u, label))
    }

    /// Gap-safe screening (module header): drops the planes that keep their side on the ball of radius
    /// `radius` around `x`, which is proven to hold the answer. Runs only when the radius has shrunk by 4
    /// since the last screening.
    fn screen(
        &mut self,
        items: &[Item],
        x: DVec3,
        radius: f64,
        screened_radius_m: &mut f64,
        dual: &mut [DVec3],
    ) {
        // (A NaN radius screens nothing.)
        if radius.is_nan() || radius >= 0.25 * *screened_radius_m {
            return;
        }
        *screened_radius_m = radius;
        let scale = x.abs().max_element();
        let mut kept = 0;
        for slot in 0..self.active.len() {
            let index = self.active[slot];
            let i = index as usize;
            let item = &items[i];
            let state = self.state[i];
            if item.kind == PrimitiveKind::Plane && matches!(state, State::Off | State::Full) {
                let sigma = item.direction.dot(x - item.position_m);
                let rounding = 8.0 * EPS * (scale + item.position_m.abs().max_element());
                if sigma.abs() > radius + rounding {
                    if sigma < 0.0 {
                        self.state[i] = State::ScreenedFull;
                        self.fixed_gradient_n -= item.strength_n * item.direction;
                        self.fixed_energy_j +=
                            item.strength_n * item.direction.dot(item.position_m);
                        dual[i] = -item.strength_n * item.direction;
                    } else {
                        self.state[i] = State::ScreenedOff;
                        dual[i] = DVec3::ZERO;
                    }
                    continue;
                }
            }
            self.active[kept] = index;
            kept += 1;
        }
        self.active.truncate(kept);
    }

    /// The affine set of W.
    fn face(&self, items: &[Item]) -> Face {
        let kinks = &self.kinks[..self.kink_count];
        if let Some(&p) = kinks
            .iter()
            .find(|&&i| items[i as usize].kind == PrimitiveKind::Point)
        {
            return Face {
                pinv: DMat3::ZERO,
                null: DMat3::ZERO,
                point: Some(p as usize),
            };
        }
        match kinks {
            [] => Face {
                pinv: DMat3::ZERO,
                null: DMat3::IDENTITY,
                point: None,
            },
            [only] => {
                let p = kink_projector(&items[*only as usize]);
                Face {
                    pinv: p,
                    null: DMat3::IDENTITY - p,
                    point: None,
                }
            }
            _ => {
                let m = kinks
                    .iter()
                    .map(|&i| kink_projector(&items[i as usize]))
                    .fold(DMat3::ZERO, |m, p| m + p);
                let (pinv, null, _) = psd_pseudo_inverse(m, RANK_TOLERANCE);
                Face {
                    pinv,
                    null,
                    point: None,
                }
            }
        }
    }

    /// Moves `x` onto the affine set of W (two rounds: the second removes the first's rounding). Returns whether
    /// every kink then holds it (the set is consistent).
    fn project_onto_face(&self, items: &[Item], face: &Face, x: &mut DVec3, scale: f64) -> bool {
        if self.kink_count == 0 {
            return true;
        }
        if let Some(p) = face.point {
            *x = items[p].position_m;
        } else {
            for _ in 0..2 {
                let mut residual = DVec3::ZERO;
                for &index in &self.kinks[..self.kink_count] {
                    let item = &items[index as usize];
                    residual += kink_projector(item) * (item.position_m - *x);
                }
                *x += face.pinv * residual;
            }
        }
        let tolerance = 64.0 * EPS * scale;
        self.kinks[..self.kink_count]
            .iter()
            .all(|&i| kink_distance_squared(&items[i as usize], *x) <= tolerance * tolerance)
    }

    /// Adds item `i` to W if the enlarged set is consistent, moving `x` onto it, and returns the new face;
    /// otherwise leaves W and `x`.
    fn try_add_kink(
        &mut self,
        items: &[Item],
        i: usize,
        x: &mut DVec3,
        scale: f64,
    ) -> Option<Face> {
        if self.kink_count == MAX_KINKS || self.state[i] == State::Kink {
            return None;
        }
        self.kinks[self.kink_count] = i as u32;
        self.kink_count += 1;
        let face = self.face(items);
        let mut moved = *x;
        if self.project_onto_face(items, &face, &mut moved, scale) {
            self.state[i] = State::Kink;
            *x = moved;
            Some(face)
        } else {
            self.kink_count -= 1;
            None
        }
    }

    /// Takes kink `i`, whose multiplier `u` lies outside its set, out of W with `label` (a point or line is
    /// moved off its kink the way the excess force pushes, by what the coupling alone would yield to it).
    /// Returns false when `i` has left W too often in this solve (the attempt is then abandoned as cycling).
    #[allow(clippy::too_many_arguments)]
    fn leave(
        &mut self,
        items: &[Item],
        i: usize,
        u: DVec3,
        label: State,
        x: &mut DVec3,
        k: f64,
        scale: f64,
    ) -> bool {
        self.drops[i] = self.drops[i].saturating_add(1);
        if self.drops[i] > MAX_DROPS_PER_PRIMITIVE {
            return false;
        }
        self.remove_kink(i, label);
        let item = &items[i];
        if item.kind != PrimitiveKind::Plane {
            let excess = u.length() - item.strength_n;
            *x += u.normalize_or_zero() * (excess / k).max(1e-9 * scale);
        }
        true
    }

    /// Step 4 ahead of time: with one kink in W (a plane or a line), its multiplier at the minimiser of the
    /// face's model, from the gradient the model predicts there (`g + H d`). If that lies far outside its set
    /// (by more than [`EARLY_LEAVE`] of the strength), converging on the face would only end in the kink
    /// leaving: returns it, its multiplier and its label, so that it leaves now.
    fn early_leave(
        &self,
        items: &[Item],
        face: &Face,
        predicted: DVec3,
    ) -> Option<(usize, DVec3, State)> {
        if self.kink_count != 1 || face.point.is_some() {
            return None;
        }
        let i = self.kinks[0] as usize;
        let item = &items[i];
        let u = kink_projector(item) * -predicted;
        let (amount, label) = violation(item, u)?;
        (amount > EARLY_LEAVE).then_some((i, u, label))
    }

    /// Removes item `i` from W with the given label.
    fn remove_kink(&mut self, i: usize, label: State) {
        if let Some(slot) = self.kinks[..self.kink_count]
            .iter()
            .position(|&k| k as usize == i)
        {
            self.kinks.copy_within(slot + 1..self.kink_count, slot);
            self.kink_count -= 1;
        }
        self.state[i] = label;
    }

    /// Puts W back as it was before a step that is being halved.
    fn restore_kinks(&mut self, items: &[Item], kinks: [u32; MAX_KINKS], count: usize, x: DVec3) {
        for slot in 0..self.kink_count {
            let i = self.kinks[slot] as usize;
            if !kinks[..count].contains(&(i as u32)) {
                self.state[i] = start_state(&items[i], x);
            }
        }
        self.kinks = kinks;
        self.kink_count = count;
        for &i in &kinks[..count] {
            self.state[i as usize] = State::Kink;
        }
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
    let (amount, label) = match item.kind {
        PrimitiveKind::Plane => {
            let t = -item.direction.dot(u);
            if t < 0.0 {
                (-t, State::Off)
            } else {
                (t - s, State::Full)
            }
        }
        _ => (u.length() - s, State::Smooth),
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
mod tests {
    use super::*;
    use crate::bench_scenes::{random_scene, SplitMix};
    use crate::item::subgradient;

    /// The gradient of the smooth terms at `x` (points and lines off their kink: their subgradient), for
    /// finite differences.
    fn smooth_gradient(items: &[Item], x: DVec3) -> DVec3 {
        items.iter().map(|item| subgradient(item, x)).sum()
    }

    /// `third_order` is the third derivative applied twice: it matches the second central difference of the
    /// gradient along `d`, `(g(x + h d) - 2 g(x) + g(x - h d)) / h^2`, on random points and lines.
    #[test]
    fn third_order_matches_finite_differences_of_the_gradient() {
        let mut rng = SplitMix(42);
        for scene in 0..50 {
            let items: Vec<Item> = (0..6)
                .map(|i| Item {
                    kind: if i % 2 == 0 {
                        PrimitiveKind::Point
                    } else {
                        PrimitiveKind::Line
                    },
                    position_m: rng.vec(0.01),
                    direction: if i % 2 == 0 {
                        DVec3::ZERO
                    } else {
                        rng.vec(1.0).normalize()
                    },
                    strength_n: rng.range(0.1, 2.0),
                })
                .collect();
            let x = rng.vec(0.01);
            let d = rng.vec(1e-3);
            let mut workspace = Workspace::<crate::storage::Heap>::with_capacity(items.len());
            // A pass at x writes each smooth item's force there (its subgradient) as its dual value.
            let dual: Vec<DVec3> = items.iter().map(|item| subgradient(item, x)).collect();
            for (i, item) in items.iter().enumerate() {
                workspace.active.push(i as u32);
                workspace.state.push(State::Smooth);
                workspace
                    .kink_distance_m
                    .push(kink_distance_squared(item, x).sqrt());
            }
            let analytic = workspace.third_order(&items, &dual, d);
            let h = 1e-3;
            let numeric = (smooth_gradient(&items, x + h * d) - 2.0 * smooth_gradient(&items, x)
                + smooth_gradient(&items, x - h * d))
                / (h * h);
            let error = (analytic - numeric).length();
            assert!(
                error <= 1e-4 * analytic.length(),
                "scene {scene}: analytic {analytic:?}, numeric {numeric:?}"
            );
        }
    }

    /// The iteration compiled with the pass inlined (scenes of up to `INLINE_PASS_MAX_ITEMS`) and with it called
    /// (larger scenes) is the same computation: on small random scenes, cold and warm, both give the same point,
    /// dual, passes and certificate to the bit. Fails if either copy's pass or iteration drifts from the other.
    #[test]
    fn the_inlined_and_the_called_pass_iterate_alike() {
        let k = 500.0;
        let mut certified = 0;
        for seed in 1..=300u64 {
            let n = 1 + (seed as usize) % INLINE_PASS_MAX_ITEMS;
            let (probe, primitives) = random_scene(seed * 7_919 + n as u64, n);
            let items: Vec<Item> = primitives
                .iter()
                .filter(|p| p.kind() != PrimitiveKind::Directed)
                .map(|p| Item {
                    kind: p.kind(),
                    position_m: p.position_m(),
                    direction: p.direction(),
                    strength_n: p.strength_n(),
                })
                .collect();
            let frame = Frame {
                y: probe,
                k,
                y_error_m: 0.0,
                strength_over_k_m: items.iter().map(|item| item.strength_n).sum::<f64>() / k,
            };
            let limits = Limits {
                tolerance_m: 1e-12,
                max_passes: 60,
                screening: true,
            };
            for start in [None, Some(probe + DVec3::new(1e-3, -2e-3, 5e-4))] {
                let run = |inline: bool| {
                    let mut workspace =
                        Workspace::<crate::storage::Heap>::with_capacity(items.len());
                    let mut dual = vec![DVec3::splat(f64::NAN); items.len()];
                    let outcome = if inline {
                        workspace.solve_with::<true>(
                            &items,
                            &frame,
                            start,
                            limits,
                            &mut dual,
                            &mut || false,
                        )
                    } else {
                        workspace.solve_with::<false>(
                            &items,
                            &frame,
                            start,
                            limits,
                            &mut dual,
                            &mut || false,
                        )
                    };
                    (outcome, dual)
                };
                let ((inlined, inlined_dual), (called, called_dual)) = (run(true), run(false));
                let bits = |v: DVec3| v.to_array().map(f64::to_bits);
                let context = format!("seed {seed}, {} items, start {start:?}", items.len());
                assert_eq!(bits(inlined.x), bits(called.x), "{context}");
                assert_eq!(inlined.passes, called.passes, "{context}");
                assert_eq!(inlined.certified, called.certified, "{context}");
                assert_eq!(
                    inlined.certificate.map(|c| c.bound_m.to_bits()),
                    called.certificate.map(|c| c.bound_m.to_bits()),
                    "{context}"
                );
                let dual_bits = |dual: &[DVec3]| dual.iter().map(|&u| bits(u)).collect::<Vec<_>>();
                assert_eq!(
                    dual_bits(&inlined_dual),
                    dual_bits(&called_dual),
                    "{context}"
                );
                certified += usize::from(inlined.certified);
            }
        }
        // Most attempts certify: the comparison covers whole iterations, not only first passes.
        assert!(certified >= 500, "{certified} of 600 attempts certified");
    }
}
