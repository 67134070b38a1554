//! The device session that the local-loop tests, the fuzz body and the cycle-cost example drive: a 3-DOF device
//! with the local-model capability (workspace ±0.1 m, no buttons), greeted and enabled at time 0.

use voxhap_protocol::{
    DeviceInfo, DeviceSession, Enable, Hello, HostToDevice, Label, RateSet, SetStateRate,
    PROTOCOL_VERSION,
};

/// What differs between the devices the tests drive.
pub struct TestDevice {
    pub model: &'static str,
    /// The one state rate the device supports.
    pub rate_hz: u16,
    pub max_force_n: f32,
    pub max_stiffness_n_per_m: f32,
}

/// A session for `device` after Hello, Enable (`watchdog_timeout_us`, 0: the default) and, unless
/// `state_rate_hz` is 0, SetStateRate.
pub fn enabled_session(
    device: &TestDevice,
    watchdog_timeout_us: u32,
    state_rate_hz: u16,
) -> DeviceSession {
    let info = DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new(device.model).unwrap_or_default(),
        serial_number: Label::new("0").unwrap_or_default(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[device.rate_hz]).unwrap_or_default(),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: device.max_force_n,
        max_stiffness_n_per_m: device.max_stiffness_n_per_m,
    };
    let mut session = DeviceSession::with_local_model(info);
    let hello = Hello {
        version: PROTOCOL_VERSION,
    };
    session.on_message(&HostToDevice::Hello(hello), 0);
    session.on_message(
        &HostToDevice::Enable(Enable {
            watchdog_timeout_us,
        }),
        0,
    );
    if state_rate_hz != 0 {
        session.on_message(
            &HostToDevice::SetStateRate(SetStateRate { state_rate_hz }),
            0,
        );
    }
    session
}
