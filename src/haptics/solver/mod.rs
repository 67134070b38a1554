//! The exact proxy solver: the proxy position that minimises the energy of DESIGN.md section 2, with a
//! certificate of its accuracy on every answer.
//!
//! # The maths
//!
//! With probe `p`, coupling stiffness `k` and the sum of directed forces `d`, put `y = p + d/k`. The proxy
//! minimises the k-strongly convex energy
//!
//! ```text
//!     P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)            (plus a constant)
//! ```
//!
//! where `C_i` is the point, the line or the half-space `(x - x_i).q_i >= 0` of primitive `i`. Each distance term
//! is a support function, `s_i dist(x, C_i) = max_{u in U_i} u.(x - x_i)`, with `U_i` a ball of radius `s_i`
//! (point), a disc of radius `s_i` orthogonal to `q_i` (line) or the segment `{-t q_i : 0 <= t <= s_i}` (plane).
//! Minimising over `x` first gives the dual, to be maximised:
//!
//! ```text
//!     D(u) = -|U|^2/(2k) + sum_i u_i.(y - x_i),   U = sum_i u_i,   x(u) = y - U/k
//! ```
//!
//! `-u_i` is the force primitive `i` exerts on the proxy.
//!
//! **Block coordinate ascent.** Holding the others, the best `u_i` is the Euclidean projection of
//! `k (y - x_i) - sum_{j != i} u_j` onto `U_i` (the dual Hessian is isotropic), a closed form. A sweep is O(N).
//! Sweeps alternate direction (symmetric Gauss-Seidel).
//!
//! **Certificate.** For any `x` and any feasible `u`, the duality gap splits into non-negative pieces that are
//! computed without cancellation (so it stays meaningful down to ~1e-30 J):
//!
//! ```text
//!     gap = P(x) - D(u) = sum_i [ s_i dist(x, C_i) - u_i.(x - x_i) ] + |k (x - y) + U|^2 / (2k)
//! ```
//!
//! Strong convexity gives `|x - x*| <= sqrt(2 gap / k)`. Every answer carries this bound. Distances to a kink
//! below 8 machine epsilons of the coordinates (about 1e-18 m at 1 cm from the origin) are rounding, not solver
//! error: the gap counts them as zero and the bound adds that floor instead, since the square root would
//! otherwise turn 1e-19 m of rounding into a claimed 1e-11 m.
//!
//! **Active-set finish** ([`active_set`]). Near-parallel planes make sweeps crawl (like alternating projections).
//! After a few sweeps the solver guesses which primitives sit on their kink, solves the smooth model on that
//! affine set with Newton steps (x is in R^3, so each is a 3x3 solve), recovers the kink multipliers by least
//! squares and flips statuses until the guess is consistent. The answer is accepted only when the certificate
//! says so; otherwise sweeps go on from the improved dual.
//!
//! # Real time
//!
//! `Solver` owns its workspace. After the first solve with N primitives, solving any scene of at most N
//! primitives allocates nothing (a counting-allocator test proves it). The budget bounds sweeps and, when a
//! clock is given, nanoseconds; the solver always returns its best point with its certificate.

pub mod active_set;
pub mod linalg;

use crate::clock::Clock;
use crate::haptics::primitive::{Primitive, PrimitiveKind};
use glam::DVec3;
use serde::Serialize;

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverConfig {
    /// Stop when the certified error bound `sqrt(2 gap / k)` is at most this many metres.
    pub tolerance_m: f64,
    /// Most block-coordinate sweeps per solve.
    pub max_sweeps: u32,
    /// Most wall-clock nanoseconds per solve; only enforced by [`Solver::solve_with_clock`].
    pub max_time_ns: u64,
    /// Sweeps between active-set attempts.
    pub sweeps_per_round: u32,
    /// Status flips allowed within one active-set attempt.
    pub max_flips_per_round: u32,
    /// Reuse the previous solve's dual variables when the primitive list has the same kinds in the same order.
    pub warm_start_dual: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            tolerance_m: 1e-12,
            max_sweeps: 100_000,
            max_time_ns: u64::MAX,
            sweeps_per_round: 6,
            max_flips_per_round: 48,
            warm_start_dual: true,
        }
    }
}

/// One proxy problem: the coupling, the probe, and the primitives.
#[derive(Debug, Clone, Copy)]
pub struct Problem<'a> {
    pub stiffness_n_per_m: f64,
    pub probe_m: DVec3,
    /// Where the proxy was last tick; used to warm-start when the previous dual cannot be reused.
    pub previous_proxy_m: Option<DVec3>,
    pub primitives: &'a [Primitive],
}

/// Why a problem was refused. Primitives are validated when they are built, so only the coupling can be bad.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SolveError {
    #[error("stiffness must be a finite number > 0 N/m, got {0}")]
    BadStiffness(f64),
    #[error("probe position must be three finite numbers (m), got {0:?}")]
    BadProbe([f64; 3]),
    #[error("previous proxy position must be three finite numbers (m), got {0:?}")]
    BadPreviousProxy([f64; 3]),
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// The certified error bound is within the tolerance.
    Certified,
    /// The sweep or time budget ran out first; the answer is the best found, with its (honest) bound.
    BudgetExhausted,
    /// The bound stopped improving (2000 sweeps without halving) above the tolerance: the scene is at the limit
    /// of f64 precision for that tolerance. The answer is the best found, with its (honest) bound.
    Stalled,
}

/// The proxy position with its certificate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Solution {
    /// The proxy position (m).
    pub proxy_m: DVec3,
    /// The coupling force sent to the device, `k (proxy - probe)` (N).
    pub force_n: DVec3,
    /// Block-coordinate sweeps run.
    pub sweeps: u32,
    /// Active-set attempts run.
    pub active_set_rounds: u32,
    /// Duality gap of the returned pair (J).
    pub gap_j: f64,
    /// Certified bound on the distance to the true minimiser, `sqrt(2 gap / k)` (m).
    pub error_bound_m: f64,
    pub status: SolveStatus,
}

/// A non-directed primitive as the solver sees it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Item {
    pub kind: PrimitiveKind,
    pub position_m: DVec3,
    pub direction: DVec3,
    pub strength_n: f64,
    /// The rounding floor of this item's own coordinates (see [`position_floor_m`]).
    pub floor_m: f64,
}

/// The solver and its workspace (STYLE.md item 3: allocate up front, `clear()` instead of rebuild).
#[derive(Debug, Clone)]
pub struct Solver {
    config: SolverConfig,
    items: Vec<Item>,
    dual: Vec<DVec3>,
    /// The active-set attempt writes here; it replaces `dual` only if it certifies a better point.
    candidate_dual: Vec<DVec3>,
    /// Whether `items` and `dual` hold the previous solve's values (false after `reset`).
    has_previous_dual: bool,
    active_set: active_set::Workspace,
}

/// A primal point with its certificate.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    x: DVec3,
    gap_j: f64,
    bound_m: f64,
}

/// Sweeps without halving the bound after which a solve stops as [`SolveStatus::Stalled`]: the bound has reached
/// the floating-point floor of the scene and more sweeps cannot help.
const STALL_SWEEPS: u32 = 2000;

/// A clock for solves without a time budget: never read.
struct NoClock;

impl Clock for NoClock {
    fn now_ns(&self) -> u64 {
        0
    }
}

impl Default for Solver {
    fn default() -> Self {
        Self::new(SolverConfig::default())
    }
}

impl Solver {
    pub fn new(config: SolverConfig) -> Self {
        Self::with_capacity(config, 16)
    }

    /// A solver whose workspace already holds `max_primitives`, so that no solve of that size allocates.
    pub fn with_capacity(config: SolverConfig, max_primitives: usize) -> Self {
        Self {
            config,
            items: Vec::with_capacity(max_primitives),
            dual: Vec::with_capacity(max_primitives),
            candidate_dual: Vec::with_capacity(max_primitives),
            has_previous_dual: false,
            active_set: active_set::Workspace::with_capacity(max_primitives),
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
        let start_ns = if timed { clock.now_ns() } else { 0 };
        let config = self.config;

        // y = probe + (sum of directed forces) / k; the rest become items.
        let mut directed = DVec3::ZERO;
        // Build the items in place; the previous dual is reused when the kinds match one for one.
        let mut count = 0;
        let mut same_structure = self.config.warm_start_dual && self.has_previous_dual;
        let mut strength_sum = 0.0;
        for p in problem.primitives {
            if p.kind() == PrimitiveKind::Directed {
                directed += p.strength_n() * p.direction();
                continue;
            }
            let item = Item {
                kind: p.kind(),
                position_m: p.position_m(),
                direction: p.direction(),
                strength_n: p.strength_n(),
                floor_m: ROUNDING_SLACK * p.position_m().abs().max_element(),
            };
            strength_sum += item.strength_n;
            if count < self.items.len() {
                same_structure &= self.items[count].kind == item.kind;
                self.items[count] = item;
            } else {
                same_structure = false;
                self.items.push(item);
            }
            count += 1;
        }
        same_structure &= count == self.items.len() && count == self.dual.len();
        self.items.truncate(count);
        let y = problem.probe_m + directed / k;
        // The previous dual need not be projected onto this tick's sets: the first sweep replaces every u_i by a
        // projection before any certificate is taken.
        if !same_structure {
            self.dual.clear();
            for item in &self.items {
                self.dual.push(
                    problem
                        .previous_proxy_m
                        .map_or(DVec3::ZERO, |x| subgradient(item, x)),
                );
            }
        }
        self.has_previous_dual = true;
        let position_floor = position_floor_m(y, strength_sum, k);

        let mut sweeps = 0u32;
        let mut rounds = 0u32;
        let mut total = self.dual.iter().copied().sum::<DVec3>();
        // With primitives, at least one sweep always runs, so the warm start is not certified separately
        // (it saves a gap evaluation per tick; warm starts are rarely exact because primitives move).
        let mut best = if self.items.is_empty() {
            self.certify_dual(y, k, total, position_floor)
        } else {
            Candidate {
                x: y - total / k,
                gap_j: f64::INFINITY,
                bound_m: f64::INFINITY,
            }
        };
        let mut best_at_sweep = 0u32;
        let finish = |best: Candidate, sweeps, rounds, status| Solution {
            proxy_m: best.x,
            force_n: k * (best.x - problem.probe_m),
            sweeps,
            active_set_rounds: rounds,
            gap_j: best.gap_j,
            error_bound_m: best.bound_m,
            status,
        };
        let over_budget = |sweeps: u32| {
            sweeps >= config.max_sweeps
                || (timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns)
        };
        loop {
            if best.bound_m <= config.tolerance_m {
                return Ok(finish(best, sweeps, rounds, SolveStatus::Certified));
            }
            if over_budget(sweeps) {
                if !best.bound_m.is_finite() {
                    best = self.certify_dual(y, k, total, position_floor);
                }
                return Ok(finish(best, sweeps, rounds, SolveStatus::BudgetExhausted));
            }
            if sweeps - best_at_sweep >= STALL_SWEEPS {
                return Ok(finish(best, sweeps, rounds, SolveStatus::Stalled));
            }
            for _ in 0..config.sweeps_per_round.max(1) {
                total = self.sweep(y, k, total, sweeps % 2 == 1);
                sweeps += 1;
                let candidate = self.certify_dual(y, k, total, position_floor);
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
            let attempt = self.active_set.solve(
                &self.items,
                y,
                k,
                best.x,
                config.max_flips_per_round,
                &mut self.candidate_dual,
            );
            if let Some(x) = attempt {
                let candidate_total = self.candidate_dual.iter().copied().sum::<DVec3>();
                let (gap, bound) = certificate(
                    &self.items,
                    &self.candidate_dual,
                    y,
                    k,
                    x,
                    candidate_total,
                    position_floor,
                );
                if bound < best.bound_m {
                    if bound < 0.5 * best.bound_m {
                        best_at_sweep = sweeps;
                    }
                    best = Candidate {
                        x,
                        gap_j: gap,
                        bound_m: bound,
                    };
                    std::mem::swap(&mut self.dual, &mut self.candidate_dual);
                    total = candidate_total;
                }
            }
        }
    }

    /// One block-coordinate sweep over the dual; returns the new `U = sum u_i` (recomputed exactly).
    fn sweep(&mut self, y: DVec3, k: f64, mut total: DVec3, backwards: bool) -> DVec3 {
        let n = self.items.len();
        for step in 0..n {
            let i = if backwards { n - 1 - step } else { step };
            let item = &self.items[i];
            let others = total - self.dual[i];
            let u = project(item, k * (y - item.position_m) - others);
            self.dual[i] = u;
            total = others + u;
        }
        self.dual.iter().copied().sum()
    }

    /// The primal point of the current dual and its certificate.
    fn certify_dual(&self, y: DVec3, k: f64, total: DVec3, position_floor: f64) -> Candidate {
        let x = y - total / k;
        let (gap_j, bound_m) = certificate(&self.items, &self.dual, y, k, x, total, position_floor);
        Candidate { x, gap_j, bound_m }
    }
}

/// Euclidean projection of `v` onto the dual set `U_i` of an item.
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

/// Relative slack below which `s - |u|` counts as zero: `|u|` of a vector scaled to length `s` is `s` only to a
/// few ulps, and without this the gap would floor at `s * dist * 1e-16` instead of converging.
const ROUNDING_SLACK: f64 = 8.0 * f64::EPSILON;

/// The rounding floor of a position computed as `x = y - (sum_i u_i)/k`: 8 machine epsilons of `|x|`, `|y|`
/// and `sum_i |u_i| / k` (the sum of many forces loses that much). Since `|u_i| <= s_i`, both `|x|` and the sum
/// are bounded by `|y| + sum_i s_i / k`, so the floor is fixed for a solve: `8 eps (2 |y| + 2 sum_i s_i / k)`.
/// A distance to a kink below this floor (plus the kink's own coordinates) is representation error, not solver
/// error: the gap counts it as zero and [`error_bound_m`] adds the floor to the bound instead (the square root
/// would otherwise turn 1e-19 m of rounding into a claimed 1e-11 m).
pub(crate) fn position_floor_m(y: DVec3, strength_sum_n: f64, k: f64) -> f64 {
    2.0 * ROUNDING_SLACK * (y.abs().max_element() + strength_sum_n / k)
}

/// The certified distance bound: `sqrt(2 gap / k)` plus the rounding floor of the position.
pub(crate) fn error_bound_m(gap_j: f64, k: f64, floor_m: f64) -> f64 {
    (2.0 * gap_j / k).sqrt() + floor_m
}

/// `s dist(x, C) - u.(x - c)` for a ball or disc, written as two non-negative terms so that nothing cancels:
/// `(s - |u|) |r| + (|u| |r| - u.r)`.
fn ball_gap(s: f64, u: DVec3, r: DVec3, floor_m: f64) -> f64 {
    let rho = r.length();
    if rho <= floor_m {
        return 0.0;
    }
    let a = u.length();
    let slack = if (s - a) <= ROUNDING_SLACK * s {
        0.0
    } else {
        s - a
    };
    // |u||r| - u.r, without cancellation: |u x r|^2 / (|u||r| + u.r) when u.r > 0.
    let dot = u.dot(r);
    let angle_term = if dot > 0.0 {
        u.cross(r).length_squared() / (a * rho + dot)
    } else {
        a * rho - dot
    };
    slack * rho + angle_term
}

/// One primitive's share of the gap, `s dist(x, C) - u.(x - c) >= 0`, computed without cancellation.
pub(crate) fn item_gap_j(item: &Item, u: DVec3, x: DVec3, position_floor_m: f64) -> f64 {
    let r = x - item.position_m;
    let s = item.strength_n;
    let floor_m = position_floor_m + item.floor_m;
    match item.kind {
        PrimitiveKind::Point => ball_gap(s, u, r, floor_m),
        PrimitiveKind::Line => {
            let q = item.direction;
            ball_gap(s, u - q * q.dot(u), r - q * q.dot(r), floor_m)
        }
        PrimitiveKind::Plane => {
            let q = item.direction;
            let sigma = q.dot(r);
            // u = -t q; recovering t from u is exact only to a few ulps, like |u| for a ball.
            let t = (-q.dot(u)).max(0.0).min(s);
            if sigma.abs() <= floor_m {
                0.0
            } else if sigma > 0.0 {
                if t <= ROUNDING_SLACK * s {
                    0.0
                } else {
                    t * sigma
                }
            } else if s - t <= ROUNDING_SLACK * s {
                0.0
            } else {
                (s - t) * -sigma
            }
        }
        PrimitiveKind::Directed => 0.0,
    }
}

/// The duality gap of the pair `(x, u)` (module docs), in joules, and the bound it certifies, in metres.
/// `total` must be `sum u_i`.
pub(crate) fn certificate(
    items: &[Item],
    dual: &[DVec3],
    y: DVec3,
    k: f64,
    x: DVec3,
    total: DVec3,
    position_floor: f64,
) -> (f64, f64) {
    let mut gap: f64 = items
        .iter()
        .zip(dual)
        .map(|(item, &u)| item_gap_j(item, u, x, position_floor))
        .sum();
    gap += (k * (x - y) + total).length_squared() / (2.0 * k);
    (gap, error_bound_m(gap, k, position_floor))
}

#[cfg(test)]
mod tests;
