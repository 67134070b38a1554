//! The in-process simulated arm as a [`HapticDevice`] ([`SimDevice`]), the default device: a [`SimArm`]
//! stepped one servo period per force written, its virtual hand following a scripted path, or, when a client
//! sets one through the session, a hand target (a triple buffer, so setting it never blocks the servo thread).

use crate::device::sim::{SimArm, SimArmConfig, SimError};
use crate::device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;

/// The simulated arm as a [`HapticDevice`]: each `write_force` steps the arm one servo period under that
/// force; `read_state` reports where it got to.
pub struct SimDevice {
    arm: SimArm,
    dt_s: f64,
    t_s: f64,
    info: DeviceInfo,
    hand_target: triple_buffer::Output<Option<DVec3>>,
    applied_target: Option<DVec3>,
}

/// The handle that moves a [`SimDevice`]'s hand from another thread (wait-free for the servo thread).
pub type HandTargetInput = triple_buffer::Input<Option<DVec3>>;

impl SimDevice {
    /// An arm built from `config`, at rest at `start_m`, stepped `dt_s` per force; and the input that sets
    /// its hand target.
    pub fn new(
        config: SimArmConfig,
        start_m: DVec3,
        dt_s: f64,
    ) -> Result<(SimDevice, HandTargetInput), SimError> {
        let arm = SimArm::new(config, start_m)?;
        // Check the tick length now: `step` would refuse it on every tick otherwise.
        arm.clone().step(0.0, dt_s, DVec3::ZERO)?;
        let (input, output) = triple_buffer::triple_buffer(&None);
        let info = DeviceInfo {
            model: "voxhap simulated arm".to_owned(),
            serial_number: "in-process".to_owned(),
            position_dof: 3,
            force_dof: 3,
            button_count: 0,
            workspace_min_m: DVec3::splat(-1.0),
            workspace_max_m: DVec3::splat(1.0),
            max_force_n: 10.0,
            max_stiffness_n_per_m: 5000.0,
            max_speed_m_per_s: crate::device::info::DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: true,
            state_rates_hz: Vec::new(),
        };
        Ok((
            SimDevice {
                arm,
                dt_s,
                t_s: 0.0,
                info,
                hand_target: output,
                applied_target: None,
            },
            input,
        ))
    }

    /// The hand target in force, if a client set one.
    pub fn hand_target_m(&self) -> Option<DVec3> {
        self.applied_target
    }
}

impl HapticDevice for SimDevice {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let target = *self.hand_target.read();
        if target != self.applied_target && self.arm.set_hand_target_m(target) {
            self.applied_target = target;
        }
        self.arm
            .step(self.t_s, self.dt_s, force_n)
            .map_err(|_| DeviceError::Protocol {
                what: "simulated arm refused its step",
            })?;
        self.t_s += self.dt_s;
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        Ok(DeviceState {
            position_m: self.arm.position_m(),
            velocity_m_per_s: self.arm.velocity_m_per_s(),
            buttons: 0,
            device_time_us: Some((self.t_s * 1e6) as u64),
            sequence: None,
            status: None,
        })
    }
}
