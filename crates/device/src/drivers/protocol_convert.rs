//! The protocol driver's conversions from the protocol crate's messages to the device layer's types.

use crate::info::DEFAULT_MAX_SPEED_M_PER_S;
use crate::{DeviceInfo, DeviceState, DeviceStatus};
use glam::DVec3;
use voxhap_protocol::StatusFlags;

pub(super) fn placeholder_info() -> DeviceInfo {
    DeviceInfo {
        model: String::from("voxhap protocol device (not open)"),
        serial_number: String::new(),
        position_dof: 0,
        force_dof: 0,
        button_count: 0,
        workspace_min_m: DVec3::ZERO,
        workspace_max_m: DVec3::ZERO,
        max_force_n: 0.0,
        max_stiffness_n_per_m: 0.0,
        max_speed_m_per_s: DEFAULT_MAX_SPEED_M_PER_S,
        reports_velocity: true,
        state_rates_hz: Vec::new(),
    }
}

pub(super) fn to_dvec3(v: [f32; 3]) -> DVec3 {
    DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
}

pub(super) fn convert_info(info: &voxhap_protocol::DeviceInfo) -> DeviceInfo {
    DeviceInfo {
        model: info.model.as_str().to_string(),
        serial_number: info.serial_number.as_str().to_string(),
        position_dof: info.position_dof,
        force_dof: info.force_dof,
        button_count: info.button_count,
        workspace_min_m: to_dvec3(info.workspace_min_m),
        workspace_max_m: to_dvec3(info.workspace_max_m),
        max_force_n: f64::from(info.max_force_n),
        max_stiffness_n_per_m: f64::from(info.max_stiffness_n_per_m),
        max_speed_m_per_s: DEFAULT_MAX_SPEED_M_PER_S,
        reports_velocity: true,
        state_rates_hz: info.supported_rates.iter_hz().collect(),
    }
}

/// A protocol State as the device layer's sample (the first State of an open and every later one).
pub(super) fn convert_state(state: &voxhap_protocol::State) -> DeviceState {
    DeviceState {
        position_m: to_dvec3(state.position_m),
        velocity_m_per_s: to_dvec3(state.velocity_m_per_s),
        buttons: state.buttons,
        device_time_us: Some(state.device_time_us),
        sequence: Some(state.sequence),
        status: Some(convert_status(state.status, state.faults.0)),
    }
}

fn convert_status(status: StatusFlags, active_faults: u16) -> DeviceStatus {
    DeviceStatus {
        enabled: status.contains(StatusFlags::ENABLED),
        faulted: status.contains(StatusFlags::FAULTED),
        watchdog_tripped: status.contains(StatusFlags::WATCHDOG_TRIPPED),
        force_clamped: status.contains(StatusFlags::FORCE_CLAMPED),
        active_faults,
    }
}
