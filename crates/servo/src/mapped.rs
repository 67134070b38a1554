//! The one place where the device frame becomes the scene frame: [`MappedDevice`] wraps the supervised device
//! the servo thread talks to and applies the profile's [`WorkspaceMapping`] to everything that crosses.
//!
//! Where it sits: between the servo loop (scene frame: the probe, the proxy, the rendered force, the coupling
//! caps) and the supervisor (device frame: the input checks, the force clamp and slew limit, the driver). Per
//! tick it maps the rendered force back to the device (`Rᵀ f`, not scaled), lets the supervisor make it safe and
//! exchange it, then maps the answering state into the scene (`s R p + t`, `s R v`) and the force that went
//! out back into the scene frame (`R f`), so traces and the "repeat the last safe force" fallback stay in one
//! frame. The coupling caps it reports are the device's (lowered by the profile) in scene units: stiffness and
//! damping the hand may feel, divided by the scale (`device::mapping` derives this, after CHAI3D).
//!
//! A mapping that fits the volume (`--fit-volume`, `fit_volume = true`) is computed once, in [`connect`], from
//! the device's declared workspace and the volume bounds given at construction; a reconnect keeps it. The
//! simulated arm, whose scripted path is in the scene frame, is told the mapping through a
//! [`SceneMappingSlot`] that `connect` fills ([`MappedDevice::publish_mapping_to`]).
//!
//! `exchange` and the queries used on the servo thread do a few multiplications: nothing allocates or locks.
//!
//! [`connect`]: ServoDevice::connect

use super::device::{forward_to_wrapped, ConnectError, ServoDevice};
use super::monitor::StopSlot;
use glam::DVec3;
use std::sync::{Arc, OnceLock};
use voxhap_device::mapping::WorkspaceMapping;
use voxhap_device::profile::{DeviceProfile, MappingChoice};
use voxhap_device::safety::DEFAULT_MAX_STIFFNESS_N_PER_M;
use voxhap_device::supervisor::{SupervisorOutput, TickInput};
use voxhap_device::{DeviceInfo, ErrorKind};

/// Where [`MappedDevice::connect`] leaves the mapping it settled on, for a device that needs it itself (the
/// simulated arm reads its scripted path in the scene frame). Set once; reading it is an atomic load.
pub type SceneMappingSlot = Arc<OnceLock<WorkspaceMapping>>;

/// A supervised device seen through a workspace mapping (see the module docs).
pub struct MappedDevice {
    inner: Box<dyn ServoDevice>,
    profile: DeviceProfile,
    volume_bounds_m: Option<(DVec3, DVec3)>,
    mapping: WorkspaceMapping,
    mapping_slot: Option<SceneMappingSlot>,
}

impl MappedDevice {
    /// `inner` seen through `profile`'s mapping; `volume_bounds_m` is what a fitting mapping fits.
    pub fn new(
        inner: Box<dyn ServoDevice>,
        profile: DeviceProfile,
        volume_bounds_m: Option<(DVec3, DVec3)>,
    ) -> MappedDevice {
        let mapping = match profile.mapping {
            MappingChoice::Fixed(mapping) | MappingChoice::FitWhenOutOfReach(mapping) => mapping,
            MappingChoice::FitVolume { .. } => WorkspaceMapping::IDENTITY,
        };
        MappedDevice {
            inner,
            profile,
            volume_bounds_m,
            mapping,
            mapping_slot: None,
        }
    }

    /// Leaves the mapping in `slot` when the device connects (the first connect's mapping stays there).
    pub fn publish_mapping_to(mut self, slot: SceneMappingSlot) -> MappedDevice {
        self.mapping_slot = Some(slot);
        self
    }

    /// The mapping in force (after `connect` for a fitting profile).
    pub fn mapping(&self) -> WorkspaceMapping {
        self.mapping
    }

    /// The profile.
    pub fn profile(&self) -> &DeviceProfile {
        &self.profile
    }

    /// True when the volume was out of reach under the profile's mapping and was fitted automatically
    /// ([`MappingChoice::FitWhenOutOfReach`]).
    pub fn fitted_automatically(&self) -> bool {
        matches!(self.profile.mapping, MappingChoice::FitWhenOutOfReach(given) if given != self.mapping)
    }

    /// The stiffness the hand may feel (N/m): the declaration (or the default when none is stated), lowered
    /// by the profile.
    fn felt_stiffness_limit_n_per_m(&self, declared_n_per_m: f64) -> f64 {
        let declared = if declared_n_per_m.is_finite() && declared_n_per_m > 0.0 {
            declared_n_per_m
        } else {
            DEFAULT_MAX_STIFFNESS_N_PER_M
        };
        self.profile.felt_stiffness_limit_n_per_m(declared)
    }
}

impl ServoDevice for MappedDevice {
    fn exchange(&mut self, mut input: TickInput) -> SupervisorOutput {
        input.force_n = self.mapping.to_device_force_n(input.force_n);
        let mapping = self.mapping;
        input.local = input.local.map(|offer| {
            offer.mapped(
                |p| mapping.to_device_position_m(p),
                |q| mapping.to_device_force_n(q),
                mapping.scale(),
            )
        });
        let mut out = self.inner.exchange(input);
        if let Some(report) = out.local.as_mut() {
            report.proxy_m = self.mapping.to_scene_position_m(report.proxy_m);
            report.force_n = self.mapping.to_scene_force_n(report.force_n);
            // A length: scene metres per device metre.
            report.bound_m *= self.mapping.scale();
        }
        if let Some(state) = out.state.as_mut() {
            state.position_m = self.mapping.to_scene_position_m(state.position_m);
            state.velocity_m_per_s = self
                .mapping
                .to_scene_velocity_m_per_s(state.velocity_m_per_s);
        }
        out.sent_force_n = self.mapping.to_scene_force_n(out.sent_force_n);
        out
    }

    forward_to_wrapped!(inner);

    fn reported_force_n(&self) -> Option<DVec3> {
        self.inner
            .reported_force_n()
            .map(|force| self.mapping.to_scene_force_n(force))
    }

    fn stop(&mut self) {
        self.inner.stop();
    }

    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError> {
        self.inner.connect(now_us)?;
        if let Some(info) = self.inner.info() {
            self.mapping = self
                .profile
                .mapping_for(
                    info.workspace_min_m,
                    info.workspace_max_m,
                    self.volume_bounds_m,
                )
                .map_err(|error| ConnectError {
                    kind: ErrorKind::Unsupported,
                    message: format!("device profile {}: {error}", self.profile.name),
                })?;
        }
        if let Some(slot) = &self.mapping_slot {
            // A later connect computes the same mapping from the same inputs; the first one stays.
            let _ = slot.set(self.mapping);
        }
        Ok(())
    }

    /// The device's record in scene units: its workspace box as mapped into the scene, its stiffness as the
    /// scene may render it (the profile's limit included), its speed as a scene speed. Forces are unchanged.
    fn info(&self) -> Option<DeviceInfo> {
        let mut info = self.inner.info()?;
        let (min, max) = self
            .mapping
            .scene_box_m(info.workspace_min_m, info.workspace_max_m);
        info.workspace_min_m = min;
        info.workspace_max_m = max;
        info.max_stiffness_n_per_m = self.mapping.scene_stiffness_cap_n_per_m(
            self.felt_stiffness_limit_n_per_m(info.max_stiffness_n_per_m),
        );
        info.max_speed_m_per_s = self.mapping.scene_speed_m_per_s(info.max_speed_m_per_s);
        if let Some(limit) = self.profile.limits.max_force_n {
            info.max_force_n = info.max_force_n.min(limit);
        }
        Some(info)
    }

    fn set_stop_slot(&mut self, slot: Arc<StopSlot>) {
        self.inner.set_stop_slot(slot);
    }

    fn workspace_mapping(&self) -> WorkspaceMapping {
        self.mapping
    }

    fn max_damping_n_s_per_m(&self) -> Option<f64> {
        self.profile
            .limits
            .max_damping_n_s_per_m
            .map(|felt| self.mapping.scene_damping_cap_n_s_per_m(felt))
    }

    fn profile_notes(&self) -> Vec<String> {
        let mut notes = match self.inner.info() {
            Some(info) => self.profile.notes_against(&info),
            None => Vec::new(),
        };
        if self.mapping.is_identity() {
            return notes;
        }
        let m = &self.mapping;
        let rows = voxhap_device::mapping::matrix_rows(m.rotation());
        if self.fitted_automatically() {
            let translation = m
                .translation_m()
                .to_array()
                .map(|v| (v * 1e4).round() / 1e4);
            notes.push(format!(
                "device profile {}: the volume does not fit in the device's workspace under the profile's \
                 mapping, so it was fitted: scale {:.4} (scene m per device m), translation {:?} m; the hand \
                 feels the scene's stiffness x {:.4}. Turn this off with --no-fit-volume, or give a [mapping] in \
                 a profile (--device-profile FILE)",
                self.profile.name,
                m.scale(),
                translation,
                m.scale()
            ));
            return notes;
        }
        notes.push(format!(
            "device profile {}: scene = {:.4} x R x device + {:?} m, R = {:?}; the hand feels the scene's \
             stiffness x {:.4}",
            self.profile.name,
            m.scale(),
            m.translation_m().to_array(),
            rows,
            m.scale()
        ));
        notes
    }

    fn max_stiffness_n_per_m(&self) -> Option<f64> {
        self.inner.max_stiffness_n_per_m().map(|declared| {
            self.mapping
                .scene_stiffness_cap_n_per_m(self.felt_stiffness_limit_n_per_m(declared))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;
    use voxhap_device::profile::DeviceProfile;
    use voxhap_device::safety::CouplingCaps;
    use voxhap_device::supervisor::{Supervisor, SupervisorConfig};
    use voxhap_device::{DeviceError, DeviceState, HapticDevice};

    /// A device that logs every force it receives, sits where it is told, and declares 2000 N/m.
    struct LoggingArm {
        info: DeviceInfo,
        position_m: Arc<Mutex<DVec3>>,
        forces: Arc<Mutex<Vec<DVec3>>>,
    }

    impl HapticDevice for LoggingArm {
        type Error = DeviceError;
        fn info(&self) -> &DeviceInfo {
            &self.info
        }
        fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
            self.forces.lock().unwrap().push(force_n);
            Ok(())
        }
        fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
            Ok(DeviceState::at_rest(*self.position_m.lock().unwrap()))
        }
    }

    type Shared<T> = Arc<Mutex<T>>;

    fn mapped(profile_text: &str) -> (MappedDevice, Shared<DVec3>, Shared<Vec<DVec3>>) {
        let position = Arc::new(Mutex::new(DVec3::new(0.01, 0.02, 0.03)));
        let forces = Arc::new(Mutex::new(Vec::new()));
        let mut info = DeviceInfo::basic("logging arm", DVec3::splat(-0.05), DVec3::splat(0.05));
        info.max_stiffness_n_per_m = 2000.0;
        info.max_force_n = 10.0;
        let arm = LoggingArm {
            info,
            position_m: position.clone(),
            forces: forces.clone(),
        };
        let mut slot = Some(arm);
        let mut config = SupervisorConfig {
            steady_ticks_before_enable: 1,
            ..SupervisorConfig::default()
        };
        config.safety.ramp_time_us = 0;
        config.safety.engage_ticks = 1;
        config.safety.slew_n_per_ms = 100.0;
        config.safety.max_force_n = 10.0;
        let supervisor = Supervisor::new(config, move || {
            slot.take().ok_or(DeviceError::Config {
                what: "opened twice".to_owned(),
            })
        })
        .unwrap();
        let profile = DeviceProfile::parse(profile_text, "test").unwrap();
        let bounds = Some((DVec3::splat(-0.1), DVec3::new(0.1, 0.1, 0.3)));
        (
            MappedDevice::new(Box::new(supervisor), profile, bounds),
            position,
            forces,
        )
    }

    /// [`mapped`], connected.
    fn connected(profile_text: &str) -> (MappedDevice, Shared<DVec3>, Shared<Vec<DVec3>>) {
        let (mut device, position, forces) = mapped(profile_text);
        device.connect(0).unwrap();
        (device, position, forces)
    }

    fn run(
        device: &mut MappedDevice,
        now_us: &mut u64,
        force_n: DVec3,
        ticks: u64,
    ) -> SupervisorOutput {
        let mut out = None;
        for _ in 0..ticks {
            *now_us += 1000;
            out = Some(device.exchange(TickInput::at(force_n, *now_us)));
        }
        out.unwrap()
    }

    #[test]
    fn positions_come_in_mapped_and_forces_go_out_rotated_back_unscaled() {
        let (mut device, _position, forces) = connected(
            "[mapping]\nscale = 4\ntranslation_m = [1, 2, 3]\nrotation_deg = [0, 0, 90]\n",
        );
        let out = run(&mut device, &mut 0, DVec3::new(0.0, 1.0, 0.0), 50);
        let state = out.state.unwrap();
        // R about z by 90°: (x, y, z) -> (-y, x, z); then × 4, + t.
        let expected = DVec3::new(1.0 - 0.08, 2.0 + 0.04, 3.0 + 0.12);
        assert!(
            (state.position_m - expected).length() < 1e-12,
            "{}",
            state.position_m
        );
        // The device received the scene's +y force as its +x force, 1 N, unscaled.
        let last = *forces.lock().unwrap().last().unwrap();
        assert!(
            (last - DVec3::new(1.0, 0.0, 0.0)).length() < 1e-12,
            "{last}"
        );
        // And the trace sees the sent force in the scene frame.
        assert!((out.sent_force_n - DVec3::new(0.0, 1.0, 0.0)).length() < 1e-12);
    }

    /// The scene's stiffness and damping limits are the profile's (or the device's) divided by the scale.
    #[test]
    fn the_scene_limits_are_the_device_limits_divided_by_the_scale() {
        for (profile, stiffness_n_per_m, damping_n_s_per_m) in [
            // The profile's 1500 N/m / 10; no damping limit in the profile: none.
            (
                "[mapping]\nscale = 10\n[limits]\nmax_stiffness_n_per_m = 1500\n",
                150.0,
                None,
            ),
            // The device's declared 2000 N/m / 4; the profile's 0.2 N s/m / 4.
            (
                "[mapping]\nscale = 4\n[limits]\nmax_damping_n_s_per_m = 0.2\n",
                500.0,
                Some(0.05),
            ),
        ] {
            let (device, _, _) = connected(profile);
            let cap = device.max_stiffness_n_per_m().unwrap();
            assert!((cap - stiffness_n_per_m).abs() < 1e-9, "{profile}: {cap}");
            let limit = device.max_damping_n_s_per_m();
            match (limit, damping_n_s_per_m) {
                (None, None) => {}
                (Some(limit), Some(expected)) => {
                    assert!((limit - expected).abs() < 1e-12, "{profile}: {limit}")
                }
                _ => panic!("{profile}: damping limit {limit:?}, expected {damping_n_s_per_m:?}"),
            }
        }
    }

    #[test]
    fn the_stiffness_the_hand_feels_never_exceeds_the_device_or_the_profile() {
        let (mut device, position, forces) =
            connected("[mapping]\nscale = 10\n[limits]\nmax_stiffness_n_per_m = 1500\n");
        // The scene may render at most 1500 / 10 N/m.
        let cap = device.max_stiffness_n_per_m().unwrap();
        let caps = CouplingCaps::new(cap, 1e-3);
        let (k, _) = caps.cap(10_000.0, 0.0);
        // A spring at that stiffness, proxy at the mapped start, hand moved 2 mm: the device is asked for
        // at most 1500 N/m × 2 mm = 3 N.
        let now_us = &mut 0;
        run(&mut device, now_us, DVec3::ZERO, 50);
        let proxy_scene = device
            .mapping()
            .to_scene_position_m(*position.lock().unwrap());
        *position.lock().unwrap() += DVec3::new(0.002, 0.0, 0.0);
        let out = run(&mut device, now_us, DVec3::ZERO, 1);
        let probe_scene = out.state.unwrap().position_m;
        let scene_force = k * (proxy_scene - probe_scene);
        run(&mut device, now_us, scene_force, 1);
        let felt = forces.lock().unwrap().last().unwrap().length();
        assert!(felt <= 1500.0 * 0.002 + 1e-9, "felt {felt} N");
        assert!(felt > 2.99, "felt {felt} N: the cap was not reached");
        let info = device.info().unwrap();
        assert!((info.max_stiffness_n_per_m - 150.0).abs() < 1e-9);
        // 1500 N/m is below the declared 2000: nothing to say but the mapping.
        let notes = device.profile_notes();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("stiffness x 10.0000"), "{notes:?}");
        assert!((info.workspace_max_m - DVec3::splat(0.5)).length() < 1e-12);
    }

    #[test]
    fn a_profile_damping_limit_is_felt_damping_divided_by_the_scale() {
        let (device, _, _) =
            connected("[mapping]\nscale = 4\n[limits]\nmax_damping_n_s_per_m = 0.2\n");
        let caps = CouplingCaps::new(device.max_stiffness_n_per_m().unwrap(), 1e-3)
            .with_damping_limit(device.max_damping_n_s_per_m());
        // 2000 N/m declared / 4 = 500 N/m in the scene; passivity would allow 0.25 - 0.05 = 0.2 N s/m at
        // k = 100: the profile's 0.05 wins.
        assert_eq!(caps.cap(100.0, 1.0), (100.0, 0.05));
    }

    #[test]
    fn a_fitting_profile_fits_when_it_connects() {
        let (mut device, _, _) = mapped("[mapping]\nfit_volume = true\n");
        assert!(device.mapping().is_identity());
        device.connect(0).unwrap();
        // Device ±5 cm; volume 0.2 x 0.2 x 0.4 m: the z ratio 4 wins; centre (0, 0, 0.1).
        assert!((device.mapping().scale() - 4.0).abs() < 1e-12);
        assert!(
            (device.mapping().to_scene_position_m(DVec3::ZERO) - DVec3::new(0.0, 0.0, 0.1))
                .length()
                < 1e-12
        );
    }
}
