//! The in-process simulated arm as a [`HapticDevice`] ([`SimDevice`]), the default device: a [`SimArm`]
//! stepped one servo period per force written, its virtual hand following a scripted path, or, when a client
//! sets one through the session, a hand target (a triple buffer, so setting it never blocks the servo thread).
//!
//! Frames: the scripted path and the start point are scene positions. Under a workspace mapping the arm is told
//! the mapping once it is known ([`SimDevice::follow_scene_mapping`]: `servo::mapped::MappedDevice` fills the
//! slot when it connects, before the first exchange) and moves them into the device frame
//! ([`SimArm::use_scene_frame`]). A hand target arrives already in the device frame (`servo::control` maps it).
//!
//! **Local model** ([`SimDevice::with_local_model`]): the arm simulates a device with the local-model capability
//! (protocol/SPEC.md section 10) whose control loop runs at its own rate. Each servo period is then split into
//! that many control cycles, each running the reference device loop (`voxhap-local`, behind the protocol's
//! device session, as a firmware or `voxhap mock-device --local-model` runs it) and stepping the arm one cycle
//! under its force. A LocalModel from the host is rendered by that loop; a set-force is held for the period, as
//! without the capability, so the two paths differ only in who closes the contact loop and how fast.

use super::local::{LocalDevice, LocalRateError};
use crate::mapped::SceneMappingSlot;
use glam::DVec3;
use voxhap_device::local_offer::{LocalOffer, LocalReport};
use voxhap_device::sim::{SimArm, SimArmConfig, SimError};
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};
use voxhap_protocol::HostToDevice;

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
    /// The simulated local loop, when the arm simulates a device with the capability.
    local: Option<Box<LocalDevice>>,
    /// What the local loop reported at the end of the last period.
    local_report: Option<LocalReport>,
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
                local: None,
                local_report: None,
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

    /// The arm as a device with the local-model capability whose control loop runs at `rate_hz` (a whole
    /// multiple of the servo rate, at most 100 kHz); see the module docs.
    pub fn with_local_model(mut self, rate_hz: f64) -> Result<SimDevice, LocalRateError> {
        self.local = Some(Box::new(LocalDevice::new(
            1.0 / self.dt_s,
            rate_hz,
            "voxhap-sim",
            self.info.max_force_n,
            self.info.max_stiffness_n_per_m,
        )?));
        Ok(self)
    }

    /// One servo period of the simulated local-model device after `message` arrived: its control cycles, each
    /// sensing, running the device loop and stepping the arm.
    fn run_local_period(&mut self, message: &HostToDevice) -> Result<(), DeviceError> {
        let Some(local) = self.local.as_deref_mut() else {
            return Ok(());
        };
        local.receive(message);
        let cycle_s = self.dt_s / f64::from(local.cycles_per_period());
        for _ in 0..local.cycles_per_period() {
            let force = local.cycle(self.arm.position_m(), self.arm.velocity_m_per_s());
            self.arm
                .step(self.t_s, cycle_s, force)
                .map_err(|_| DeviceError::Protocol {
                    what: "simulated arm refused its step",
                })?;
            self.t_s += cycle_s;
        }
        self.local_report = local.local_report();
        Ok(())
    }

    /// Takes the mapping if it has arrived and moves the hand to the target a client set, before a step.
    fn before_step(&mut self) -> Result<(), DeviceError> {
        self.take_scene_mapping(true)?;
        let target = *self.hand_target.read();
        if target != self.applied_target && self.arm.set_hand_target_m(target) {
            self.applied_target = target;
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
        self.before_step()?;
        if let Some(local) = self.local.as_deref_mut() {
            // The device's set-force path: the force is held for the period, the arm stepped per cycle.
            let message = local.set_force_message(force_n);
            return self.run_local_period(&message);
        }
        self.arm
            .step(self.t_s, self.dt_s, force_n)
            .map_err(|_| DeviceError::Protocol {
                what: "simulated arm refused its step",
            })?;
        self.t_s += self.dt_s;
        Ok(())
    }

    fn enable(&mut self) -> Result<(), DeviceError> {
        if let Some(local) = self.local.as_deref_mut() {
            // The simulated device's own drive: enabled again (after its watchdog, say) as a real one would be.
            local.enable();
        }
        Ok(())
    }

    fn local_model_capable(&self) -> bool {
        self.local.is_some()
    }

    fn write_local_model(
        &mut self,
        model: &LocalOffer,
        force_limit_n: f64,
        fallback_force_n: DVec3,
    ) -> Result<(), DeviceError> {
        self.before_step()?;
        let Some(local) = self.local.as_deref_mut() else {
            return self.write_force(fallback_force_n);
        };
        match local.model_message(model, force_limit_n) {
            Ok(message) => self.run_local_period(&message),
            Err(_) => self.write_force(fallback_force_n),
        }
    }

    fn local_report(&self) -> Option<LocalReport> {
        self.local_report
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
    use voxhap_device::sim::{HandParams, HandPath};

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

    /// Arm damping of the wall tests, N s/m; the hand adds none.
    const ARM_DAMPING: f64 = 1.0;

    /// An arm of 0.1 kg with [`ARM_DAMPING`] (the hand holds 3 mm inside a wall at x = 0 facing -x, with a
    /// 50 N/m spring and no damping of its own), simulating a local-model device at 10 kHz; started 2 mm in
    /// front of the wall.
    fn wall_arm() -> SimDevice {
        let mut config = voxhap_device::mock::default_arm_config();
        config.arm.damping_n_s_per_m = ARM_DAMPING;
        config.hand = HandParams {
            stiffness_n_per_m: 50.0,
            damping_n_s_per_m: 0.0,
        };
        config.path = HandPath::Hold {
            at_m: DVec3::new(0.003, 0.0, 0.0),
        };
        SimDevice::new(config, DVec3::new(-0.002, 0.0, 0.0), 1e-3)
            .unwrap()
            .0
            .with_local_model(10_000.0)
            .unwrap()
    }

    /// Three seconds of a 1 kHz host rendering the wall at `k_n_per_m` (the proxy of a 50 N plane is the probe
    /// pushed back onto the plane), through set-forces or (`local`) as local models; returns how often the
    /// handle left the wall after first touching it, in the last two seconds.
    fn exits_from_the_wall(k_n_per_m: f64, local: bool) -> usize {
        let mut device = wall_arm();
        let plane = voxhap_solver::Primitive::plane(DVec3::ZERO, DVec3::NEG_X, 50.0).unwrap();
        let mut exits = 0;
        let mut inside = false;
        for tick in 0..3000 {
            let state = device.read_state().unwrap();
            let probe = state.position_m;
            let proxy = DVec3::new(probe.x.min(0.0), probe.y, probe.z);
            let force = k_n_per_m * (proxy - probe);
            if local {
                let offer = crate::local_model::offer(&[plane], k_n_per_m, 0.0, proxy);
                device.write_local_model(&offer, 10.0, force).unwrap();
            } else {
                device.write_force(force).unwrap();
            }
            let now_inside = device.read_state().unwrap().position_m.x > 0.0;
            if tick >= 1000 && inside && !now_inside {
                exits += 1;
            }
            inside = now_inside;
        }
        exits
    }

    #[test]
    fn a_wall_above_the_host_rate_bound_bounces_with_set_forces_and_holds_with_a_10_khz_local_model(
    ) {
        // Colgate and Schenkel: a sampled wall is passive while K < 2 b / T, here 2 000 N/m at the host's
        // 1 kHz and 20 000 N/m at the device's 10 kHz (docs/stability.md).
        let host_bound = 2.0 * ARM_DAMPING / 1e-3;
        let local_bound = 2.0 * ARM_DAMPING / 1e-4;
        assert_eq!((host_bound, local_bound), (2000.0, 20_000.0));
        // Half the host's bound: both hold.
        assert_eq!(exits_from_the_wall(0.5 * host_bound, false), 0);
        assert_eq!(exits_from_the_wall(0.5 * host_bound, true), 0);
        // 2.5 times the host's bound, an eighth of the device's: the host's loop bounces off the wall, the
        // device's own loop holds it.
        let k = 2.5 * host_bound;
        let host_exits = exits_from_the_wall(k, false);
        assert!(
            host_exits > 10,
            "the 1 kHz loop left the wall {host_exits} times"
        );
        assert_eq!(exits_from_the_wall(k, true), 0);
    }

    #[test]
    fn a_local_rate_that_is_not_a_multiple_of_the_servo_rate_is_refused() {
        let config = voxhap_device::mock::default_arm_config();
        let device = || SimDevice::new(config.clone(), DVec3::ZERO, 1e-3).unwrap().0;
        assert!(device().with_local_model(10_000.0).is_ok());
        for bad in [1500.0, 0.0, -1000.0, f64::NAN, 200_000.0, 3_000.0 * 1.0001] {
            let error = device().with_local_model(bad).err().unwrap();
            assert!(error.to_string().contains("local_model.rate_hz"), "{error}");
        }
    }

    #[test]
    fn a_mapping_that_arrives_after_the_first_step_is_not_taken() {
        let mut device = arm_after_steps(false);
        assert!((device.read_state().unwrap().position_m - START_M).length() < 1e-12);
    }
}
