//! How stale a model up to one host period old feels, and what models take on the link.
//!
//! A scenario runs with a local-model device ([`super::local::DeviceLoop`]): the host ticks at the scenario's
//! rate and sends each tick's model, the device renders the latest one at `device_rate_hz` and moves the arm.
//! Beside it, on the very same probe positions, a second host tick runs at the device's rate: the full-rate
//! render, whose model would never be older than one device cycle. The force error is the difference between
//! the force the device applied and the force the full-rate render gives at the same position, every device
//! cycle once the device's engage ramp is done. Both follow the scenario's `[[events]]` at the same instant.
//! The arm's `latency_s` becomes the link's delay of each model (whole host periods); the device's own loop
//! has none. What the model leaves out is in the error too: a mode that acts on the solve rather than through
//! primitives (viscosity) is not rendered by the device (docs/local-model.md).
//!
//! The bytes: every model is encoded as the protocol sends it (`voxhap_protocol::encode_frame`, the serial
//! wire frame with its COBS byte, CRC and delimiter; a HID report is always `REPORT_LEN` bytes), and the
//! primitives it carries are counted.

use super::error::StabilityError;
use super::local::DeviceLoop;
use crate::sim::LoadedScenario;
use std::path::Path;
use voxhap_core::haptics::tick::{tick, SolverKind, TickState, TickWorkspace};
use voxhap_device::sim::SimArm;
use voxhap_protocol::{encode_frame, ForceFlags, HostSession, HostToDevice, MAX_WIRE_FRAME_LEN};

/// What one scenario's run gave.
#[derive(Debug, Clone, PartialEq)]
pub struct StaleForce {
    /// The scenario file's name without its extension.
    pub name: String,
    /// Host rate, Hz.
    pub host_rate_hz: f64,
    /// Device loop rate, Hz.
    pub device_rate_hz: f64,
    /// Device cycles compared (after the engage ramp).
    pub compared_cycles: u64,
    /// Median, 99th percentile and largest force error, N.
    pub error_median_n: f64,
    /// 99th percentile (nearest rank), N.
    pub error_p99_n: f64,
    /// Largest, N.
    pub error_max_n: f64,
    /// Largest force of the full-rate render on the compared cycles, N.
    pub reference_max_n: f64,
    /// Median and 99th percentile of the arm's speed on the compared cycles, m/s.
    pub speed_median_m_per_s: f64,
    /// 99th percentile, m/s.
    pub speed_p99_m_per_s: f64,
    /// Models sent.
    pub models: u64,
    /// The most primitives one model carried.
    pub primitives_max: usize,
    /// Mean primitives per model.
    pub primitives_mean: f64,
    /// Models marked `TRUNCATED` (the tick had more primitives than fit).
    pub truncated_models: u64,
    /// The largest serial wire frame of a model, bytes.
    pub model_frame_bytes: usize,
    /// A SetForce's serial wire frame, bytes, for comparison.
    pub set_force_frame_bytes: usize,
}

impl StaleForce {
    /// The models' share of the link: serial frame bits per second at the host rate.
    pub fn model_bits_per_s(&self) -> f64 {
        self.model_frame_bytes as f64 * 8.0 * self.host_rate_hz
    }
}

/// The `q` quantile of sorted `values` (nearest rank); 0 when empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// The serial wire frame length of `message`, bytes.
fn frame_len(message: &HostToDevice) -> usize {
    let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
    encode_frame(message, &mut buf).unwrap_or(0)
}

/// Runs the scenario file at `path` with a local-model device at `device_rate_hz` and a full-rate render beside
/// it (module docs).
pub fn stale_force(path: &Path, device_rate_hz: f64) -> Result<StaleForce, StabilityError> {
    let loaded = LoadedScenario::from_file(path)?;
    let settings = &loaded.scenario;
    let host_rate_hz = settings.rate_hz;
    let dt_s = settings.dt_s();
    let mut arm_config = loaded.arm.clone();
    let latency_s = arm_config.arm.effects.latency_s;
    arm_config.arm.effects.latency_s = 0.0;
    arm_config.local_model = None;
    let mut arm = SimArm::new(arm_config, loaded.start_m)?;
    let mut link = DeviceLoop::new(host_rate_hz, device_rate_hz, latency_s)?;
    let cycle_s = link.device().cycle_s();
    let cycles = link.device().cycles_per_period();
    let scenes: Vec<_> = std::iter::once(&loaded.scene)
        .chain(loaded.events.iter().map(|e| &e.scene))
        .collect();
    let config = settings.solver.solver_config();
    let mut host_ws: Vec<TickWorkspace> = scenes
        .iter()
        .map(|s| TickWorkspace::new(s, SolverKind::Exact, config))
        .collect();
    let mut full_ws: Vec<TickWorkspace> = scenes
        .iter()
        .map(|s| TickWorkspace::new(s, SolverKind::Exact, config))
        .collect();
    let mut host = TickState::new(arm.position_m());
    let mut full = TickState::new(arm.position_m());
    let mut damping = settings.damping_n_s_per_m;
    let mut current = 0;
    let mut errors = Vec::new();
    let mut speeds = Vec::new();
    let mut reference_max_n = 0.0f64;
    let (mut models, mut primitives, mut primitives_max, mut truncated) = (0u64, 0usize, 0, 0u64);
    let mut model_frame_bytes = 0;
    let mut t_s = 0.0;
    for index in 0..settings.tick_count() {
        while let Some(event) = loaded.events.get(current).filter(|e| e.tick <= index) {
            damping = event.damping_n_s_per_m;
            current += 1;
        }
        let scene = scenes[current];
        let out = tick(
            &mut host,
            scene,
            arm.position_m(),
            dt_s,
            &mut host_ws[current],
        );
        let offer = crate::local_model::offer(
            host_ws[current].primitives(),
            scene.stiffness_n_per_m(),
            damping,
            out.proxy_m,
        );
        let message = link.send(&offer)?;
        if let HostToDevice::LocalModel(model) = &message {
            models += 1;
            primitives += model.primitive_count();
            primitives_max = primitives_max.max(model.primitive_count());
            truncated += u64::from(model.flags.contains(voxhap_protocol::ModelFlags::TRUNCATED));
        }
        model_frame_bytes = model_frame_bytes.max(frame_len(&message));
        let device = link.device();
        for _ in 0..cycles {
            let probe_m = arm.position_m();
            let velocity = arm.velocity_m_per_s();
            let force_n = device.cycle(probe_m, velocity);
            let reference = tick(&mut full, scene, probe_m, cycle_s, &mut full_ws[current]);
            let reference_n = reference.coupling_force_n
                + damping * (reference.proxy_velocity_m_per_s - velocity);
            if device.ramp_factor() >= 1.0 {
                errors.push((force_n - reference_n).length());
                speeds.push(velocity.length());
                reference_max_n = reference_max_n.max(reference_n.length());
            }
            arm.step(t_s, cycle_s, force_n)?;
            t_s += cycle_s;
        }
    }
    errors.sort_by(f64::total_cmp);
    speeds.sort_by(f64::total_cmp);
    let set_force = HostSession::new().set_force([0.0; 3], ForceFlags::EMPTY);
    Ok(StaleForce {
        name: path
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned()),
        host_rate_hz,
        device_rate_hz,
        compared_cycles: errors.len() as u64,
        error_median_n: quantile(&errors, 0.5),
        error_p99_n: quantile(&errors, 0.99),
        error_max_n: errors.last().copied().unwrap_or(0.0),
        reference_max_n,
        speed_median_m_per_s: quantile(&speeds, 0.5),
        speed_p99_m_per_s: quantile(&speeds, 0.99),
        models,
        primitives_max,
        primitives_mean: primitives as f64 / models.max(1) as f64,
        truncated_models: truncated,
        model_frame_bytes,
        set_force_frame_bytes: frame_len(&set_force),
    })
}
