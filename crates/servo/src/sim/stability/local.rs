//! The headless host + device loop of a local-model device (protocol/SPEC.md section 10).
//!
//! The host runs the real tick at its rate, turns each tick's primitives, coupling and proxy into a LocalModel
//! ([`crate::local_model::offer`], `voxhap_protocol::HostSession::local_model`) and sends it over a link that
//! delays it by whole host periods; the device runs the reference device loop (`voxhap_local::LocalLoop`) behind
//! the protocol's device session at its own rate, sensing the simulated arm and stepping it one cycle under the
//! force it returns, as `crate::device::SimDevice` and `voxhap mock-device --local-model` do. Unlike those, every
//! cycle is visible here, and the device loop can be engaged before the measured run starts.

use super::arms::ArmCase;
use super::error::StabilityError;
use super::setup::{scenario_text, Sample};
use crate::device::LocalDevice;
use crate::energy::EnergyLedger;
use crate::sim::Scenario;
use glam::DVec3;
use std::collections::VecDeque;
use std::path::Path;
use voxhap_device::local_offer::LocalOffer;
use voxhap_device::sim::SimArm;
use voxhap_local::ENGAGE_US;
use voxhap_protocol::HostToDevice;

/// The simulated device's largest force, N (as `crate::device::SimDevice` declares).
pub const DEVICE_MAX_FORCE_N: f64 = 10.0;

/// A local-model device ([`LocalDevice`]) behind a link that delays each model by whole host periods.
pub struct DeviceLoop {
    device: LocalDevice,
    /// Models on their way, oldest first.
    pipe: VecDeque<HostToDevice>,
    delay_periods: usize,
}

impl DeviceLoop {
    /// A device whose loop runs at `device_rate_hz` (a whole multiple of `host_rate_hz`), enabled, behind a
    /// link that delays each model by `latency_s` rounded to whole host periods.
    pub fn new(
        host_rate_hz: f64,
        device_rate_hz: f64,
        latency_s: f64,
    ) -> Result<DeviceLoop, StabilityError> {
        let device = LocalDevice::new(
            host_rate_hz,
            device_rate_hz,
            "voxhap-bench",
            DEVICE_MAX_FORCE_N,
            65_535.0,
        )
        .map_err(|_| StabilityError::LocalRate {
            device_hz: device_rate_hz,
            host_hz: host_rate_hz,
        })?;
        Ok(DeviceLoop {
            device,
            pipe: VecDeque::new(),
            delay_periods: (latency_s * host_rate_hz).round().max(0.0) as usize,
        })
    }

    /// The host sends `offer` (limited to the device's largest force); the model built is returned, and the
    /// oldest model whose delay has passed reaches the device.
    pub fn send(&mut self, offer: &LocalOffer) -> Result<HostToDevice, StabilityError> {
        let message = self.device.model_message(offer, DEVICE_MAX_FORCE_N)?;
        self.pipe.push_back(message);
        if self.pipe.len() > self.delay_periods {
            if let Some(arrived) = self.pipe.pop_front() {
                self.device.receive(&arrived);
            }
        }
        Ok(message)
    }

    /// The device behind the link.
    pub fn device(&mut self) -> &mut LocalDevice {
        &mut self.device
    }
}

/// What a local-model run gave: one sample per device cycle, the stiffness the device rendered (the model
/// carries whole N/m) and the energy ledger's finding.
pub struct LocalRun {
    /// One per device cycle of the measured run.
    pub samples: Vec<Sample>,
    /// The coupling stiffness in the models, N/m.
    pub k_n_per_m: f64,
    /// The ledger found a contact limit cycle.
    pub oscillating: bool,
}

/// The run of [`super::judge`] with a local-model device: first the device loop engages (its 0.5 s ramp,
/// which starts only below 1 N) with the arm held still, 10 mm above the plane for one host period and then
/// where the set-force runs start it; then the arm is released there, at rest, and the measured run of
/// [`super::setup::RUN_S`] follows. The link latency delays the
/// models; the device's own loop has none.
pub fn run_local(
    arm: &ArmCase,
    host_rate_hz: f64,
    device_rate_hz: f64,
    latency_s: f64,
    k: f64,
) -> Result<LocalRun, StabilityError> {
    // The model carries the stiffness in whole N/m: the run renders (and is judged at) that.
    let k = k.round().max(1.0);
    let text = scenario_text(arm, host_rate_hz, 0.0, false, k);
    let loaded =
        Scenario::parse(&text, "stiffness-sweep")?.load(Path::new(""), "stiffness-sweep")?;
    let settings = &loaded.scenario;
    let scene = &loaded.scene;
    let dt_s = settings.dt_s();
    let mut workspace = voxhap_core::haptics::tick::TickWorkspace::new(
        scene,
        voxhap_core::haptics::tick::SolverKind::Exact,
        settings.solver.solver_config(),
    );
    let mut device = DeviceLoop::new(host_rate_hz, device_rate_hz, latency_s)?;
    let cycle_s = device.device().cycle_s();
    let cycles = device.device().cycles_per_period();
    let mut host_tick = |state: &mut voxhap_core::haptics::tick::TickState,
                         probe_m: DVec3,
                         device: &mut DeviceLoop|
     -> Result<(), StabilityError> {
        let out = voxhap_core::haptics::tick::tick(state, scene, probe_m, dt_s, &mut workspace);
        let offer = crate::local_model::offer(
            workspace.primitives(),
            scene.stiffness_n_per_m(),
            settings.damping_n_s_per_m,
            out.proxy_m,
        );
        device.send(&offer)?;
        Ok(())
    };
    // Engage: the device senses the arm held clear of the plane until its ramp has started (the force zero),
    // then held still where the measured run starts it, until the ramp is done. The force has
    // then risen slowly to the start's coupling force, as the set-force runs start with it (the slew limit
    // does not hold it back at the start).
    let clear_m = loaded.start_m + DVec3::new(0.0, 0.0, 0.01);
    let mut state = voxhap_core::haptics::tick::TickState::new(clear_m);
    let engage_s = f64::from(ENGAGE_US) * 1e-6 + 0.02;
    let engage_ticks = (engage_s * host_rate_hz).ceil() as u64;
    for _ in 0..engage_ticks {
        let started = device.device().ramp_factor() > 0.0;
        let held_m = if started { loaded.start_m } else { clear_m };
        host_tick(&mut state, held_m, &mut device)?;
        for _ in 0..cycles {
            device.device().cycle(held_m, DVec3::ZERO);
        }
    }
    let factor = device.device().ramp_factor();
    if factor < 1.0 {
        return Err(StabilityError::NoEngage {
            seconds: engage_s,
            factor,
        });
    }
    // The measured run, from rest at the start.
    let mut sim_arm = SimArm::new(loaded.arm.clone(), loaded.start_m)?;
    let mut ledger = EnergyLedger::new(arm.damping_n_s_per_m);
    let ticks = settings.tick_count();
    let mut samples = Vec::with_capacity((ticks * u64::from(cycles)) as usize);
    let mut t_s = 0.0;
    for _ in 0..ticks {
        host_tick(&mut state, sim_arm.position_m(), &mut device)?;
        let device = device.device();
        for _ in 0..cycles {
            let probe_m = sim_arm.position_m();
            let velocity_m_per_s = sim_arm.velocity_m_per_s();
            let force_n = device.cycle(probe_m, velocity_m_per_s);
            let proxy_m = device.proxy_m(probe_m);
            device.book_cycle(
                &mut ledger,
                t_s,
                probe_m,
                velocity_m_per_s,
                force_n,
                DVec3::ZERO,
            );
            samples.push(Sample {
                probe_m,
                velocity_m_per_s,
                proxy_m,
            });
            sim_arm.step(t_s, cycle_s, force_n)?;
            t_s += cycle_s;
        }
    }
    Ok(LocalRun {
        samples,
        k_n_per_m: k,
        oscillating: ledger.totals().oscillating(),
    })
}
