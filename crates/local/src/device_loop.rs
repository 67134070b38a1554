//! One cycle of the local loop (protocol/SPEC.md section 10.5): sense, solve, couple, passivity (observe and
//! control, [`crate::passivity`]), clamp, ramp, slew, apply, report.
//!
//! Where it sits: a firmware (or `voxhap mock-device`) calls [`LocalLoop::step`] once per control cycle instead of
//! `DeviceSession::poll`; `step` polls the session itself (watchdog, State frames), renders the session's local
//! model when there is one, and otherwise returns the session's set-force force unchanged.

use crate::passivity::{DevicePassivity, PassivityTotals};
use crate::ramp::{clamp, norm, slew_limit, Ramp, RampState};
use glam::DVec3;
use voxhap_protocol::local::MAX_BOUND_M;
use voxhap_protocol::{
    DeviceSample, DeviceSession, DriveState, LocalKind, LocalModel, LocalPassivity, LocalStatus,
    LocalTick, ModelFlags, MAX_LOCAL_PRIMITIVES,
};
use voxhap_solver::storage::Fixed;
use voxhap_solver::{Primitive, PrimitiveError, Problem, Solver, SolverConfig};

/// The solver settings of the device loop: a 0.1 µm tolerance (the SPEC asks for the applied force within
/// `k (bound + 1 µm)`) and at most 32 passes per solve, which bounds every solve's time (docs/local-model.md
/// measures the worst case). Rounds of the active-set finish are cut to 8 flips (three items need no more). The
/// certificate is formed once per check, without the balancing second attempt (`rebalance_certificate`), which
/// earns sub-nanometre bounds the 0.1 µm tolerance does not need and a solve that never reaches its tolerance
/// would pay at every check.
pub const DEVICE_SOLVER_CONFIG: SolverConfig = SolverConfig {
    tolerance_m: 1e-7,
    max_sweeps: 32,
    max_flips_per_round: 8,
    rebalance_certificate: false,
    ..SolverConfig::DEFAULT
};

/// Settings of a [`LocalLoop`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopConfig {
    /// The solver's tolerance and budget.
    pub solver: SolverConfig,
    /// The control period assumed for the first cycle (later ones use the measured time), microseconds.
    pub period_us: u32,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            solver: DEVICE_SOLVER_CONFIG,
            period_us: 100,
        }
    }
}

/// Longest time step the ramps and the slew limit take from one cycle (a stalled loop does not jump), µs.
const MAX_DT_US: u64 = 10_000;

/// The model being rendered, in the solver's terms.
#[derive(Debug, Clone, Copy)]
struct Installed {
    sequence: u32,
    received_us: u64,
    primitives: [Option<Primitive>; MAX_LOCAL_PRIMITIVES],
    stiffness_n_per_m: f64,
    damping_n_s_per_m: f64,
    force_limit_n: f64,
    expiry_us: u64,
    truncated: bool,
    /// The sum of the directed slots' forces, N (the part of the coupling force meant to do work).
    directed_n: DVec3,
    passivity: LocalPassivity,
    /// A solve exceeded [`MAX_BOUND_M`]: rendered as expired from then on.
    no_solution: bool,
}

/// The device's local loop: the solver's fixed workspace, the model in use, the proxy, the ramp and the force.
#[derive(Debug, Clone)]
pub struct LocalLoop {
    config: LoopConfig,
    solver: Solver<Fixed<MAX_LOCAL_PRIMITIVES>>,
    model: Option<Installed>,
    proxy_m: Option<DVec3>,
    bound_m: f64,
    ramp: Ramp,
    force_n: [f64; 3],
    last_us: Option<u64>,
    status: LocalStatus,
    passivity: DevicePassivity,
}

impl LocalLoop {
    /// A loop with nothing to render yet.
    pub fn new(config: LoopConfig) -> Self {
        Self {
            config,
            solver: Solver::new_in(config.solver, MAX_LOCAL_PRIMITIVES),
            model: None,
            proxy_m: None,
            bound_m: 0.0,
            ramp: Ramp::default(),
            force_n: [0.0; 3],
            last_us: None,
            status: LocalStatus::EMPTY,
            passivity: DevicePassivity::default(),
        }
    }

    /// The device-side proxy, metres (`None` before the first local solve).
    pub fn proxy_m(&self) -> Option<[f64; 3]> {
        self.proxy_m.map(|p| p.to_array())
    }

    /// The force applied in the last cycle (the local force, or the set-force path's), newtons.
    pub fn force_n(&self) -> [f64; 3] {
        self.force_n
    }

    /// What the last cycle did (empty when it rendered no local model).
    pub fn last_status(&self) -> LocalStatus {
        self.status
    }

    /// The passivity observer's and controller's totals (SPEC 10.5 step 4b).
    pub fn passivity_totals(&self) -> PassivityTotals {
        self.passivity.totals()
    }

    /// The ramp factor now (0 to 1).
    pub fn ramp_factor(&self) -> f64 {
        self.ramp.factor()
    }

    /// One control cycle at `now_us` with what the device senses: polls `session` (watchdog, State and
    /// LocalState frames), then renders its local model if it has one, and returns the force to apply, newtons.
    /// Without a local model (not enabled, or driven by SetForce) it returns the session's force unchanged.
    pub fn step(
        &mut self,
        session: &mut DeviceSession,
        now_us: u64,
        sample: &DeviceSample,
    ) -> [f32; 3] {
        let set_force = session.poll(now_us, sample);
        let elapsed_us = match self.last_us {
            Some(last) => now_us.saturating_sub(last),
            None => u64::from(self.config.period_us),
        };
        self.last_us = Some(now_us);
        let Some((model, received_us)) = session.local_model() else {
            self.model = None;
            self.passivity.gap();
            if session.drive_state() != DriveState::Enabled {
                // Disable, a fault, the watchdog or a Hello: the next Enable engages from zero (SPEC 10.5 step 6).
                self.ramp.reset();
                self.passivity.reset();
            }
            // Otherwise a SetForce drives the device: the host's force, past the host's own engage rule and slew
            // limit, is applied, and the ramp holds, so that a host falling back to SetForce for a tick does not
            // restart the 0.5 s engage ramp. The next local cycle's slew limit runs from this applied force.
            self.force_n = set_force.map(f64::from);
            self.status = LocalStatus::EMPTY;
            return set_force;
        };
        let sample_ok = sample
            .position_m
            .iter()
            .chain(&sample.velocity_m_per_s)
            .all(|v| v.is_finite());
        if !sample_ok {
            // The session has raised ENCODER (and left Enabled); nothing to solve against.
            self.force_n = [0.0; 3];
            self.passivity.gap();
            return [0.0; 3];
        }
        let fresh = self
            .model
            .is_none_or(|m| m.sequence != model.sequence || m.received_us != received_us);
        if fresh {
            self.model = Some(install(model, received_us));
        }
        let max_force_n = f64::from(session.info().max_force_n);
        let (force, tick) = match self.model {
            Some(installed) => self.render(installed, now_us, elapsed_us, sample, max_force_n),
            None => ([0.0; 3], LocalTick::default()),
        };
        session.record_local_tick(&tick);
        self.status = tick.status;
        force
    }

    fn render(
        &mut self,
        mut m: Installed,
        now_us: u64,
        elapsed_us: u64,
        sample: &DeviceSample,
        max_force_n: f64,
    ) -> ([f32; 3], LocalTick) {
        let probe = DVec3::from_array(sample.position_m.map(f64::from));
        let velocity = DVec3::from_array(sample.velocity_m_per_s.map(f64::from));
        let mut status = LocalStatus::EMPTY;
        let previous_proxy_m = self.proxy_m;
        let solver = &mut self.solver;
        let solved = with_slice(&m.primitives, |primitives| {
            solver.solve(&Problem {
                stiffness_n_per_m: m.stiffness_n_per_m,
                probe_m: probe,
                previous_proxy_m,
                primitives,
            })
        });
        match solved {
            Ok(solution) if solution.error_bound_m <= MAX_BOUND_M => {
                self.proxy_m = Some(solution.proxy_m);
                self.bound_m = solution.error_bound_m;
            }
            Ok(solution) => {
                m.no_solution = true;
                self.bound_m = solution.error_bound_m;
                status = status | LocalStatus::NO_SOLUTION;
            }
            Err(_) => {
                m.no_solution = true;
                status = status | LocalStatus::NO_SOLUTION;
            }
        }
        let proxy = self.proxy_m.unwrap_or(probe);
        let coupling = m.stiffness_n_per_m * (proxy - probe) - m.damping_n_s_per_m * velocity;
        // Rises (engage, slew) take at most MAX_DT_US from one cycle; the ramp-down takes all the time that
        // passed, so a late cycle never leaves the force up longer than 5 ms past the expiry.
        let dt_us = elapsed_us.min(MAX_DT_US);
        // Step 4b: the passivity observer books the step just moved, the controller adds its damping.
        let stretch = proxy - m.directed_n / m.stiffness_n_per_m - probe;
        let control = self.passivity.observe_and_control(
            m.passivity,
            m.stiffness_n_per_m,
            probe,
            velocity,
            stretch,
            dt_us as f64 * 1e-6,
        );
        let asked = coupling + control;
        let limit = m.force_limit_n.min(max_force_n);
        let (clamped, was_clamped) = clamp(asked.to_array(), limit);
        let age_us = now_us.saturating_sub(m.received_us);
        let live = age_us <= m.expiry_us && !m.no_solution;
        let state = self
            .ramp
            .update(if live { dt_us } else { elapsed_us }, live, norm(clamped));
        let scaled = clamped.map(|f| f * self.ramp.factor());
        let (force, slewed) = slew_limit(scaled, norm(self.force_n), dt_us);
        self.force_n = force;
        let force_f32 = force.map(|f| f as f32);
        // The observer books the force the motors get (the f32 sent to them), held until the next cycle.
        self.passivity.applied(
            m.passivity,
            asked,
            DVec3::from_array(force_f32.map(f64::from)),
            m.directed_n,
        );
        if let Some(installed) = self.model.as_mut() {
            installed.no_solution = m.no_solution;
        }
        status = status
            .with(
                LocalStatus::ACTIVE,
                self.ramp.factor() > 0.0 || state != RampState::Down,
            )
            .with(LocalStatus::EXPIRED, !live)
            .with(LocalStatus::CLAMPED, was_clamped)
            .with(LocalStatus::SLEW_LIMITED, slewed)
            .with(LocalStatus::ENGAGING, state == RampState::Engaging)
            .with(LocalStatus::TRUNCATED, m.truncated)
            .with(LocalStatus::DISSIPATING, control != DVec3::ZERO);
        let tick = LocalTick {
            model_sequence: m.sequence,
            model_age_us: u32::try_from(age_us).unwrap_or(u32::MAX),
            proxy_m: proxy.to_array().map(|c| c as f32),
            force_n: force_f32,
            bound_m: self.bound_m as f32,
            status,
        };
        (force_f32, tick)
    }
}

/// Calls `f` with the filled slots as a slice (the solver takes one); slots fill from the first.
fn with_slice<R>(
    primitives: &[Option<Primitive>; MAX_LOCAL_PRIMITIVES],
    f: impl FnOnce(&[Primitive]) -> R,
) -> R {
    match *primitives {
        [Some(a), Some(b), Some(c)] => f(&[a, b, c]),
        [Some(a), Some(b), None] => f(&[a, b]),
        [Some(a), None, _] => f(&[a]),
        _ => f(&[]),
    }
}

/// The model in the solver's terms. A slot the solver refuses (it cannot happen for a decoded model: its
/// directions are unit and its strengths finite) marks the model as without a solution.
fn install(model: &LocalModel, received_us: u64) -> Installed {
    let mut primitives = [None; MAX_LOCAL_PRIMITIVES];
    let mut refused = false;
    let mut directed_n = DVec3::ZERO;
    for (slot, p) in primitives.iter_mut().zip(model.si_primitives()) {
        let position = DVec3::from_array(p.position_m);
        let direction = DVec3::from_array(p.direction);
        let built: Result<Primitive, PrimitiveError> = match p.kind {
            LocalKind::Directed => {
                directed_n += direction * p.strength_n;
                Primitive::directed(direction, p.strength_n)
            }
            LocalKind::Point => Primitive::point(position, p.strength_n),
            LocalKind::Line => Primitive::line(position, direction, p.strength_n),
            LocalKind::Plane => Primitive::plane(position, direction, p.strength_n),
        };
        match built {
            Ok(primitive) => *slot = Some(primitive),
            Err(_) => refused = true,
        }
    }
    Installed {
        sequence: model.sequence,
        received_us,
        primitives,
        stiffness_n_per_m: f64::from(model.stiffness_n_per_m),
        damping_n_s_per_m: model.damping_n_s_per_m(),
        force_limit_n: model.force_limit_n(),
        expiry_us: u64::from(model.expiry_us),
        truncated: model.flags.contains(ModelFlags::TRUNCATED),
        directed_n,
        passivity: model.passivity,
        no_solution: refused,
    }
}
