//! `[local_model]` in `voxhap sim`: the simulated arm as a device with the local-model capability (protocol/SPEC.md
//! section 10), its control loop run cycle by cycle between two host ticks.
//!
//! Where it sits: [`super::runner`] hands each tick's local model to [`LocalDevice::send`] (built as `serve` builds
//! it: [`crate::local_model::offer`], the host session's LocalModel with the safety pipeline's default force
//! limit), then runs [`LocalDevice::cycles_per_period`] control cycles, each sensing the arm, running the
//! reference device loop (`voxhap-local`, behind the protocol's device session, the code a firmware links) and
//! stepping the arm one cycle under the force it returns, held for the cycle. The device's clock is the cycle
//! count, so runs are deterministic. What the device reports (LocalState, SPEC 10.4) is read from the session's
//! outgoing messages, as a host reads it from the link: the trace shows that.
//!
//! The same device as `crate::device::SimDevice` (`serve` on the simulated arm): the same DeviceInfo, Hello and
//! Enable ([`crate::device::enabled_local_session`]), the same loop settings; here every cycle is visible to
//! the caller, whose energy ledger books each one.

use glam::DVec3;
use voxhap_api::DeviceLocal;
use voxhap_device::local_offer::LocalOffer;
use voxhap_device::sim::LocalModelSim;
use voxhap_local::{LocalLoop, LoopConfig};
use voxhap_protocol::{
    DeviceSample, DeviceSession, DeviceToHost, ForceFlags, HostSession, HostToDevice,
};

/// The simulated device's largest force, N (as `crate::device::SimDevice` declares).
pub const DEVICE_MAX_FORCE_N: f64 = 10.0;

/// The largest coupling stiffness a local model carries, N/m (SPEC 10.3: whole N/m in 16 bits); with
/// `[local_model]` a scenario's stiffness is refused above it rather than sent saturated.
pub const MAX_LOCAL_STIFFNESS_N_PER_M: f64 = u16::MAX as f64;
/// The largest coupling damping a local model carries, N s/m (SPEC 10.3: mN s/m in 16 bits).
pub const MAX_LOCAL_DAMPING_N_S_PER_M: f64 =
    u16::MAX as f64 * voxhap_protocol::local::DAMPING_UNIT_N_S_PER_M;

/// The force limit each model carries, N: the safety pipeline's default limit, which `serve` sends
/// (`voxhap_device::safety::SafetyConfig`), within the device's [`DEVICE_MAX_FORCE_N`].
pub fn model_force_limit_n() -> f64 {
    voxhap_device::safety::SafetyConfig::default()
        .max_force_n
        .min(DEVICE_MAX_FORCE_N)
}

/// A simulated local-model device: the host session that numbers the models, the device's session and loop, its
/// clock, and what it last reported.
pub struct LocalDevice {
    cycles_per_period: u32,
    cycle_us: u64,
    now_us: u64,
    force_limit_n: f64,
    host: HostSession,
    session: DeviceSession,
    local: LocalLoop,
    /// The last LocalState that named a model, as the host reads it.
    report: Option<DeviceLocal>,
    /// The force that LocalState reported applied (N).
    reported_force_n: DVec3,
}

impl LocalDevice {
    /// An enabled device whose loop runs at `local.rate_hz`, a whole multiple of `servo_hz` (`None` otherwise: the
    /// scenario's validation refuses such a rate first); it declares the stiffness cap `declared_n_per_m` (N/m) as
    /// the simulated arm does.
    pub fn new(servo_hz: f64, local: LocalModelSim, declared_n_per_m: f64) -> Option<LocalDevice> {
        let cycles = local.cycles_per_period(servo_hz)?;
        // Whole microseconds (cycles_per_period checked it).
        let cycle_us = (1e6 / local.rate_hz).round() as u64;
        let (host, session) = crate::device::enabled_local_session(
            "voxhap-sim",
            DEVICE_MAX_FORCE_N as f32,
            declared_n_per_m.max(f64::MIN_POSITIVE) as f32,
        );
        Some(LocalDevice {
            cycles_per_period: cycles,
            cycle_us,
            now_us: 0,
            force_limit_n: model_force_limit_n(),
            host,
            session,
            local: LocalLoop::new(LoopConfig {
                period_us: cycle_us as u32,
                ..LoopConfig::default()
            }),
            report: None,
            reported_force_n: DVec3::ZERO,
        })
    }

    /// Control cycles per host tick.
    pub fn cycles_per_period(&self) -> u32 {
        self.cycles_per_period
    }

    /// One control cycle's length (s).
    pub fn cycle_s(&self) -> f64 {
        self.cycle_us as f64 * 1e-6
    }

    /// The force limit the models carry (N).
    pub fn force_limit_n(&self) -> f64 {
        self.force_limit_n
    }

    /// The host sends this tick's model, or, when the tick's force is not valid (`None`, as `serve`'s supervisor
    /// decides) or no model can be built from it, a set-force of `fallback_n`, which the device holds for the
    /// period and which makes the next model engage from zero again.
    pub fn send(&mut self, offer: Option<&LocalOffer>, fallback_n: DVec3) {
        let model = offer.and_then(|offer| {
            let params = offer.params(self.force_limit_n, DEVICE_MAX_FORCE_N);
            self.host.local_model(&params, offer.primitives()).ok()
        });
        let message: HostToDevice = model.unwrap_or_else(|| {
            let force = if fallback_n.is_finite() {
                fallback_n
            } else {
                DVec3::ZERO
            };
            self.host
                .set_force(force.to_array().map(|c| c as f32), ForceFlags::EMPTY)
        });
        self.session.on_message(&message, self.now_us);
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
                let f64s = |v: [f32; 3]| DVec3::from_array(v.map(f64::from));
                // Sequence 0: no model since Enable, so no proxy to show.
                self.report = (state.model_sequence != 0).then(|| DeviceLocal {
                    proxy_m: f64s(state.proxy_m),
                    proxy_bound_m: f64::from(state.bound_m),
                    model_sequence: state.model_sequence,
                    model_age_s: f64::from(state.model_age_us) * 1e-6,
                });
                self.reported_force_n = f64s(state.force_n);
            }
        }
        self.now_us += self.cycle_us;
        DVec3::from_array(force.map(f64::from))
    }

    /// The energy the coupling spring of the model in use holds for the force applied, J: `k/2 |proxy -
    /// probe|^2` scaled by the share of the coupling force (`k (proxy - probe) - b v`) that went out
    /// ([`crate::energy::SentShare`], as `serve` books it: the engage ramp, the clamp and the slew limit shrink
    /// it). Zero without a model in use (the set-force path).
    pub fn coupling_energy_j(
        &self,
        position_m: DVec3,
        velocity_m_per_s: DVec3,
        applied_n: DVec3,
    ) -> f64 {
        let (Some((model, _)), Some(proxy)) = (self.session.local_model(), self.local.proxy_m())
        else {
            return 0.0;
        };
        let k = f64::from(model.stiffness_n_per_m);
        let stretch_m = DVec3::from_array(proxy) - position_m;
        let coupling_n = k * stretch_m - model.damping_n_s_per_m() * velocity_m_per_s;
        crate::energy::SentShare::of(applied_n, coupling_n).spring_energy_j(k, stretch_m)
    }

    /// What the device last reported of its loop (LocalState, SPEC 10.4): `None` before a report that names a
    /// model.
    pub fn report(&self) -> Option<DeviceLocal> {
        self.report
    }

    /// The force the last report says the device applied (N).
    pub fn reported_force_n(&self) -> DVec3 {
        self.reported_force_n
    }
}
