//! The in-process device with the local-model capability (protocol/SPEC.md section 10): the one simulated
//! device behind `serve` on the simulated arm ([`super::SimDevice::with_local_model`]), `voxhap sim` with
//! `[local_model]` (`crate::sim::runner`) and `voxhap stability` (`crate::sim::stability::local`).
//!
//! A [`LocalDevice`] is the host session that numbers what is sent, the device's protocol session (enabled,
//! through its Hello) and the reference device loop (`voxhap-local`, the code a firmware links, as `voxhap
//! mock-device --local-model` runs it), clocked by its cycle count so that runs are deterministic. The caller
//! owns the arm: each [`LocalDevice::cycle`] senses it, runs the loop and returns the force to hold over the
//! cycle. What the device reports (LocalState, SPEC 10.4) is kept as a host would read it from the link.
//!
//! The energy ledger's split of a cycle ([`LocalDevice::cycle_books`]): the loop applies
//! `F = r (k (x − p) − b v)`, `x` the proxy solved with the directed force `d` in the problem (SPEC 10.5 step 2:
//! `x` minimises `k/2 |x − p − d/k|² + Σ s_i dist(x, C_i)`) and `r ≤ 1` what the clamp, the ramp and the slew
//! limit left of it (each scales the whole vector). So `F = r d + r (R − b v)` with `R = k (x − p − d/k)` the
//! reaction of the model's other primitives: `r d` is the directed force applied, the intended work; `R` derives
//! from the potential `k/2 |x − p − d/k|²` (plus the primitives' own terms), whose share `r² k/2 |x − p − d/k|²`
//! is the coupling energy booked.

use crate::energy::{EnergyLedger, EnergyTotals};
use glam::DVec3;
use voxhap_api::DeviceLocal;
use voxhap_device::local_offer::{LocalOffer, LocalReport};
use voxhap_device::sim::LocalModelSim;
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::{
    DeviceSample, DeviceSession, DeviceToHost, ForceFlags, HostSession, HostToDevice, Label,
    LocalBuildError, LocalKind, LocalState, RateSet, PROTOCOL_VERSION,
};
use voxhap_solver::Primitive;

/// The watchdog timeout of the Enable the device is given, µs.
const WATCHDOG_US: u32 = 50_000;

/// Why a simulated local loop cannot run at the rate asked.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "local_model.rate_hz: {rate_hz} Hz must be a whole multiple of the servo rate ({servo_hz} Hz), \
     at most 100000 Hz, with a whole number of microseconds per cycle"
)]
pub struct LocalRateError {
    /// What was asked.
    pub rate_hz: f64,
    /// The servo rate.
    pub servo_hz: f64,
}

/// What the ledger books for one cycle of a device rendering a local model (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleBooks {
    /// The coupling energy: the share of the reaction's spring `r² k/2 |x − p − d/k|²`, J.
    pub coupling_energy_j: f64,
    /// The directed force applied, `r d`, N.
    pub directed_n: DVec3,
}

/// A simulated device with the local-model capability (module docs).
pub struct LocalDevice {
    cycles_per_period: u32,
    cycle_us: u64,
    now_us: u64,
    max_force_n: f64,
    host: HostSession,
    session: DeviceSession,
    local: LocalLoop,
    /// The last LocalState the device sent.
    last_state: Option<LocalState>,
}

impl LocalDevice {
    /// An enabled device named `model` whose loop runs at `rate_hz`, a whole multiple of `servo_hz`, declaring
    /// `max_force_n` (N) and the stiffness cap `max_stiffness_n_per_m` (N/m).
    pub fn new(
        servo_hz: f64,
        rate_hz: f64,
        model: &str,
        max_force_n: f64,
        max_stiffness_n_per_m: f64,
    ) -> Result<LocalDevice, LocalRateError> {
        let cycles = (LocalModelSim { rate_hz })
            .cycles_per_period(servo_hz)
            .ok_or(LocalRateError { rate_hz, servo_hz })?;
        // Whole microseconds (cycles_per_period checked it).
        let cycle_us = (1e6 / rate_hz).round() as u64;
        let (host, session) =
            enabled_local_session(model, max_force_n as f32, max_stiffness_n_per_m as f32);
        Ok(LocalDevice {
            cycles_per_period: cycles,
            cycle_us,
            now_us: 0,
            max_force_n,
            host,
            session,
            local: LocalLoop::new(loop_config(cycle_us)),
            last_state: None,
        })
    }

    /// Control cycles per servo period.
    pub fn cycles_per_period(&self) -> u32 {
        self.cycles_per_period
    }

    /// One control cycle's length (s).
    pub fn cycle_s(&self) -> f64 {
        self.cycle_us as f64 * 1e-6
    }

    /// The local model the host builds from `offer` with `force_limit_n` (within the device's largest force).
    pub fn model_message(
        &mut self,
        offer: &LocalOffer,
        force_limit_n: f64,
    ) -> Result<HostToDevice, LocalBuildError> {
        let params = offer.params(force_limit_n, self.max_force_n);
        self.host.local_model(&params, offer.primitives())
    }

    /// The set-force the host builds for `force_n` (N).
    pub fn set_force_message(&mut self, force_n: DVec3) -> HostToDevice {
        self.host
            .set_force(force_n.to_array().map(|c| c as f32), ForceFlags::EMPTY)
    }

    /// `message` reaches the device now.
    pub fn receive(&mut self, message: &HostToDevice) {
        self.session.on_message(message, self.now_us);
    }

    /// The device's drive is enabled again (after its watchdog, say), as a real one would be.
    pub fn enable(&mut self) {
        let message = self.host.enable(WATCHDOG_US);
        self.session.on_message(&message, self.now_us);
        while self.session.poll_transmit().is_some() {}
    }

    /// One control cycle with the arm at `position_m` moving at `velocity_m_per_s`: the force to apply for the
    /// cycle (N). Reads what the device sent the host meanwhile.
    pub fn cycle(&mut self, position_m: DVec3, velocity_m_per_s: DVec3) -> DVec3 {
        let sample = DeviceSample {
            position_m: position_m.to_array().map(|c| c as f32),
            velocity_m_per_s: velocity_m_per_s.to_array().map(|c| c as f32),
            buttons: 0,
        };
        let force = self.local.step(&mut self.session, self.now_us, &sample);
        while let Some(sent) = self.session.poll_transmit() {
            if let DeviceToHost::LocalState(state) = sent {
                self.last_state = Some(state);
            }
        }
        self.now_us += self.cycle_us;
        DVec3::from_array(force.map(f64::from))
    }

    /// The device loop's proxy (`position_m` if it has none yet), m.
    pub fn proxy_m(&self, position_m: DVec3) -> DVec3 {
        self.local.proxy_m().map_or(position_m, DVec3::from_array)
    }

    /// The device loop's ramp factor (1: full force).
    pub fn ramp_factor(&self) -> f64 {
        self.local.ramp_factor()
    }

    /// What the device last reported of its loop (LocalState, SPEC 10.4) as the host reads it: `None` before a
    /// report that names a model (sequence 0: no model since Enable, so no proxy to show).
    pub fn report(&self) -> Option<DeviceLocal> {
        let state = self.last_state.filter(|s| s.model_sequence != 0)?;
        Some(DeviceLocal {
            proxy_m: f64s(state.proxy_m),
            proxy_bound_m: f64::from(state.bound_m),
            model_sequence: state.model_sequence,
            model_age_s: f64::from(state.model_age_us) * 1e-6,
        })
    }

    /// The force the last report says the device applied (N; zero before any report).
    pub fn reported_force_n(&self) -> DVec3 {
        self.last_state.map_or(DVec3::ZERO, |s| f64s(s.force_n))
    }

    /// The device's loop as a driver reports it (`HapticDevice::local_report`): the model in use, the loop's
    /// proxy and force now, and the certified bound of the last LocalState. `None` without a model.
    pub fn local_report(&self) -> Option<LocalReport> {
        let (model, received_us) = self.session.local_model()?;
        let force_n = DVec3::from_array(self.local.force_n());
        Some(LocalReport {
            proxy_m: DVec3::from_array(self.local.proxy_m().unwrap_or([0.0; 3])),
            force_n,
            bound_m: self.last_state.map_or(0.0, |s| f64::from(s.bound_m)),
            peak_force_n: force_n.length(),
            model_sequence: model.sequence,
            model_age_us: u32::try_from(self.now_us.saturating_sub(received_us))
                .unwrap_or(u32::MAX),
            status: self.local.last_status().0,
        })
    }

    /// The energy ledger's books of the cycle just run, with the arm at `position_m` moving at
    /// `velocity_m_per_s` when it sensed and `applied_n` the force the cycle returned (module docs): `None`
    /// without a model in use (the set-force path, whose force is the host's).
    pub fn cycle_books(
        &self,
        position_m: DVec3,
        velocity_m_per_s: DVec3,
        applied_n: DVec3,
    ) -> Option<CycleBooks> {
        let (model, _) = self.session.local_model()?;
        let proxy = DVec3::from_array(self.local.proxy_m()?);
        let k = f64::from(model.stiffness_n_per_m);
        // The directed slots as the loop's solver takes them (the direction normalised).
        let directed_n: DVec3 = model
            .si_primitives()
            .filter(|p| p.kind == LocalKind::Directed)
            .filter_map(|p| Primitive::directed(DVec3::from_array(p.direction), p.strength_n).ok())
            .map(|p| p.direction() * p.strength_n())
            .sum();
        // The share `r` of the loop's coupling force that went out: that force from what the loop sensed (f32).
        let sensed = |v: DVec3| DVec3::from_array(v.to_array().map(|c| f64::from(c as f32)));
        let coupling_n =
            k * (proxy - sensed(position_m)) - model.damping_n_s_per_m() * sensed(velocity_m_per_s);
        let share = crate::energy::SentShare::of(applied_n, coupling_n);
        Some(CycleBooks {
            coupling_energy_j: share.reaction_energy_j(k, proxy - position_m, directed_n),
            directed_n: share.fraction() * directed_n,
        })
    }

    /// Books the cycle just run in `ledger` at `t_s` (see [`Self::cycle_books`]): the directed force the device
    /// applied is the intended work; on the set-force path, `set_force_directed_n`, the directed part of the
    /// force the host sent.
    pub fn book_cycle(
        &self,
        ledger: &mut EnergyLedger,
        t_s: f64,
        position_m: DVec3,
        velocity_m_per_s: DVec3,
        applied_n: DVec3,
        set_force_directed_n: DVec3,
    ) -> EnergyTotals {
        let (coupling_j, directed_n) = self
            .cycle_books(position_m, velocity_m_per_s, applied_n)
            .map_or((0.0, set_force_directed_n), |b| {
                (b.coupling_energy_j, b.directed_n)
            });
        ledger.record(
            t_s,
            self.cycle_s(),
            position_m,
            applied_n,
            directed_n,
            coupling_j,
        )
    }
}

/// The device loop's settings for a cycle of `cycle_us`: the one place they are made.
fn loop_config(cycle_us: u64) -> LoopConfig {
    LoopConfig {
        period_us: cycle_us as u32,
        ..LoopConfig::default()
    }
}

fn f64s(v: [f32; 3]) -> DVec3 {
    DVec3::from_array(v.map(f64::from))
}

/// An in-process device with the local-model capability (3-DOF, ±1 m workspace, 1 kHz), through its Hello and
/// an Enable with a 50 ms watchdog.
fn enabled_local_session(
    model: &str,
    max_force_n: f32,
    max_stiffness_n_per_m: f32,
) -> (HostSession, DeviceSession) {
    let info = voxhap_protocol::DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new(model).unwrap_or_default(),
        serial_number: Label::new("in-process").unwrap_or_default(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[1000]).unwrap_or_default(),
        workspace_min_m: [-1.0; 3],
        workspace_max_m: [1.0; 3],
        max_force_n,
        max_stiffness_n_per_m,
    };
    let mut host = HostSession::new();
    let mut session = DeviceSession::with_local_model(info);
    session.on_message(&host.hello(), 0);
    session.on_message(&host.enable(WATCHDOG_US), 0);
    while session.poll_transmit().is_some() {}
    (host, session)
}

#[cfg(test)]
#[path = "local_tests.rs"]
mod tests;
