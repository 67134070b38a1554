//! The headless sim loop: simulated arm -> tick -> simulated arm, recorded every tick.
//!
//! Place in the data flow (docs/design.md, "Threads", with the device and the clock replaced): each servo tick
//! the arm's position is the probe, [`tick`] renders the force, and the arm integrates one tick of
//! physics (its own substeps) under that force. Time is the tick number divided by the rate (a mock clock
//! nobody reads: the loop is the clock), so runs are deterministic and as fast as the machine allows.
//! Each tick becomes a [`TraceSample`] handed to the caller's [`TraceWriter`]; the tick itself stays pure
//! and allocation-free, the writer does the I/O. The writer is flushed every [`FLUSH_EVERY_TICKS`] ticks
//! (whole CSV lines, a closed MCAP chunk), so a sim killed half-way leaves a trace readable up to at most
//! that many ticks before the kill; the flush points depend only on the tick count, so runs stay
//! byte-for-byte deterministic. The trace's velocity is the one the arm reports (exact, or estimated from
//! quantised positions with `[arm] velocity_window_ticks`); the coupling damping acts on it as in `serve`, and
//! with no safety pipeline in a sim the rendered force is the force sent. Every tick is booked in the energy
//! ledger (crate::energy), whose totals end in the summary.

use super::scenario::{LoadedScenario, ScenarioValueError};
use crate::device::LocalDevice;
use crate::energy::{EnergyLedger, EnergyTotals, SentShare};
use crate::passivity::{
    CouplingTransition, ObserverLatency, PassivityController, PassivityMode, PassivityTotals,
};
use glam::DVec3;
use voxhap_core::haptics::modes::{ModeKind, ModeMemory};
use voxhap_core::haptics::tick::{tick, SolverKind, TickState, TickStatus, TickWorkspace};
use voxhap_device::sim::{SimArm, SimError, StepOutcome};
use voxhap_record::{
    TraceError, TraceSample, TraceWriter, FLAG_NON_FINITE_REPLACED, FLAG_WORKSPACE_LIMIT,
};

/// Ticks between two flushes of the trace writer.
pub const FLUSH_EVERY_TICKS: u64 = 1000;

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum SimRunError {
    #[error(transparent)]
    Arm(#[from] SimError),
    #[error(transparent)]
    Trace(#[from] TraceError),
    /// The scenario's `[local_model]` cannot run (its validation refuses this first).
    #[error(transparent)]
    Scenario(#[from] ScenarioValueError),
}

/// What a run did, for the summary line and the tests.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSummary {
    pub ticks: u64,
    /// Ticks whose exact solve met the tolerance.
    pub certified_ticks: u64,
    /// The largest certificate bound of the run (m); `+inf` when a baseline solver ran.
    pub max_error_bound_m: f64,
    /// The most sweeps one tick took.
    pub max_sweeps: u32,
    /// The largest force magnitude sent (N).
    pub max_force_n: f64,
    /// Ticks with the probe at the workspace limit.
    pub workspace_limit_ticks: u64,
    /// Ticks whose force was not finite and was replaced by zero (by the tick or the arm).
    pub non_finite_ticks: u64,
    /// The energy ledger's totals at the end (crate::energy).
    pub energy: EnergyTotals,
    /// The passivity observer's and controller's totals (crate::passivity).
    pub passivity: PassivityTotals,
    /// The mode the passivity controller ran in.
    pub passivity_mode: PassivityMode,
    /// Changes made in contact by `[[events]]` that were introduced gradually (crate::passivity::transition).
    pub changes_introduced: u64,
    /// `[[events]]` applied.
    pub events_applied: u64,
}

/// Runs `scenario` with `solver`, writing every tick to `writer`; `progress(ticks_done)` is called every
/// 1000 ticks and at the end. The writer is not finished here (the caller owns it).
pub fn run(
    scenario: &LoadedScenario,
    solver: SolverKind,
    writer: &mut dyn TraceWriter,
    mut progress: impl FnMut(u64),
) -> Result<SimSummary, SimRunError> {
    let scene = &scenario.scene;
    let settings = &scenario.scenario;
    let ticks = settings.tick_count();
    let dt_s = settings.dt_s();
    let mut arm = SimArm::new(scenario.arm.clone(), scenario.start_m)?;
    let mut state = TickState::new(arm.position_m());
    // `[local_model]`: the arm is a device whose own loop renders the tick's local model (super::local).
    let mut device = match settings.local_model {
        Some(local) => Some(
            super::local::new_device(
                settings.rate_hz,
                local,
                scenario.arm.physics().declared_at_1khz_n_per_m(dt_s),
            )
            .ok_or(ScenarioValueError::LocalRate {
                local_hz: local.rate_hz,
                servo_hz: settings.rate_hz,
            })?,
        ),
        None => None,
    };
    let mut summary = SimSummary {
        ticks,
        certified_ticks: 0,
        max_error_bound_m: 0.0,
        max_sweeps: 0,
        max_force_n: 0.0,
        workspace_limit_ticks: 0,
        non_finite_ticks: 0,
        energy: EnergyTotals::default(),
        passivity: PassivityTotals::default(),
        passivity_mode: PassivityMode::Off,
        changes_introduced: 0,
        events_applied: 0,
    };
    let mut ledger = EnergyLedger::new(settings.arm.damping_n_s_per_m);
    // The directed-force modes, whose work on the hand is intended (crate::energy).
    let mut active = [false; voxhap_record::MAX_MODES];
    for (slot, mode) in active.iter_mut().zip(&settings.modes) {
        *slot = matches!(mode.kind, ModeKind::VectorForce | ModeKind::GradientForce);
    }
    // The passivity observer and controller, and the passive introduction of changes (crate::passivity):
    // the simulated arm's force acts `[arm] latency_s` after it was sent; the observer pairs with that in
    // whole ticks, or with `[passivity] latency_s` when written.
    let passivity_mode = settings.passivity.mode_for(true);
    let latency_ticks = ObserverLatency::choose(
        &settings.passivity,
        Some(settings.arm.effects.latency_s),
        None,
        dt_s,
    )
    .ticks;
    let mut passivity =
        PassivityController::new(passivity_mode, &settings.passivity, latency_ticks);
    // The local-model device runs the same mode on its own loop (crate::local_model).
    let local_passivity =
        crate::local_model::passivity_request(passivity_mode, &settings.passivity);
    let mut transition = CouplingTransition::new();
    // The scenes of the run: the scenario's, then each event's, with their workspaces (built before it).
    let mut workspaces: Vec<TickWorkspace> = std::iter::once(scene)
        .chain(scenario.events.iter().map(|e| &e.scene))
        .map(|s| TickWorkspace::new(s, solver, settings.solver.solver_config()))
        .collect();
    let mut scene = scene;
    let mut current = 0;
    let mut damping_n_s_per_m = settings.damping_n_s_per_m;
    let mut last_anchor_m = state.proxy_m;
    let mut last_k = scene.stiffness_n_per_m();
    for index in 0..ticks {
        let t_s = index as f64 * dt_s;
        let mut changed = false;
        while let Some(event) = scenario.events.get(current).filter(|e| e.tick <= index) {
            scene = &event.scene;
            damping_n_s_per_m = event.damping_n_s_per_m;
            current += 1;
            changed = true;
            // As `serve` does on a scene swap: what the modes remembered no longer applies.
            state.memory = ModeMemory {
                previous_force_n: state.memory.previous_force_n,
                ..ModeMemory::default()
            };
        }
        let probe_m = arm.position_m();
        let probe_velocity_m_per_s = arm.velocity_m_per_s();
        let out = tick(&mut state, scene, probe_m, dt_s, &mut workspaces[current]);
        let k = scene.stiffness_n_per_m();
        if changed && passivity_mode != PassivityMode::Off {
            transition.begin(probe_m, last_anchor_m, last_k, out.proxy_m, k);
        }
        let (anchor_m, spring_n, anchor_velocity) =
            match transition.anchor(probe_m, out.proxy_m, dt_s) {
                Some((anchor_m, velocity)) => (anchor_m, k * (anchor_m - probe_m), velocity),
                None => (
                    out.proxy_m,
                    out.coupling_force_n,
                    out.proxy_velocity_m_per_s,
                ),
            };
        let mut rendered_n =
            spring_n + damping_n_s_per_m * (anchor_velocity - probe_velocity_m_per_s);
        let active_n: DVec3 = out
            .modes
            .forces_n()
            .iter()
            .zip(&active)
            .filter(|(_, a)| **a)
            .map(|(f, _)| *f)
            .sum();
        // The ledger's coupling energy and the observer's reference: the spring without the directed part,
        // as serve books it (crate::energy::SentShare::reaction_energy_j).
        let coupling_j = SentShare::ALL.reaction_energy_j(k, anchor_m - probe_m, active_n);
        let control_n =
            passivity.observe_and_control(probe_m, probe_velocity_m_per_s, coupling_j, dt_s);
        if control_n != DVec3::ZERO {
            rendered_n += control_n;
        }
        ledger.book_passivity(passivity.totals().dissipated_j);
        let period = match device.as_mut() {
            None => {
                // The set-force path: the rendered force is sent and held for the tick.
                let outcome = arm.step(t_s, dt_s, rendered_n)?;
                let sent_n = if outcome.force_rejected {
                    DVec3::ZERO
                } else {
                    rendered_n
                };
                passivity.sent_with_active(rendered_n, sent_n, active_n);
                summary.energy =
                    ledger.record(t_s, dt_s, probe_m, rendered_n, active_n, coupling_j);
                Period {
                    outcome,
                    force_n: rendered_n,
                    peak_force_n: rendered_n.length(),
                    local: None,
                }
            }
            Some(device) => {
                // The tick's local model, built as `serve` builds it, while its force is valid (as `serve`'s
                // supervisor decides); the device's loop renders it for the period.
                // The arm's state is fresh every tick, and the sim has no compute budget.
                let valid = crate::local_model::force_valid(crate::local_model::ForceChecks {
                    state_fresh: true,
                    status: out.status,
                    force_finite: rendered_n.is_finite(),
                    on_budget: true,
                });
                let offer = crate::local_model::offer(
                    workspaces[current].primitives(),
                    k,
                    damping_n_s_per_m,
                    out.proxy_m,
                )
                .with_passivity(local_passivity);
                if valid {
                    super::local::send(device, Some(&offer), rendered_n);
                } else {
                    super::local::send(device, None, DVec3::ZERO);
                }
                // A set-force the device holds instead is the rendered force, directed modes included.
                let set_force_active_n = if valid { active_n } else { DVec3::ZERO };
                let period = device_period(device, &mut arm, &mut ledger, t_s, set_force_active_n)?;
                summary.energy = ledger.totals();
                passivity.sent_with_active(rendered_n, period.force_n, set_force_active_n);
                period
            }
        };
        last_anchor_m = anchor_m;
        last_k = k;
        let outcome = period.outcome;
        let mut flags = out.flags;
        if outcome.workspace_limit_hit {
            flags |= FLAG_WORKSPACE_LIMIT;
            summary.workspace_limit_ticks += 1;
        }
        if outcome.force_rejected {
            flags |= FLAG_NON_FINITE_REPLACED;
        }
        if flags & FLAG_NON_FINITE_REPLACED != 0 {
            summary.non_finite_ticks += 1;
        }
        writer.write_sample(&TraceSample {
            tick: index,
            t_s,
            probe_m,
            probe_velocity_m_per_s,
            proxy_m: out.proxy_m,
            rendered_force_n: rendered_n,
            sent_force_n: period.force_n,
            modes: out.modes,
            solver_status: out.status.into(),
            sweeps: out.sweeps,
            error_bound_m: out.error_bound_m,
            device_sequence: None,
            device_time_us: None,
            flags,
            truth: voxhap_api::TickTruth {
                energy: summary.energy.tick_energy(),
                device_local: period.local,
                ..voxhap_api::TickTruth::default()
            },
        })?;
        if (index + 1) % FLUSH_EVERY_TICKS == 0 {
            writer.flush()?;
        }
        summary.certified_ticks += u64::from(out.status == TickStatus::Certified);
        summary.max_error_bound_m = summary.max_error_bound_m.max(out.error_bound_m);
        summary.max_sweeps = summary.max_sweeps.max(out.sweeps);
        summary.max_force_n = summary.max_force_n.max(period.peak_force_n);
        if (index + 1) % 1000 == 0 {
            progress(index + 1);
        }
    }
    progress(ticks);
    summary.passivity = passivity.totals();
    summary.passivity_mode = passivity_mode;
    summary.changes_introduced = transition.introduced();
    summary.events_applied = current as u64;
    Ok(summary)
}

/// What the arm did over one tick, and the force the trace shows for it.
struct Period {
    /// The arm's steps, merged (any step at the workspace limit, any force replaced).
    outcome: StepOutcome,
    /// The force sent (set-force path) or the force the device reported applied (local model), N.
    force_n: DVec3,
    /// The largest force magnitude applied during the tick, N.
    peak_force_n: f64,
    /// What the device reported of its loop (local model).
    local: Option<voxhap_api::DeviceLocal>,
}

/// One tick of a local-model device after its model was sent: each control cycle senses the arm, runs the
/// device loop and steps the arm one cycle under the force it returned (held for the cycle), and is booked in
/// `ledger` on its own, so the work stays exact under the device's zero-order hold. The intended work of a
/// cycle is the directed force the device applied in it (`crate::device::LocalDevice::cycle_books`), or on the
/// set-force path the directed modes' part of the force the host sent (`set_force_active_n`).
fn device_period(
    device: &mut LocalDevice,
    arm: &mut SimArm,
    ledger: &mut EnergyLedger,
    t_s: f64,
    set_force_active_n: DVec3,
) -> Result<Period, SimRunError> {
    let cycle_s = device.cycle_s();
    let mut outcome = StepOutcome::default();
    let mut peak_force_n: f64 = 0.0;
    for cycle in 0..device.cycles_per_period() {
        let t_cycle_s = t_s + f64::from(cycle) * cycle_s;
        let position_m = arm.position_m();
        let velocity_m_per_s = arm.velocity_m_per_s();
        let force_n = device.cycle(position_m, velocity_m_per_s);
        device.book_cycle(
            ledger,
            t_cycle_s,
            position_m,
            velocity_m_per_s,
            force_n,
            set_force_active_n,
        );
        let step = arm.step(t_cycle_s, cycle_s, force_n)?;
        outcome.workspace_limit_hit |= step.workspace_limit_hit;
        outcome.force_rejected |= step.force_rejected;
        peak_force_n = peak_force_n.max(force_n.length());
    }
    Ok(Period {
        outcome,
        force_n: device.reported_force_n(),
        peak_force_n,
        local: device.report(),
    })
}
