//! What a device is and what it senses: [`DeviceInfo`], the capability record every driver fills in (chai3d's
//! `cHapticDeviceInfo` in spirit: degrees of freedom, workspace, maximum force and stiffness, rates), and
//! [`DeviceState`], one sample of the handle.
//!
//! Where it sits: the servo loop reads `DeviceInfo` once after open (it sizes the safety pipeline's clamp and the
//! coupling stiffness), and a `DeviceState` every tick (the probe position). Units are SI.

use glam::DVec3;

/// Capabilities of a device, as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// Model name, for people.
    pub model: String,
    /// Serial number or other identity, may be empty.
    pub serial_number: String,
    /// Sensed degrees of freedom (3 for a position-only arm, 2 for a planar one).
    pub position_dof: u8,
    /// Actuated degrees of freedom.
    pub force_dof: u8,
    /// Number of buttons reported in [`DeviceState::buttons`].
    pub button_count: u8,
    /// Lower corner of the reachable box in the device frame (m).
    pub workspace_min_m: DVec3,
    /// Upper corner of the reachable box in the device frame (m).
    pub workspace_max_m: DVec3,
    /// Largest force the device renders (N).
    pub max_force_n: f64,
    /// Largest coupling stiffness rendered stably at 1 kHz (N/m).
    pub max_stiffness_n_per_m: f64,
    /// State rates the device can stream at (Hz); empty when it only answers each force (lockstep).
    pub state_rates_hz: Vec<u16>,
}

/// One sample of a device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceState {
    /// Handle position in the device frame (m).
    pub position_m: DVec3,
    /// Handle velocity (m/s); drivers without a velocity estimate report zero.
    pub velocity_m_per_s: DVec3,
    /// Button `n` pressed = bit `n`.
    pub buttons: u16,
    /// Device clock at the sample (µs), where the device has one.
    pub device_time_us: Option<u64>,
}

impl DeviceState {
    /// A handle at rest at `position_m`.
    pub fn at_rest(position_m: DVec3) -> DeviceState {
        DeviceState {
            position_m,
            velocity_m_per_s: DVec3::ZERO,
            buttons: 0,
            device_time_us: None,
        }
    }
}
