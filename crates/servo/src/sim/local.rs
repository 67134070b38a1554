//! `[local_model]` in `voxhap sim`: the simulated arm as a device with the local-model capability (protocol/SPEC.md
//! section 10), its control loop run cycle by cycle between two host ticks.
//!
//! Where it sits: [`super::runner`] builds the device ([`new_device`], the in-process
//! [`crate::device::LocalDevice`] that `serve` runs on the simulated arm: the same DeviceInfo, Hello, Enable and
//! loop settings) and hands it each tick's local model ([`send`], built as `serve` builds it: the safety
//! pipeline's default force limit), then runs its control cycles, each sensing the arm, running the reference
//! device loop and stepping the arm one cycle under the force it returns, held for the cycle; the runner's energy
//! ledger books each cycle. What the device reports (LocalState, SPEC 10.4) is what the trace shows.

use crate::device::LocalDevice;
use glam::DVec3;
use voxhap_device::local_offer::LocalOffer;
use voxhap_device::sim::LocalModelSim;

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

/// The enabled device of a scenario at `servo_hz` whose loop runs at `local.rate_hz` (`None` when that is not a
/// whole multiple: the scenario's validation refuses such a rate first); it declares the stiffness cap
/// `declared_n_per_m` (N/m) as the simulated arm does.
pub fn new_device(
    servo_hz: f64,
    local: LocalModelSim,
    declared_n_per_m: f64,
) -> Option<LocalDevice> {
    LocalDevice::new(
        servo_hz,
        local.rate_hz,
        "voxhap-sim",
        DEVICE_MAX_FORCE_N,
        declared_n_per_m.max(f64::MIN_POSITIVE),
    )
    .ok()
}

/// The host sends this tick's model, or, when the tick's force is not valid (`None`, as `serve`'s supervisor
/// decides) or no model can be built from it, a set-force of `fallback_n` (zero if not finite), which the
/// device holds for the period and which makes the next model engage from zero again. Returns the set-force
/// sent, `None` when a model went.
pub fn send(
    device: &mut LocalDevice,
    offer: Option<&LocalOffer>,
    fallback_n: DVec3,
) -> Option<DVec3> {
    let model = offer.and_then(|offer| device.model_message(offer, model_force_limit_n()).ok());
    let (message, set_force) = match model {
        Some(message) => (message, None),
        None => {
            let force = if fallback_n.is_finite() {
                fallback_n
            } else {
                DVec3::ZERO
            };
            (device.set_force_message(force), Some(force))
        }
    };
    device.receive(&message);
    set_force
}
