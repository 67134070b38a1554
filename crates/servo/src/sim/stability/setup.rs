//! The run every stability verdict is made on: a released hand pushing the arm onto a plane, started off the
//! contact's equilibrium ([`super::judge`] has why), and what is kept of each loop period.

use super::arms::ArmCase;
use glam::DVec3;

/// The hand's constant push onto the plane (N).
pub const PUSH_N: f64 = 1.0;
/// Length of one run (s), after the device loop's engage ramp for a local model.
pub const RUN_S: f64 = 1.5;

/// The scenario of a run: the arm `arm` at `rate_hz` with `latency_s`, the passivity controller on or off, and
/// coupling stiffness `k`.
pub fn scenario_text(arm: &ArmCase, rate_hz: f64, latency_s: f64, control: bool, k: f64) -> String {
    let preset = arm
        .preset
        .map(|p| format!("preset = \"{}\"\n", p.name()))
        .unwrap_or_default();
    format!(
        "name = \"stiffness-sweep\"\nduration_s = {RUN_S}\nrate_hz = {rate_hz}\nk_n_per_m = {k}\n\
         start_m = [0.0, 0.0, {z0}]\nvolumes = []\n\n[passivity]\nmode = \"{mode}\"\n\n\
         [[modes]]\nkind = \"support_plane\"\npoint_m = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\n\
         strength_n = 50.0\n\n[arm]\n{preset}mass_kg = {m}\ndamping_n_s_per_m = {b}\nlatency_s = {latency_s}\n\
         position_resolution_m = 0.0\nsubsteps_per_tick = 10\nworkspace = {{ shape = \"unbounded\" }}\n\n\
         [hand]\nstiffness_n_per_m = 200.0\ndamping_n_s_per_m = 2.0\n\n[path]\nkind = \"force\"\n\
         profile = {{ shape = \"constant\", force_n = [0.0, 0.0, -{PUSH_N}] }}\n",
        z0 = -0.5 * PUSH_N / k,
        mode = if control { "control" } else { "off" },
        m = arm.mass_kg,
        b = arm.damping_n_s_per_m,
    )
}

/// One sample of a run, at the loop's rate: what the loop sensed and the proxy it rendered against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The arm's position, m.
    pub probe_m: DVec3,
    /// The arm's velocity, m/s.
    pub velocity_m_per_s: DVec3,
    /// The proxy the coupling pulled towards, m.
    pub proxy_m: DVec3,
}
