//! The servo tick as a pure function (CONTRIBUTING.md item 1): state, probe position, scene, `dt` and a
//! caller-owned workspace in; proxy, device force and diagnostics out.
//!
//! Place in the data flow (docs/design.md, "Threads"): the servo thread (or `voxhap sim`, with a mock clock)
//! reads the probe position and calls [`tick`]. The tick runs every mode of the [`RenderScene`] at the
//! proxy position of the previous tick, collecting their primitives in the workspace's preallocated
//! buffer, then solves for the new proxy with the chosen solver:
//!
//! - [`SolverKind::Exact`]: [`Solver`] (owned by the workspace, warm-started from the previous dual and
//!   `previous_proxy_m`), certified: the output carries the bound `sqrt(2 gap / k)` on the distance to the
//!   true equilibrium;
//! - [`SolverKind::Euler`] and [`SolverKind::Constraint`]: the paper's baselines, started from the
//!   previous proxy. They have no certificate: the output's `error_bound_m` is `+inf` (the trace
//!   convention for "no certificate") and its status [`TickStatus::Uncertified`].
//!
//! **Viscosity** is rendered implicitly (backward Euler): a viscosity mode with damping `b_i = TF(V)` (N s/m)
//! at the start-of-tick proxy `x0` adds the energy `c_i/2 |x - x0|²`, `c_i = b_i / dt`, to the proxy's, a
//! damper between the proxy and where it was. With `c = Σ c_i` the coupling and the damper together are one
//! spring of stiffness `k + c` towards `(k probe + c x0) / (k + c)` plus a constant, so every solver solves
//! that problem unchanged, and its certificate bounds the distance to the damped equilibrium. The mode's
//! force on the proxy is `c_i (x0 - x) = -b_i v_proxy`; in steady motion the hand feels exactly `-b v`, and
//! every tick the damper dissipates `c |x - x0|²`.
//!
//! **Active modes** (`vector_force`, `gradient_force`) sample their field at the hand, half-way through the
//! tick their force is held for ([`ModeInput`]), not at the proxy the force itself displaced: a conservative
//! field then does no work over a closed loop, to second order in the step.
//!
//! The device force is the coupling `k (proxy - probe)`. A tick reads no clock, does no I/O, takes no
//! lock and allocates nothing once the workspace was made for the scene ([`TickWorkspace::new`]); a
//! counting-allocator integration test runs thousands of multi-mode ticks to prove it. `dt_s` enters the
//! viscous damper, the hand's velocity (active modes' budgets) and the proxy velocity in the output; the tick
//! reads no clock, so a run is deterministic.
//!
//! A non-finite probe position (a device glitch) or a bad `dt_s` leaves the proxy where it was, sends zero
//! force and sets [`FLAG_NON_FINITE_REPLACED`].

use crate::clock::Clock;
use crate::haptics::baselines::{constraint, euler};
use crate::haptics::modes::{ModeInput, ModeMemory, RenderScene, MAX_MODES};
use crate::haptics::{Primitive, Problem, SolveStatus, Solver, SolverConfig};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Flag bits the tick sets, shared with the trace format: `FLAG_SOLVER_BUDGET_HIT` (the exact solver stopped
/// on its budget before the certificate met its tolerance) and `FLAG_NON_FINITE_REPLACED` (the probe position
/// or `dt_s` was not finite; the proxy was held and zero force sent).
pub use crate::status::flags::{FLAG_NON_FINITE_REPLACED, FLAG_SOLVER_BUDGET_HIT};

crate::named_enum! {
    /// Which proxy solver a tick runs.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    #[serde(rename_all = "lowercase")]
    pub enum SolverKind {
        /// The certified exact solver (docs/solver.md).
        #[default]
        Exact => "exact",
        /// The paper's adaptive Euler solver (baseline, uncertified).
        Euler => "euler",
        /// The constraint approach (baseline, uncertified; shows the non-orthogonal artifact).
        Constraint => "constraint",
    }
}

/// How a tick's solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TickStatus {
    /// The exact solver certified its answer within tolerance.
    Certified,
    /// The exact solver ran out of budget; the bound is honest but above tolerance.
    BudgetExhausted,
    /// The exact solver's bound stopped improving (f64 limit); the bound is honest.
    Stalled,
    /// A baseline solver ran: no certificate.
    Uncertified,
    /// The input was not finite; the proxy was held and no force sent.
    InputRejected,
}

/// What persists from tick to tick: the proxy and what modes remember. `Copy`, fixed size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickState {
    /// The proxy position after the last tick (m).
    pub proxy_m: DVec3,
    /// Per-mode memory (surface normals, last device force) for friction.
    pub memory: ModeMemory,
}

impl TickState {
    /// A state with the proxy at `proxy_m` (usually the first probe position) and no contact.
    pub fn new(proxy_m: DVec3) -> Self {
        Self {
            proxy_m,
            memory: ModeMemory::default(),
        }
    }
}

/// The tick's preallocated buffers and the solver. Make one per scene, off the servo thread: ticking a scene
/// with more modes than the workspace was made for still works, but the first such tick allocates.
#[derive(Debug, Clone)]
pub struct TickWorkspace {
    solver_kind: SolverKind,
    solver: Solver,
    euler_config: euler::EulerConfig,
    primitives: Vec<Primitive>,
}

impl TickWorkspace {
    /// A workspace sized for `scene`, using `solver_kind` (the exact solver with `config`).
    pub fn new(scene: &RenderScene, solver_kind: SolverKind, config: SolverConfig) -> Self {
        let capacity = scene.max_primitives().max(1);
        Self {
            solver_kind,
            solver: Solver::with_capacity(config, capacity),
            euler_config: euler::EulerConfig::default(),
            primitives: Vec::with_capacity(capacity),
        }
    }

    pub fn solver_kind(&self) -> SolverKind {
        self.solver_kind
    }

    /// The primitives the last tick solved with.
    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }
}

/// A tick's per-mode breakdown: how many primitives each of the scene's modes emitted and the force they
/// exert on the proxy (N), in the scene's mode order. `Copy`, heap-free (the servo thread passes it on
/// in a [`TickOutput`] and records it in a trace sample).
///
/// Invariant: there are [`count`](Self::count) modes; the slots at and past the count are zero, so they
/// read back as 0 ([`slot`](Self::slot)). A count above [`MAX_MODES`] (a malformed trace sample) is
/// kept as given, with every slot in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeBreakdown {
    primitives: [u16; MAX_MODES],
    forces_n: [DVec3; MAX_MODES],
    count: u8,
}

impl ModeBreakdown {
    /// `count` modes, with no primitives and no force.
    pub const fn zeroed(count: u8) -> Self {
        Self {
            primitives: [0; MAX_MODES],
            forces_n: [DVec3::ZERO; MAX_MODES],
            count,
        }
    }

    /// `count` modes with these primitive counts and forces; the slots at and past `count` are zeroed.
    pub fn new(count: u8, primitives: [u16; MAX_MODES], forces_n: [DVec3; MAX_MODES]) -> Self {
        let mut modes = Self {
            primitives,
            forces_n,
            count,
        };
        modes.set_count(count);
        modes
    }

    /// How many modes.
    pub fn count(&self) -> usize {
        usize::from(self.count)
    }

    /// Makes it `count` modes: the slots at and past `count` are zeroed (those of new modes already are).
    pub fn set_count(&mut self, count: u8) {
        let live = usize::from(count).min(MAX_MODES);
        self.primitives[live..].fill(0);
        self.forces_n[live..].fill(DVec3::ZERO);
        self.count = count;
    }

    /// The primitive counts of the modes.
    pub fn primitives(&self) -> &[u16] {
        &self.primitives[..self.live()]
    }

    /// The forces of the modes (N).
    pub fn forces_n(&self) -> &[DVec3] {
        &self.forces_n[..self.live()]
    }

    /// Mode `mode`'s primitive count and force; 0 and zero force for a slot at or past the count.
    pub fn slot(&self, mode: usize) -> (u16, DVec3) {
        if mode < self.live() {
            (self.primitives[mode], self.forces_n[mode])
        } else {
            (0, DVec3::ZERO)
        }
    }

    /// Each mode's primitive count and force, to fill in.
    pub fn slots_mut(&mut self) -> impl Iterator<Item = (&mut u16, &mut DVec3)> {
        let live = self.live();
        self.primitives[..live]
            .iter_mut()
            .zip(&mut self.forces_n[..live])
    }

    fn live(&self) -> usize {
        self.count().min(MAX_MODES)
    }
}

/// What one tick produces. `Copy`, heap-free.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickOutput {
    /// The new proxy position (m).
    pub proxy_m: DVec3,
    /// The coupling spring's force, `k (proxy - probe)` (N): what the renderer sends before damping and the
    /// safety pipeline.
    pub coupling_force_n: DVec3,
    /// The proxy's velocity over the tick (m/s).
    pub proxy_velocity_m_per_s: DVec3,
    /// What each of the scene's modes contributed: its primitives, and the force they exert on the proxy at
    /// the new position (N), from the exact solver's dual (they sum to `coupling_force_n` within
    /// `k error_bound_m`) or the primitives' force functions for the baselines.
    pub modes: ModeBreakdown,
    /// Exact solver: block sweeps; Euler: iterations; constraint: 1.
    pub sweeps: u32,
    /// Exact solver: active-set rounds; baselines: 0.
    pub active_set_rounds: u32,
    /// Certified bound on the distance from the exact equilibrium (m); `+inf` without a certificate.
    pub error_bound_m: f64,
    pub status: TickStatus,
    /// `FLAG_*` bits.
    pub flags: u32,
}

/// One servo tick (module docs). Pure apart from `state` and `workspace`; no allocation, clock, lock or I/O.
/// The exact solver stops on its sweep budget only, so the result is deterministic.
pub fn tick(
    state: &mut TickState,
    scene: &RenderScene,
    probe_m: DVec3,
    dt_s: f64,
    workspace: &mut TickWorkspace,
) -> TickOutput {
    tick_inner(state, scene, probe_m, dt_s, workspace, None)
}

/// [`tick`] with the exact solver's time budget (`SolverConfig::max_time_ns`) measured on `clock`: the
/// servo thread's variant. The clock is only read, so a mock clock keeps tests deterministic.
pub fn tick_timed(
    state: &mut TickState,
    scene: &RenderScene,
    probe_m: DVec3,
    dt_s: f64,
    workspace: &mut TickWorkspace,
    clock: &dyn Clock,
) -> TickOutput {
    tick_inner(state, scene, probe_m, dt_s, workspace, Some(clock))
}

fn tick_inner(
    state: &mut TickState,
    scene: &RenderScene,
    probe_m: DVec3,
    dt_s: f64,
    workspace: &mut TickWorkspace,
    clock: Option<&dyn Clock>,
) -> TickOutput {
    let mode_count = scene.modes().len().min(MAX_MODES);
    let mut output = TickOutput {
        proxy_m: state.proxy_m,
        coupling_force_n: DVec3::ZERO,
        proxy_velocity_m_per_s: DVec3::ZERO,
        modes: ModeBreakdown::zeroed(mode_count as u8),
        sweeps: 0,
        active_set_rounds: 0,
        error_bound_m: f64::INFINITY,
        status: TickStatus::InputRejected,
        flags: 0,
    };
    if !(probe_m.is_finite() && dt_s.is_finite() && dt_s > 0.0) {
        output.flags |= FLAG_NON_FINITE_REPLACED;
        state.memory.previous_force_n = DVec3::ZERO;
        state.memory.previous_probe_m = None;
        return output;
    }
    let previous_proxy_m = state.proxy_m;
    let k = scene.stiffness_n_per_m();

    workspace.primitives.clear();
    let at = ModeInput::new(
        previous_proxy_m,
        probe_m,
        state.memory.previous_probe_m,
        dt_s,
    );
    state.memory.previous_probe_m = Some(probe_m);
    // Viscous dampers (module docs): c_i = b_i / dt per mode, c their sum.
    let mut damper_n_per_m = [0.0; MAX_MODES];
    for (index, slot) in damper_n_per_m.iter_mut().enumerate().take(mode_count) {
        let c = scene.damping_n_s_per_m(index, previous_proxy_m) / dt_s;
        *slot = if c.is_finite() { c } else { 0.0 };
    }
    let damper_total: f64 = damper_n_per_m.iter().sum();
    let (solve_k, solve_probe_m) = if damper_total > 0.0 {
        let total = k + damper_total;
        let target = (k * probe_m + damper_total * previous_proxy_m) / total;
        if total.is_finite() && target.is_finite() {
            (total, target)
        } else {
            (k, probe_m)
        }
    } else {
        (k, probe_m)
    };
    let mut normals = [DVec3::ZERO; MAX_MODES];
    for (index, ((count_slot, _), normal_slot)) in
        output.modes.slots_mut().zip(normals.iter_mut()).enumerate()
    {
        let (count, normal) = scene.emit(index, &at, &state.memory, &mut workspace.primitives);
        *count_slot = count;
        *normal_slot = normal;
    }

    let primitives = &workspace.primitives;
    let (proxy_m, status) = match workspace.solver_kind {
        SolverKind::Exact => {
            let problem = Problem {
                stiffness_n_per_m: solve_k,
                probe_m: solve_probe_m,
                previous_proxy_m: Some(previous_proxy_m),
                primitives,
            };
            let solved = match clock {
                Some(clock) => workspace.solver.solve_with_clock(&problem, clock),
                None => workspace.solver.solve(&problem),
            };
            match solved {
                Ok(solution) => {
                    output.sweeps = solution.sweeps;
                    output.active_set_rounds = solution.active_set_rounds;
                    output.error_bound_m = solution.error_bound_m;
                    let status = match solution.status {
                        SolveStatus::Certified => TickStatus::Certified,
                        SolveStatus::BudgetExhausted => {
                            output.flags |= FLAG_SOLVER_BUDGET_HIT;
                            TickStatus::BudgetExhausted
                        }
                        SolveStatus::Stalled => TickStatus::Stalled,
                    };
                    (solution.proxy_m, status)
                }
                // Unreachable with a validated scene and a finite probe; hold the proxy rather than panic.
                Err(_) => {
                    output.flags |= FLAG_NON_FINITE_REPLACED;
                    (previous_proxy_m, TickStatus::InputRejected)
                }
            }
        }
        SolverKind::Euler => {
            let solution = euler::solve(
                solve_k,
                solve_probe_m,
                previous_proxy_m,
                primitives,
                &workspace.euler_config,
            );
            output.sweeps = solution.iterations;
            (solution.proxy_m, TickStatus::Uncertified)
        }
        SolverKind::Constraint => {
            let solution = constraint::solve(solve_k, solve_probe_m, previous_proxy_m, primitives);
            output.sweeps = solution.iterations;
            (solution.proxy_m, TickStatus::Uncertified)
        }
    };
    // Guard the numbers (CONTRIBUTING.md item 8): a non-finite proxy from a baseline is never passed on.
    let proxy_m = if proxy_m.is_finite() {
        proxy_m
    } else {
        output.flags |= FLAG_NON_FINITE_REPLACED;
        previous_proxy_m
    };
    let force_n = k * (proxy_m - probe_m);
    if status != TickStatus::InputRejected {
        let exact = workspace.solver_kind == SolverKind::Exact;
        let mut dual_forces = workspace.solver.primitive_forces_n();
        let mut primitives = workspace.primitives.iter();
        for ((&mut count, mode_force_n), damper) in output.modes.slots_mut().zip(damper_n_per_m) {
            for primitive in primitives.by_ref().take(usize::from(count)) {
                let force = if exact && primitive.kind() != crate::haptics::PrimitiveKind::Directed
                {
                    dual_forces.next().unwrap_or(DVec3::ZERO)
                } else {
                    primitive.force_n(proxy_m)
                };
                *mode_force_n += force;
            }
            *mode_force_n += damper * (previous_proxy_m - proxy_m);
        }
    }
    output.proxy_m = proxy_m;
    output.coupling_force_n = force_n;
    output.proxy_velocity_m_per_s = (proxy_m - previous_proxy_m) / dt_s;
    output.status = status;

    state.proxy_m = proxy_m;
    state.memory.plane_normals = normals;
    state.memory.previous_force_n = force_n;
    output
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The invariant, from its statement: only the first `count` slots are live, the rest read back as 0,
    /// and a count that shrinks then grows again does not bring old values back.
    #[test]
    fn a_mode_breakdown_keeps_only_its_live_slots() {
        let mut primitives = [7u16; MAX_MODES];
        primitives[0] = 1;
        primitives[1] = 2;
        let forces_n = [DVec3::new(0.0, 0.0, -1.0); MAX_MODES];
        let mut modes = ModeBreakdown::new(2, primitives, forces_n);
        assert_eq!(modes.count(), 2);
        assert_eq!(modes.primitives(), &[1, 2]);
        assert_eq!(modes.forces_n(), &[DVec3::new(0.0, 0.0, -1.0); 2]);
        assert_eq!(modes.slot(2), (0, DVec3::ZERO), "a slot past the count");

        modes.set_count(1);
        assert_eq!(modes.primitives(), &[1]);
        modes.set_count(2);
        assert_eq!(
            modes.primitives(),
            &[1, 0],
            "the dropped slot came back zeroed"
        );
        assert_eq!(modes.slot(1), (0, DVec3::ZERO));

        for (slot, (n, force_n)) in modes.slots_mut().enumerate() {
            *n = 10 + slot as u16;
            *force_n = DVec3::X;
        }
        assert_eq!(modes.primitives(), &[10, 11]);
        let mut expected_primitives = [0u16; MAX_MODES];
        expected_primitives[..2].copy_from_slice(&[10, 11]);
        let mut expected_forces_n = [DVec3::ZERO; MAX_MODES];
        expected_forces_n[..2].copy_from_slice(&[DVec3::X, DVec3::X]);
        assert_eq!(
            modes,
            ModeBreakdown::new(2, expected_primitives, expected_forces_n)
        );
    }
}
