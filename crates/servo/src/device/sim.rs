//! The in-process simulated arm as a [`HapticDevice`] ([`SimDevice`]), the default device: a [`SimArm`]
//! stepped one servo period per force written, its virtual hand following a scripted path, or, when a client
//! sets one through the session, a hand target (a triple buffer, so setting it never blocks the servo thread).
//!
//! Frames: the scripted path and the start point are scene positions. Under a workspace mapping the arm is told
//! the mapping once it is known ([`SimDevice::follow_scene_mapping`]: `servo::mapped::MappedDevice` fills the
//! slot when it connects, before the first exchange) and moves them into the device frame
//! ([`SimArm::use_scene_frame`]). A hand target arrives already in the device frame (`servo::control` maps it).

use crate::mapped::SceneMappingSlot;
use glam::DVec3;
use voxhap_device::sim::{SimArm, SimArmConfig, SimError};
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};

/// The simulated arm as a [`HapticDevice`]: each `write_force` steps the arm one servo period under that
/// force; `read_state` reports where it got to.
pub struct SimDevice {
    arm: SimArm,
    dt_s: f64,
    t_s: f64,
    info: DeviceInfo,
    hand_target: triple_buffer::Output<Option<DVec3>>,
    applied_target: Option<DVec3>,
    /// The start point as given (scene frame), for when the mapping arrives.
    start_scene_m: DVec3,
    /// Where the workspace mapping will be, until the arm has taken it or has stepped.
    scene_mapping: Option<SceneMappingSlot>,
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
        // The stiffness cap follows the arm's [arm] table (voxhap_device::physics): declared so that the
        // session's `CouplingCaps` caps at b / (T/2 + tau) at this period.
        let declared_n_per_m = config
            .physics()
            .declared_at_1khz_n_per_m(dt_s)
            .max(f64::MIN_POSITIVE);
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
            max_stiffness_n_per_m: declared_n_per_m,
            max_speed_m_per_s: voxhap_device::info::DEFAULT_MAX_SPEED_M_PER_S,
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
                start_scene_m: start_m,
                scene_mapping: None,
            },
            input,
        ))
    }

    /// Reads the scripted path and the start point as scene positions under the mapping `slot` will hold
    /// (filled by `MappedDevice::connect`). The arm takes it on its first exchange (state read or force
    /// written) after the slot is filled and before its first step; an arm whose slot is still empty when
    /// it first steps keeps the device frame (the identity), as an arm without a slot does.
    pub fn follow_scene_mapping(&mut self, slot: SceneMappingSlot) {
        self.scene_mapping = Some(slot);
    }

    /// Takes the mapping from the slot if it is there (an atomic load, nothing allocates); once taken, or
    /// once the arm has stepped, the slot is let go.
    fn take_scene_mapping(&mut self, stepping: bool) -> Result<(), DeviceError> {
        let Some(slot) = &self.scene_mapping else {
            return Ok(());
        };
        if let Some(mapping) = slot.get().copied() {
            self.scene_mapping = None;
            self.arm
                .use_scene_frame(mapping, self.start_scene_m)
                .map_err(|_| DeviceError::Protocol {
                    what: "simulated arm: start_m mapped into the device frame is not finite",
                })?;
        } else if stepping {
            self.scene_mapping = None;
        }
        Ok(())
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
        self.take_scene_mapping(true)?;
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
        self.take_scene_mapping(false)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use voxhap_device::mapping::WorkspaceMapping;
    use voxhap_device::sim::HandPath;

    const START_M: DVec3 = DVec3::new(0.02, 0.01, 0.0);

    /// An arm holding its start point [`START_M`], following a mapping slot; with `mapping_first` the slot is
    /// filled before the first step, otherwise after it. Returns the arm after 100 more steps.
    fn arm_after_steps(mapping_first: bool) -> SimDevice {
        let mut config = voxhap_device::mock::default_arm_config();
        config.path = HandPath::Hold { at_m: START_M };
        let mut device = SimDevice::new(config, START_M, 1e-3).unwrap().0;
        let slot = SceneMappingSlot::default();
        device.follow_scene_mapping(slot.clone());
        if !mapping_first {
            device.write_force(DVec3::ZERO).unwrap();
        }
        let scale_2 = WorkspaceMapping::new(DMat3::IDENTITY, 2.0, DVec3::new(0.1, 0.0, 0.0));
        slot.set(scale_2.unwrap()).unwrap();
        for _ in 0..100 {
            device.write_force(DVec3::ZERO).unwrap();
        }
        device
    }

    #[test]
    fn a_mapping_given_before_the_first_exchange_moves_the_start_into_the_device_frame() {
        // Holding its start, mapped to R^T (start - t) / s, the arm stays there.
        let mut device = arm_after_steps(true);
        let expected = DVec3::new(-0.04, 0.005, 0.0);
        assert!((device.read_state().unwrap().position_m - expected).length() < 1e-12);
    }

    #[test]
    fn a_mapping_that_arrives_after_the_first_step_is_not_taken() {
        let mut device = arm_after_steps(false);
        assert!((device.read_state().unwrap().position_m - START_M).length() < 1e-12);
    }
}
