//! A proxy problem, the solver's settings, and what a solve returns.

use crate::primitive::Primitive;
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
    /// Over-relaxation of the block updates, in `[1, 2)`: `u_i <- proj(u_i + w (u_i^best - u_i))`. 1 is plain
    /// block coordinate ascent.
    pub relaxation: f64,
    /// Try the primal Newton method (`newton.rs`) first; `false` runs the dual method alone (kept for comparison
    /// in the benchmark).
    pub primal_newton: bool,
    /// Screen out planes that provably keep their side at the answer (primal Newton only).
    pub screening: bool,
    /// When certificate B misses the tolerance, form it a second time with the dual of the saturated point or
    /// line nearest its kink balancing the coupling (a friction point a fraction of a nanometre behind a sliding
    /// proxy is certified only this way at a tight tolerance). `false` skips that attempt: every bound stays
    /// valid, some are larger, and a solve that never reaches its tolerance no longer pays it at every check
    /// (the device loop's setting, whose 0.1 µm tolerance does not need it).
    pub rebalance_certificate: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SolverConfig {
    /// The defaults, usable in constants.
    pub const DEFAULT: Self = Self {
        tolerance_m: 1e-12,
        max_sweeps: 100_000,
        max_time_ns: u64::MAX,
        sweeps_per_round: 6,
        max_flips_per_round: 48,
        warm_start_dual: true,
        relaxation: 1.0,
        primal_newton: true,
        screening: true,
        rebalance_certificate: true,
    };
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
    #[error("{given} non-directed primitives given, but this solver's fixed storage holds at most {capacity}")]
    TooManyPrimitives { given: usize, capacity: usize },
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
    /// O(N) passes over the primitives: the primal Newton method's passes plus the dual method's block
    /// sweeps (each is what `max_sweeps` limits).
    pub sweeps: u32,
    /// How many of `sweeps` were primal Newton passes.
    pub newton_passes: u32,
    /// Active-set attempts run.
    pub active_set_rounds: u32,
    /// Duality gap of the returned pair (J).
    pub gap_j: f64,
    /// Certified bound on the distance to the true minimiser, `sqrt(2 gap / k)` (m).
    pub error_bound_m: f64,
    pub status: SolveStatus,
}
