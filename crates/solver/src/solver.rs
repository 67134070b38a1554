//! The solver: its workspace, the choice between the methods (crate header, "The methods"), and the exits.

use crate::certificate::{certify, Frame};
use crate::clock::Clock;
use crate::item::{block_update, project, subgradient, Item};
use crate::primitive::PrimitiveKind;
use crate::problem::{Problem, Solution, SolveError, SolveStatus, SolverConfig};
#[cfg(feature = "alloc")]
use crate::storage::Heap;
use crate::storage::{self, Buffer, Storage};
use crate::sum::CompensatedSum;
use crate::{active_set, newton};
use glam::DVec3;

/// The storage a plain `Solver` uses: growable with `alloc`, else 64 primitives in arrays.
#[cfg(feature = "alloc")]
pub type DefaultStorage = Heap;
/// The storage a plain `Solver` uses: growable with `alloc`, else 64 primitives in arrays.
#[cfg(not(feature = "alloc"))]
pub type DefaultStorage = storage::Fixed<64>;

/// The solver and its workspace (CONTRIBUTING.md item 3: allocate up front, `clear()` instead of rebuild), kept
/// in `S`: [`storage::Heap`] grows it, [`storage::Fixed`] holds it in arrays (no allocator).
#[derive(Debug, Clone)]
pub struct Solver<S: Storage = DefaultStorage> {
    config: SolverConfig,
    items: S::Buf<Item>,
    dual: S::Buf<DVec3>,
    /// The active-set attempt writes here; it replaces `dual` only if it certifies a better point.
    candidate_dual: S::Buf<DVec3>,
    /// Whether `items` and `dual` hold the previous solve's values (false after `reset`).
    has_previous_dual: bool,
    active_set: active_set::Workspace<S>,
    newton: newton::Workspace<S>,
}

/// A primal point with its certificate.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    x: DVec3,
    gap_j: f64,
    bound_m: f64,
}

/// Most passes of the primal Newton attempt before the dual method takes over.
const NEWTON_MAX_PASSES: u32 = 100;

/// Sweeps without halving the bound after which a solve stops as [`SolveStatus::Stalled`]: the bound has reached
/// the floating-point floor of the scene and more sweeps cannot help.
const STALL_SWEEPS: u32 = 2000;

/// Scenes up to this many primitives are checked on the sweep schedule within a round; larger ones at the end
/// of each round.
const CHECK_EVERY_SWEEP_MAX_ITEMS: usize = 16;

/// A clock for solves without a time budget: never read.
struct NoClock;

impl Clock for NoClock {
    fn now_ns(&self) -> u64 {
        0
    }
}

#[cfg(feature = "alloc")]
impl Default for Solver<Heap> {
    fn default() -> Self {
        Self::new(SolverConfig::default())
    }
}

#[cfg(feature = "alloc")]
impl Solver<Heap> {
    pub fn new(config: SolverConfig) -> Self {
        Self::with_capacity(config, 16)
    }

    /// A solver whose workspace already holds `max_primitives`, so that no solve of that size allocates.
    pub fn with_capacity(config: SolverConfig, max_primitives: usize) -> Self {
        Self::new_in(config, max_primitives)
    }
}

/// `solve` and `solve_with_clock`, not generic, for each storage: so that the solve is compiled once, in this
/// crate, rather than again in each crate that calls it (the generic code compiled there was up to 5 % slower in
/// instructions: other inlining).
macro_rules! solve_methods {
    () => {
        /// Solves with the sweep budget only (deterministic).
        pub fn solve(&mut self, problem: &Problem) -> Result<Solution, SolveError> {
            self.solve_inner(problem, &NoClock, false)
        }

        /// Solves with the sweep budget and the time budget `config.max_time_ns`, measured on `clock`.
        pub fn solve_with_clock(
            &mut self,
            problem: &Problem,
            clock: &dyn Clock,
        ) -> Result<Solution, SolveError> {
            self.solve_inner(problem, clock, true)
        }
    };
}

#[cfg(feature = "alloc")]
impl Solver<Heap> {
    solve_methods!();
}

impl<const N: usize> Solver<storage::Fixed<N>> {
    solve_methods!();
}

impl<S: Storage> Solver<S> {
    /// A solver in storage `S` with room for `max_primitives` (a hint for [`storage::Heap`]; a
    /// [`storage::Fixed`] storage always holds its capacity).
    pub fn new_in(config: SolverConfig, max_primitives: usize) -> Self {
        Self {
            config,
            items: Buffer::with_capacity(max_primitives),
            dual: Buffer::with_capacity(max_primitives),
            candidate_dual: Buffer::with_capacity(max_primitives),
            has_previous_dual: false,
            active_set: active_set::Workspace::with_capacity(max_primitives),
            newton: newton::Workspace::with_capacity(max_primitives),
        }
    }

    pub fn config(&self) -> &SolverConfig {
        &self.config
    }

    pub fn config_mut(&mut self) -> &mut SolverConfig {
        &mut self.config
    }

    /// The force each non-directed primitive exerted on the proxy in the last solve, `-u_i` from its final
    /// dual (N), in the order the primitives were given with the directed ones skipped. They balance the
    /// coupling at the returned proxy within `k * error_bound_m`. Allocation-free.
    pub fn primitive_forces_n(&self) -> impl Iterator<Item = DVec3> + '_ {
        self.dual.iter().map(|u| -*u)
    }

    /// Forget the previous dual (the next solve starts cold or from `previous_proxy_m`).
    pub fn reset(&mut self) {
        self.has_previous_dual = false;
    }

    fn solve_inner(
        &mut self,
        problem: &Problem,
        clock: &dyn Clock,
        timed: bool,
    ) -> Result<Solution, SolveError> {
        let k = problem.stiffness_n_per_m;
        if !(k.is_finite() && k > 0.0) {
            return Err(SolveError::BadStiffness(k));
        }
        if !problem.probe_m.is_finite() {
            return Err(SolveError::BadProbe(problem.probe_m.to_array()));
        }
        if let Some(prev) = problem.previous_proxy_m {
            if !prev.is_finite() {
                return Err(SolveError::BadPreviousProxy(prev.to_array()));
            }
        }
        if let Some(capacity) = S::fits(problem.primitives.len()) {
            // Only a fixed storage gets here (a growable one fits anything); counted only then.
            let given = problem
                .primitives
                .iter()
                .filter(|p| p.kind() != PrimitiveKind::Directed)
                .count();
            if given > capacity {
                return Err(SolveError::TooManyPrimitives { given, capacity });
            }
        }
        let start_ns = if timed { clock.now_ns() } else { 0 };
        let config = self.config;

        // y = probe + (sum of directed forces) / k; the rest become items.
        // Summed with compensation, so that y's rounding stays a few ulps however many directed forces there are.
        let mut directed = CompensatedSum::default();
        let mut directed_strength = 0.0;
        let mut directed_count = 0.0;
        // Build the items in place; the previous dual is reused when the kinds match one for one.
        let mut count = 0;
        let mut same_structure = self.config.warm_start_dual && self.has_previous_dual;
        let mut strength_sum = 0.0;
        for p in problem.primitives {
            if p.kind() == PrimitiveKind::Directed {
                directed.add(p.strength_n() * p.direction());
                directed_strength += p.strength_n();
                directed_count += 1.0;
                continue;
            }
            strength_sum += p.strength_n();
            if count < self.items.len() {
                // Field by field into the slot: an `Item` built on the stack and copied whole was read back
                // with wider loads than it was written with, which stalled the copy (store forwarding fails):
                // 4 % of a 10-primitive solve.
                let slot = &mut self.items[count];
                same_structure &= slot.kind == p.kind();
                slot.kind = p.kind();
                slot.position_m = p.position_m();
                slot.direction = p.direction();
                slot.strength_n = p.strength_n();
            } else {
                same_structure = false;
                self.items.push(Item {
                    kind: p.kind(),
                    position_m: p.position_m(),
                    direction: p.direction(),
                    strength_n: p.strength_n(),
                });
            }
            count += 1;
        }
        same_structure &= count == self.items.len() && count == self.dual.len();
        self.items.truncate(count);
        let directed = directed.value();
        let y = problem.probe_m + directed / k;
        let frame = Frame {
            y,
            k,
            // Each product s q rounds by eps/2 of s per coordinate (at most eps s in length); the compensated
            // sum adds 2 eps of the result and n eps^2 of the magnitudes (certificate.rs); the quotient by k and
            // the sum with the probe add eps/2 of their results each. Doubled for margin.
            // The 1-norms bound the lengths from above, without square roots.
            y_error_m: 2.0
                * f64::EPSILON
                * (problem.probe_m.abs().element_sum()
                    + (2.0 * directed.abs().element_sum()
                        + (1.0 + directed_count * f64::EPSILON) * directed_strength)
                        / k),
            strength_over_k_m: strength_sum / k,
            rebalance: self.config.rebalance_certificate,
        };
        // A reused dual is not projected here, though the previous tick's values may lie outside this tick's sets
        // (a weakened or tilted primitive): every use projects it first. A sweep projects each value it writes,
        // the primal method starts from zero, the certificate projects whatever it is given, and the one exit
        // that returns the warm start as it is (out of budget before any pass) projects it there.
        if !same_structure {
            if self.candidate_dual.capacity() < count {
                // Grown with the items, so that an exit that needs it (`least_energy`) never allocates.
                self.grow_candidate_dual(count);
            }
            self.dual.clear();
            match problem.previous_proxy_m {
                Some(x) => self
                    .dual
                    .extend_iter(self.items.iter().map(|item| subgradient(item, x))),
                None => self.dual.resize(self.items.len(), DVec3::ZERO),
            }
        }
        self.has_previous_dual = true;

        let mut sweeps = 0u32;
        let mut rounds = 0u32;
        let mut total = self.dual.iter().copied().sum::<DVec3>();
        // The start (module header, "Invariants"), `previous_proxy_m` or `y`: an exit without a certified
        // answer never returns a point of higher energy. Formed only at such an exit.
        let start_x = || problem.previous_proxy_m.unwrap_or(y);
        // The primal method's last accepted point, when it ran and did not certify (a candidate at such exits).
        let mut newton_x = None;
        // With primitives and a budget, at least one sweep runs before the first check, so the warm start is
        // not certified separately (it saves a gap evaluation per tick). Every exit below certifies what it
        // returns: `best` starts with an infinite bound, and the budget exit certifies the current dual.
        let mut best = if self.items.is_empty() {
            self.certify_dual(&frame, total)
        } else {
            Candidate {
                x: y - total / k,
                gap_j: f64::INFINITY,
                bound_m: f64::INFINITY,
            }
        };
        let mut best_at_sweep = 0u32;
        let mut retry_from_sweeps = false;
        let mut primal_fallback_done = false;
        let mut next_check = 1u32;
        let mut newton_passes = 0;
        let finish = |best: Candidate, sweeps, newton_passes, rounds, status| Solution {
            proxy_m: best.x,
            force_n: k * (best.x - problem.probe_m),
            sweeps,
            newton_passes,
            active_set_rounds: rounds,
            gap_j: best.gap_j,
            error_bound_m: best.bound_m,
            status,
        };
        let over_budget = |sweeps: u32| {
            sweeps >= config.max_sweeps
                || (timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns)
        };
        // With no pass allowed (or no time), the warm start is certified as it is, below.
        // Small warm-started scenes (the servo loop's usual tick: a surface and friction) are finished fastest
        // by a dual sweep or two from last tick's dual (the benchmark's exploration path: 0.2 us against 2 us
        // for the primal method); everything else starts with the primal method.
        let primal_first = config.primal_newton
            && !(same_structure && self.items.len() <= CHECK_EVERY_SWEEP_MAX_ITEMS);
        if primal_first && !self.items.is_empty() && !over_budget(sweeps) {
            let mut over_time =
                || timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns;
            let attempt = newton::Attempt {
                items: &self.items,
                frame: &frame,
                start: problem.previous_proxy_m,
                limits: newton_limits(&config, sweeps),
            };
            let outcome = self.newton.solve(&attempt, &mut self.dual, &mut over_time);
            sweeps += outcome.passes;
            newton_passes = outcome.passes;
            if !outcome.certified {
                newton_x = Some(outcome.x);
            }
            let checked = match outcome.certificate {
                Some(checked) => Some(checked),
                // Out of budget: the point and dual it reached are certified as they are.
                None if over_budget(sweeps) => Some(certify(
                    &self.items,
                    &self.dual,
                    &frame,
                    outcome.x,
                    config.tolerance_m,
                )),
                None => None,
            };
            if let Some(checked) = checked {
                best = Candidate {
                    x: outcome.x,
                    gap_j: checked.gap_j,
                    bound_m: checked.bound_m,
                };
                best_at_sweep = sweeps;
            }
            // The dual method goes on from the primal method's dual (feasible up to rounding; the sweeps project).
            // A certified answer returns at once, below, without it.
            if !outcome.certified {
                total = self.dual.iter().copied().sum::<DVec3>();
            }
        }
        loop {
            if best.bound_m <= config.tolerance_m {
                return Ok(finish(
                    best,
                    sweeps,
                    newton_passes,
                    rounds,
                    SolveStatus::Certified,
                ));
            }
            if over_budget(sweeps) {
                if !best.bound_m.is_finite() {
                    // Out of budget before any pass: the warm start, projected onto this tick's sets (it is
                    // what `primitive_forces_n` reports).
                    for (item, u) in self.items.iter().zip(self.dual.iter_mut()) {
                        *u = project(item, *u);
                    }
                    total = self.dual.iter().copied().sum::<DVec3>();
                    best = self.certify_dual(&frame, total);
                }
                let status = if best.bound_m <= config.tolerance_m {
                    SolveStatus::Certified
                } else {
                    best = self.least_energy(&frame, best, newton_x, start_x());
                    if best.bound_m <= config.tolerance_m {
                        SolveStatus::Certified
                    } else {
                        SolveStatus::BudgetExhausted
                    }
                };
                return Ok(finish(best, sweeps, newton_passes, rounds, status));
            }
            if sweeps - best_at_sweep >= STALL_SWEEPS {
                let best = self.least_energy(&frame, best, newton_x, start_x());
                let status = if best.bound_m <= config.tolerance_m {
                    SolveStatus::Certified
                } else {
                    SolveStatus::Stalled
                };
                return Ok(finish(best, sweeps, newton_passes, rounds, status));
            }
            let round_sweeps = config.sweeps_per_round.max(1);
            for sweep_in_round in 1..=round_sweeps {
                total = self.sweep(y, k, total, sweeps % 2 == 1);
                sweeps += 1;
                // A certificate costs about a sweep: check after sweeps 1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 15, ...
                // (at most a quarter of the sweeps are run past the one that met the tolerance), always at the
                // end of a round and when the budget is spent.
                // Large scenes check only at the end of a round: their sweeps rarely certify alone, and the
                // active-set attempt that follows does.
                let check_due =
                    sweeps >= next_check && self.items.len() <= CHECK_EVERY_SWEEP_MAX_ITEMS;
                if !check_due && sweep_in_round < round_sweeps && !over_budget(sweeps) {
                    continue;
                }
                next_check = sweeps + (sweeps / 4).max(1);
                let candidate = self.certify_dual(&frame, total);
                if candidate.bound_m < best.bound_m {
                    if candidate.bound_m < 0.5 * best.bound_m {
                        best_at_sweep = sweeps;
                    }
                    best = candidate;
                }
                if best.bound_m <= config.tolerance_m || over_budget(sweeps) {
                    break;
                }
            }
            if best.bound_m <= config.tolerance_m || over_budget(sweeps) || self.items.len() < 2 {
                continue;
            }
            rounds += 1;
            self.candidate_dual.clear();
            self.candidate_dual.extend_from_slice(&self.dual);
            // The guess starts from the best point so far, or, after an attempt from there did not improve on
            // it, from the sweeps' current point: the best point can sit where the guess is wrong (a proxy on a
            // friction point just under a plane, whose true minimiser is on the plane beside it), and starting
            // there again would repeat the same failed guess every round.
            let start = if retry_from_sweeps {
                y - total / k
            } else {
                best.x
            };
            let attempt = self.active_set.solve(
                &self.items,
                &frame,
                start,
                config.max_flips_per_round,
                &mut self.candidate_dual,
            );
            retry_from_sweeps = true;
            if let Some(x) = attempt {
                let candidate_total = self.candidate_dual.iter().copied().sum::<DVec3>();
                let checked = certify(
                    &self.items,
                    &self.candidate_dual,
                    &frame,
                    x,
                    config.tolerance_m,
                );
                let (gap, bound) = (checked.gap_j, checked.bound_m);
                if bound < best.bound_m {
                    if bound < 0.5 * best.bound_m {
                        best_at_sweep = sweeps;
                    }
                    best = Candidate {
                        x,
                        gap_j: gap,
                        bound_m: bound,
                    };
                    core::mem::swap(&mut self.dual, &mut self.candidate_dual);
                    total = candidate_total;
                    retry_from_sweeps = false;
                }
            }
            // A small warm scene that two active-set rounds could not finish gets the primal method once, from
            // the best point so far (the dual method can stall for its whole budget on a proxy held by a
            // friction point beside a plane; found by `the_bound_holds_on_a_plane_with_friction_tick_after_tick`).
            if !primal_first && !primal_fallback_done && config.primal_newton && rounds >= 2 {
                primal_fallback_done = true;
                let mut over_time =
                    || timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns;
                self.candidate_dual.clear();
                self.candidate_dual.extend_from_slice(&self.dual);
                let attempt = newton::Attempt {
                    items: &self.items,
                    frame: &frame,
                    start: Some(best.x),
                    limits: newton_limits(&config, sweeps),
                };
                let outcome = self
                    .newton
                    .solve(&attempt, &mut self.candidate_dual, &mut over_time);
                sweeps += outcome.passes;
                newton_passes += outcome.passes;
                if let Some(checked) = outcome.certificate {
                    if checked.bound_m < best.bound_m {
                        best = Candidate {
                            x: outcome.x,
                            gap_j: checked.gap_j,
                            bound_m: checked.bound_m,
                        };
                        best_at_sweep = sweeps;
                        core::mem::swap(&mut self.dual, &mut self.candidate_dual);
                        total = self.dual.iter().copied().sum::<DVec3>();
                    }
                }
            }
        }
    }

    /// One block-coordinate sweep over the dual; returns the new `U = sum u_i` (recomputed exactly).
    fn sweep(&mut self, y: DVec3, k: f64, mut total: DVec3, backwards: bool) -> DVec3 {
        let n = self.items.len();
        let w = self.config.relaxation;
        for step in 0..n {
            let i = if backwards { n - 1 - step } else { step };
            let item = &self.items[i];
            let old = self.dual[i];
            let others = total - old;
            let mut u = block_update(item, y, k, others);
            if w != 1.0 {
                u = project(item, old + w * (u - old));
            }
            self.dual[i] = u;
            total = others + u;
        }
        self.dual.iter().copied().sum()
    }

    /// The answer of an exit without a certified point (module header, "Invariants"): of the start `start_x`,
    /// the best certified point `best` and the primal method's last accepted point `newton_x`, the one of least
    /// energy, a point replacing the one before it only where its energy is lower by more than both energies'
    /// rounding (so ties keep the start). Its bound is the smaller of the certificates with the current dual
    /// (or `best`'s own, for `best`) and with the exact subgradients at the point; `dual` keeps the dual of the
    /// bound returned. Allocation-free: the subgradients go to `candidate_dual`, sized for the items.
    #[cold]
    #[inline(never)]
    fn least_energy(
        &mut self,
        frame: &Frame,
        best: Candidate,
        newton_x: Option<DVec3>,
        start_x: DVec3,
    ) -> Candidate {
        let (mut x, mut energy_j, mut rounding_j) = {
            let (e, r) = energy(&self.items, frame, start_x);
            (start_x, e, r)
        };
        let mut is_best = best.x == start_x;
        for (candidate, from_best) in [(Some(best.x), true), (newton_x, false)] {
            let Some(candidate) = candidate.filter(|c| c.is_finite() && *c != x) else {
                continue;
            };
            let (e, r) = energy(&self.items, frame, candidate);
            if e + r < energy_j - rounding_j {
                (x, energy_j, rounding_j, is_best) = (candidate, e, r, from_best);
            }
        }
        let mut chosen = if is_best {
            best
        } else {
            self.certify_dual_at(frame, x)
        };
        self.candidate_dual.clear();
        self.candidate_dual
            .extend_iter(self.items.iter().map(|item| subgradient(item, x)));
        let own = certify(
            &self.items,
            &self.candidate_dual,
            frame,
            x,
            self.config.tolerance_m,
        );
        if own.bound_m < chosen.bound_m {
            core::mem::swap(&mut self.dual, &mut self.candidate_dual);
            chosen = Candidate {
                x,
                gap_j: own.gap_j,
                bound_m: own.bound_m,
            };
        }
        chosen
    }

    #[cold]
    #[inline(never)]
    fn grow_candidate_dual(&mut self, count: usize) {
        self.candidate_dual.reserve_total(count);
    }

    /// `x` with its certificate from the current dual.
    fn certify_dual_at(&self, frame: &Frame, x: DVec3) -> Candidate {
        let checked = certify(&self.items, &self.dual, frame, x, self.config.tolerance_m);
        Candidate {
            x,
            gap_j: checked.gap_j,
            bound_m: checked.bound_m,
        }
    }

    /// The primal point of the current dual and its certificate.
    fn certify_dual(&self, frame: &Frame, total: DVec3) -> Candidate {
        let x = frame.y - total / frame.k;
        let checked = certify(&self.items, &self.dual, frame, x, self.config.tolerance_m);
        Candidate {
            x,
            gap_j: checked.gap_j,
            bound_m: checked.bound_m,
        }
    }
}

/// The energy `P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)` (J, the module header's, up to a constant) and a
/// bound on its rounding error, for comparing two points' energies. Each term is within a few eps of
/// `s_i (dist_i + |x - c_i|_1)` (the difference `x - c_i` is rounded per coordinate, a dot product with a unit
/// direction adds three eps), the sum of `N + 1` terms adds `N + 1` eps of the running sums, and `y`'s own
/// rounding (`frame.y_error_m`) moves the coupling term by at most `k |x - y| y_error`; the bound is eight
/// times that.
fn energy(items: &[Item], frame: &Frame, x: DVec3) -> (f64, f64) {
    let offset = x - frame.y;
    let mut energy_j = 0.5 * frame.k * offset.length_squared();
    let mut magnitude_j = energy_j;
    for item in items {
        let r = x - item.position_m;
        let distance_m = match item.kind {
            PrimitiveKind::Point => r.length(),
            PrimitiveKind::Line => (r - item.direction * item.direction.dot(r)).length(),
            PrimitiveKind::Plane => (-item.direction.dot(r)).max(0.0),
            PrimitiveKind::Directed => 0.0,
        };
        energy_j += item.strength_n * distance_m;
        magnitude_j += item.strength_n * (distance_m + r.abs().element_sum());
    }
    let rounding_j = 8.0 * (items.len() as f64 + 8.0) * f64::EPSILON * magnitude_j
        + 8.0 * frame.k * offset.length() * frame.y_error_m;
    (energy_j, rounding_j)
}

/// The primal Newton method's limits with `sweeps` of the sweep budget already spent.
fn newton_limits(config: &SolverConfig, sweeps: u32) -> newton::Limits {
    newton::Limits {
        tolerance_m: config.tolerance_m,
        max_passes: config
            .max_sweeps
            .saturating_sub(sweeps)
            .min(NEWTON_MAX_PASSES),
        screening: config.screening,
    }
}

#[cfg(test)]
#[path = "tests.rs"]
mod tests;
