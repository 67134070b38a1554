//! Workspace mapping: where the handle's position in the device frame lands in the scene, and how the scene's
//! force, stiffness and damping reach the hand. One [`WorkspaceMapping`] per device, the same convention for
//! every device.
//!
//! Where it sits: between the supervisor (which works in the device frame: its input checks, clamp and slew
//! limit are about the physical handle) and the servo tick (which works in the scene frame, the frame of the
//! volumes). `servo::mapped::MappedDevice` applies it at that one place: positions and velocities go
//! device → scene, forces go scene → device, and the coupling caps are converted to scene units.
//!
//! # The convention (CHAI3D's workspace scale factor)
//!
//! A mapping is a rotation `R` (proper: orthonormal, det +1), a uniform scale `s > 0` (scene metres per device
//! metre) and a translation `t` (m, scene frame):
//!
//! ```text
//! x_scene = s R x_device + t          v_scene = s R v_device
//! f_device = Rᵀ f_scene               (a force is not scaled)
//! ```
//!
//! This is CHAI3D's convention (chai3d/chai3d 3.3.0, src/tools/CGenericTool.cpp): `updateFromDevice` computes
//! `m_deviceLocalPos = m_workspaceScaleFactor * devicePos` and `m_deviceGlobalPos = m_globalPos + m_globalRot *
//! m_deviceLocalPos` (lines 760-763), scales the velocity the same way (line 772), and `setDeviceGlobalForce`
//! sends `m_deviceLocalForce = cTranspose(m_globalRot) * m_deviceGlobalForce` (line 545): forces are rotated
//! back, never scaled. `setWorkspaceRadius` sets the factor to `radius_scene / radius_device` (line 1115).
//! What the scale changes is the stiffness: CHAI3D's examples (examples/GLFW/13-primitives/13-primitives.cpp
//! line 409) cap a material's stiffness at `m_maxLinearStiffness / workspaceScaleFactor`.
//!
//! # What the hand feels
//!
//! The scene renders a coupling spring `k` (N per scene metre) and damping `b` (N s per scene metre). Moving the
//! hand by `d` (device metres) moves the probe by `s d` in the scene, so the force changes by `k s d`:
//!
//! ```text
//! k_felt = s k_scene        b_felt = s b_scene        speed_scene = s speed_device
//! ```
//!
//! A device declares what it renders stably in its own units (`K₁` N/m at 1 kHz): the scene stiffness is capped
//! at `K₁ / s`, and the damping at `B_max / s`, so that the hand never feels more than the device declared.
//! Because both caps divide by the same `s`, the passivity bound `b_device > K T / 2 + B` used by
//! `safety::CouplingCaps` holds in either unit: [`WorkspaceMapping::scene_stiffness_cap_n_per_m`] applied to the
//! declaration, then `CouplingCaps` in scene units, gives exactly the device-unit caps divided by `s`. Forces
//! (N) are the same number in both frames, so the force limit and the slew limit are not scaled. A scene that
//! is ten times larger than the device (`s` = 10) can therefore only be as stiff as a tenth of the device's
//! stiffness in scene units; its surfaces still feel `K₁` at most.
//!
//! Nothing here allocates; every function is a few multiplications, safe on the servo thread.

use glam::{DMat3, DVec3};

/// How far a rotation matrix may be from orthonormal (max abs element of `RᵀR - I`).
const ORTHONORMAL_TOLERANCE: f64 = 1e-6;
/// Smallest and largest scale accepted (scene metres per device metre).
pub const SCALE_RANGE: (f64, f64) = (1e-6, 1e6);

/// Why a mapping cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MappingError {
    /// The scale is not a finite number in [`SCALE_RANGE`].
    #[error("workspace scale {0} must be a finite number between 1e-6 and 1e6 (scene metres per device metre)")]
    Scale(f64),
    /// The translation has a non-finite component.
    #[error("workspace translation {0:?} must be finite (m)")]
    Translation([f64; 3]),
    /// The rotation is not a proper rotation.
    #[error("workspace rotation {rows:?} is not a rotation: {problem}")]
    Rotation {
        /// The matrix, rows.
        rows: [[f64; 3]; 3],
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A box to fit has a non-finite or inverted corner, or no extent at all.
    #[error("cannot fit {what}: {problem}")]
    Fit {
        /// Which box.
        what: &'static str,
        /// What is wrong with it.
        problem: &'static str,
    },
}

/// Device frame → scene frame: `x_scene = s R x_device + t` (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkspaceMapping {
    rotation: DMat3,
    scale: f64,
    translation_m: DVec3,
}

impl Default for WorkspaceMapping {
    fn default() -> Self {
        WorkspaceMapping::IDENTITY
    }
}

/// The rows of a matrix (for messages and files).
pub fn matrix_rows(m: DMat3) -> [[f64; 3]; 3] {
    let t = m.transpose();
    [
        t.x_axis.to_array(),
        t.y_axis.to_array(),
        t.z_axis.to_array(),
    ]
}

/// A matrix from its rows.
pub fn matrix_from_rows(rows: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols_array_2d(&rows).transpose()
}

/// The rotation `Rz(z) Ry(y) Rx(x)`: about the device's x axis by `x` first, then about the fixed y axis, then
/// about the fixed z axis (degrees).
pub fn rotation_from_degrees(xyz_deg: [f64; 3]) -> DMat3 {
    let [x, y, z] = xyz_deg.map(f64::to_radians);
    DMat3::from_rotation_z(z) * DMat3::from_rotation_y(y) * DMat3::from_rotation_x(x)
}

impl WorkspaceMapping {
    /// The device frame is the scene frame.
    pub const IDENTITY: WorkspaceMapping = WorkspaceMapping {
        rotation: DMat3::IDENTITY,
        scale: 1.0,
        translation_m: DVec3::ZERO,
    };

    /// A mapping, checked: `rotation` must be orthonormal with determinant +1 (a mirror would turn a
    /// right-handed scene into a left-handed hand), `scale` in [`SCALE_RANGE`], `translation_m` finite.
    pub fn new(
        rotation: DMat3,
        scale: f64,
        translation_m: DVec3,
    ) -> Result<WorkspaceMapping, MappingError> {
        if !(scale.is_finite() && (SCALE_RANGE.0..=SCALE_RANGE.1).contains(&scale)) {
            return Err(MappingError::Scale(scale));
        }
        if !translation_m.is_finite() {
            return Err(MappingError::Translation(translation_m.to_array()));
        }
        let rows = matrix_rows(rotation);
        if !rotation.is_finite() {
            return Err(MappingError::Rotation {
                rows,
                problem: "it has a non-finite element",
            });
        }
        let off = (rotation.transpose() * rotation - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |worst, e| worst.max(e.abs()));
        if off > ORTHONORMAL_TOLERANCE {
            return Err(MappingError::Rotation {
                rows,
                problem: "its rows are not orthonormal unit vectors",
            });
        }
        if rotation.determinant() < 0.0 {
            return Err(MappingError::Rotation {
                rows,
                problem: "its determinant is -1 (a mirror); swap the sign of one row",
            });
        }
        Ok(WorkspaceMapping {
            rotation,
            scale,
            translation_m,
        })
    }

    /// The rotation `R` (device axes → scene axes).
    pub fn rotation(&self) -> DMat3 {
        self.rotation
    }

    /// The scale `s` (scene metres per device metre).
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The translation `t` (m, scene frame): where the device's origin lands.
    pub fn translation_m(&self) -> DVec3 {
        self.translation_m
    }

    /// True for the identity (nothing to do).
    pub fn is_identity(&self) -> bool {
        *self == WorkspaceMapping::IDENTITY
    }

    /// A handle position in the scene: `s R p + t`.
    pub fn to_scene_position_m(&self, device_m: DVec3) -> DVec3 {
        self.scale * (self.rotation * device_m) + self.translation_m
    }

    /// A scene position in the device frame: `Rᵀ (p - t) / s`.
    pub fn to_device_position_m(&self, scene_m: DVec3) -> DVec3 {
        self.rotation.transpose() * (scene_m - self.translation_m) / self.scale
    }

    /// A handle velocity in the scene: `s R v`.
    pub fn to_scene_velocity_m_per_s(&self, device_m_per_s: DVec3) -> DVec3 {
        self.scale * (self.rotation * device_m_per_s)
    }

    /// A scene velocity in the device frame: `Rᵀ v / s`.
    pub fn to_device_velocity_m_per_s(&self, scene_m_per_s: DVec3) -> DVec3 {
        self.rotation.transpose() * scene_m_per_s / self.scale
    }

    /// A scene force as the device renders it: `Rᵀ f` (not scaled).
    pub fn to_device_force_n(&self, scene_n: DVec3) -> DVec3 {
        self.rotation.transpose() * scene_n
    }

    /// A device force in the scene frame: `R f`.
    pub fn to_scene_force_n(&self, device_n: DVec3) -> DVec3 {
        self.rotation * device_n
    }

    /// The stiffness the hand feels for a scene stiffness: `s k`.
    pub fn felt_stiffness_n_per_m(&self, scene_n_per_m: f64) -> f64 {
        self.scale * scene_n_per_m
    }

    /// The largest scene stiffness that the hand feels as at most `felt_n_per_m`: `k / s`.
    pub fn scene_stiffness_cap_n_per_m(&self, felt_n_per_m: f64) -> f64 {
        felt_n_per_m / self.scale
    }

    /// The largest scene damping that the hand feels as at most `felt_n_s_per_m`: `b / s`.
    pub fn scene_damping_cap_n_s_per_m(&self, felt_n_s_per_m: f64) -> f64 {
        felt_n_s_per_m / self.scale
    }

    /// A handle speed as a speed in the scene: `s v`.
    pub fn scene_speed_m_per_s(&self, device_m_per_s: f64) -> f64 {
        self.scale * device_m_per_s
    }

    /// The axis-aligned scene box that holds the device box `[min, max]` (its eight corners mapped).
    pub fn scene_box_m(&self, device_min_m: DVec3, device_max_m: DVec3) -> (DVec3, DVec3) {
        let center = self.to_scene_position_m((device_min_m + device_max_m) / 2.0);
        let half = (device_max_m - device_min_m).abs() / 2.0;
        let extent = self.scale * abs_matrix(self.rotation) * half;
        (center - extent, center + extent)
    }

    /// True when every point of the scene box `[scene_min, scene_max]` (a volume's bounds) is reachable under
    /// this mapping: its eight corners, mapped into the device frame, lie inside the device box
    /// `[device_min, device_max]` (with 1 µm of slack for rounding) on every axis the device moves in (a
    /// planar device's flat axis is skipped, as [`WorkspaceMapping::fit`] skips it).
    pub fn reaches(
        &self,
        device_min_m: DVec3,
        device_max_m: DVec3,
        scene_min_m: DVec3,
        scene_max_m: DVec3,
    ) -> bool {
        const SLACK_M: f64 = 1e-6;
        (0..8).all(|corner| {
            let scene = DVec3::new(
                if corner & 1 != 0 {
                    scene_max_m.x
                } else {
                    scene_min_m.x
                },
                if corner & 2 != 0 {
                    scene_max_m.y
                } else {
                    scene_min_m.y
                },
                if corner & 4 != 0 {
                    scene_max_m.z
                } else {
                    scene_min_m.z
                },
            );
            let device = self.to_device_position_m(scene);
            (0..3).all(|axis| {
                device_max_m[axis] <= device_min_m[axis]
                    || (device[axis] >= device_min_m[axis] - SLACK_M
                        && device[axis] <= device_max_m[axis] + SLACK_M)
            })
        })
    }

    /// The mapping that fits a scene box (a volume's bounds) into the device's workspace box, with the
    /// rotation `rotation` kept. "Fits" means exactly this:
    ///
    /// 1. the centre of the device box maps to the centre of the scene box;
    /// 2. the scale is the smallest for which every point of the scene box is reachable: the scene box,
    ///    rotated into device axes, has extents `e_i`; the device box has extents `w_i`; `s = max_i e_i / w_i`
    ///    over the axes where the device has extent (a planar device's flat axis is skipped: the scene is then
    ///    the slice through the box centre);
    /// 3. so the box touches the workspace on at least one axis and lies inside it on the others; no margin is
    ///    added (the input checks already allow positions a little outside the declared box).
    pub fn fit(
        rotation: DMat3,
        device_min_m: DVec3,
        device_max_m: DVec3,
        scene_min_m: DVec3,
        scene_max_m: DVec3,
    ) -> Result<WorkspaceMapping, MappingError> {
        check_box("the device workspace", device_min_m, device_max_m)?;
        check_box("the volume bounds", scene_min_m, scene_max_m)?;
        // Validate the rotation first (scale 1 is always valid).
        WorkspaceMapping::new(rotation, 1.0, DVec3::ZERO)?;
        let device_extent = device_max_m - device_min_m;
        let scene_in_device_axes = abs_matrix(rotation.transpose()) * (scene_max_m - scene_min_m);
        let mut scale: f64 = 0.0;
        for axis in 0..3 {
            if device_extent[axis] > 0.0 {
                scale = scale.max(scene_in_device_axes[axis] / device_extent[axis]);
            }
        }
        if scale <= 0.0 {
            return Err(MappingError::Fit {
                what: "the volume bounds",
                problem: "the volume has no extent along any axis the device moves in",
            });
        }
        let scene_center = (scene_min_m + scene_max_m) / 2.0;
        let device_center = (device_min_m + device_max_m) / 2.0;
        let translation_m = scene_center - scale * (rotation * device_center);
        WorkspaceMapping::new(rotation, scale, translation_m)
    }
}

/// Element-wise absolute value of a matrix (extent of a rotated box).
fn abs_matrix(m: DMat3) -> DMat3 {
    DMat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs())
}

fn check_box(what: &'static str, min: DVec3, max: DVec3) -> Result<(), MappingError> {
    if !(min.is_finite() && max.is_finite()) {
        return Err(MappingError::Fit {
            what,
            problem: "a corner is not finite",
        });
    }
    if min.cmpgt(max).any() {
        return Err(MappingError::Fit {
            what,
            problem: "its minimum corner is above its maximum corner",
        });
    }
    if min == max {
        return Err(MappingError::Fit {
            what,
            problem: "it is a single point",
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::CouplingCaps;
    use proptest::prelude::*;

    fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
        (a - b).abs().max_element() <= tol
    }

    fn mapping_strategy() -> impl Strategy<Value = WorkspaceMapping> {
        (
            prop::array::uniform3(-180.0f64..180.0),
            -2.0f64..2.0,
            prop::array::uniform3(-1.0f64..1.0),
        )
            .prop_map(|(deg, log_scale, t)| {
                WorkspaceMapping::new(
                    rotation_from_degrees(deg),
                    10f64.powf(log_scale),
                    DVec3::from_array(t),
                )
                .expect("valid by construction")
            })
    }

    proptest! {
        #[test]
        fn positions_round_trip(m in mapping_strategy(), p in prop::array::uniform3(-0.5f64..0.5)) {
            let p = DVec3::from_array(p);
            let back = m.to_device_position_m(m.to_scene_position_m(p));
            prop_assert!(close(back, p, 1e-9), "{p} -> {back}");
            let forth = m.to_scene_position_m(m.to_device_position_m(p));
            prop_assert!(close(forth, p, 1e-9 * m.scale().max(1.0)), "{p} -> {forth}");
        }

        #[test]
        fn forces_round_trip_and_keep_their_length(m in mapping_strategy(), f in prop::array::uniform3(-10.0f64..10.0)) {
            let f = DVec3::from_array(f);
            let device = m.to_device_force_n(f);
            prop_assert!((device.length() - f.length()).abs() < 1e-9);
            prop_assert!(close(m.to_scene_force_n(device), f, 1e-9));
        }

        /// A plane rendered in the scene pushes the handle along the mapped normal, and the power the scene
        /// force does on the scene velocity is `s` times the power the device force does on the hand (the
        /// force is not scaled, the velocity is).
        #[test]
        fn a_scene_plane_pushes_the_handle_along_the_mapped_normal(
            m in mapping_strategy(),
            normal in prop::array::uniform3(-1.0f64..1.0),
            v in prop::array::uniform3(-1.0f64..1.0),
        ) {
            let normal = DVec3::from_array(normal);
            prop_assume!(normal.length() > 0.1);
            let scene_force = 2.0 * normal.normalize();
            let device_force = m.to_device_force_n(scene_force);
            // The device-frame normal is the scene normal mapped back by the rotation.
            let device_normal = m.rotation().transpose() * normal.normalize();
            prop_assert!(close(device_force, 2.0 * device_normal, 1e-9));
            let v = DVec3::from_array(v);
            let scene_power = scene_force.dot(m.to_scene_velocity_m_per_s(v));
            let hand_power = device_force.dot(v);
            prop_assert!((scene_power - m.scale() * hand_power).abs() < 1e-9 * m.scale().max(1.0));
        }

        /// The felt stiffness cap is honoured: a scene spring at the scene cap, displaced by the hand, pushes
        /// back with at most the device's declared stiffness times the hand's displacement.
        #[test]
        fn the_felt_stiffness_cap_is_honoured(
            m in mapping_strategy(),
            declared in 100.0f64..10_000.0,
            d in prop::array::uniform3(-0.01f64..0.01),
        ) {
            let hand_displacement = DVec3::from_array(d);
            let k_scene = m.scene_stiffness_cap_n_per_m(declared);
            // The probe moves by s R d in the scene; the proxy stays; the spring pulls back.
            let scene_displacement = m.to_scene_position_m(hand_displacement) - m.to_scene_position_m(DVec3::ZERO);
            let felt = m.to_device_force_n(-k_scene * scene_displacement);
            prop_assert!(felt.length() <= declared * hand_displacement.length() * (1.0 + 1e-9) + 1e-12);
            prop_assert!((m.felt_stiffness_n_per_m(k_scene) - declared).abs() < 1e-9 * declared);
        }
    }

    #[test]
    fn the_coupling_caps_in_scene_units_are_the_device_caps_divided_by_the_scale() {
        let m = WorkspaceMapping::new(DMat3::IDENTITY, 4.0, DVec3::ZERO).unwrap();
        let period_s = 0.5e-3;
        let device = CouplingCaps::new(2000.0, period_s);
        let scene = CouplingCaps::new(m.scene_stiffness_cap_n_per_m(2000.0), period_s);
        assert!((scene.max_stiffness_n_per_m * 4.0 - device.max_stiffness_n_per_m).abs() < 1e-9);
        let k_scene = 100.0;
        let b_scene = scene.max_damping_n_s_per_m(k_scene);
        let b_device = device.max_damping_n_s_per_m(m.felt_stiffness_n_per_m(k_scene));
        assert!(
            (b_scene * 4.0 - b_device).abs() < 1e-12,
            "{b_scene} {b_device}"
        );
    }

    #[test]
    fn chai3d_example_a_scale_of_ten_divides_the_stiffness_cap_by_ten() {
        // 13-primitives.cpp: maxStiffness = m_maxLinearStiffness / workspaceScaleFactor.
        let m = WorkspaceMapping::new(DMat3::IDENTITY, 10.0, DVec3::ZERO).unwrap();
        assert_eq!(m.scene_stiffness_cap_n_per_m(1000.0), 100.0);
        assert_eq!(m.to_scene_position_m(DVec3::new(0.01, 0.0, 0.0)).x, 0.1);
        assert_eq!(m.to_device_force_n(DVec3::X), DVec3::X);
        assert_eq!(m.scene_speed_m_per_s(0.5), 5.0);
    }

    #[test]
    fn bad_mappings_are_refused_with_the_reason() {
        let mirror = DMat3::from_diagonal(DVec3::new(1.0, 1.0, -1.0));
        let error = WorkspaceMapping::new(mirror, 1.0, DVec3::ZERO).unwrap_err();
        assert!(error.to_string().contains("mirror"), "{error}");
        let sheared = matrix_from_rows([[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let error = WorkspaceMapping::new(sheared, 1.0, DVec3::ZERO).unwrap_err();
        assert!(error.to_string().contains("orthonormal"), "{error}");
        for scale in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e7] {
            assert_eq!(
                WorkspaceMapping::new(DMat3::IDENTITY, scale, DVec3::ZERO)
                    .unwrap_err()
                    .to_string(),
                MappingError::Scale(scale).to_string()
            );
        }
        assert!(matches!(
            WorkspaceMapping::new(DMat3::IDENTITY, 1.0, DVec3::new(f64::NAN, 0.0, 0.0)),
            Err(MappingError::Translation(_))
        ));
    }

    #[test]
    fn fitting_a_20_cm_head_into_a_10_cm_workspace() {
        // Inverse3-like cube of ±5 cm; a head volume 20 x 24 x 18 cm centred at (0.01, 0.02, 0.3).
        let device = (DVec3::splat(-0.05), DVec3::splat(0.05));
        let scene = (DVec3::new(-0.09, -0.10, 0.21), DVec3::new(0.11, 0.14, 0.39));
        let m =
            WorkspaceMapping::fit(DMat3::IDENTITY, device.0, device.1, scene.0, scene.1).unwrap();
        // The tallest ratio is y: 0.24 / 0.10.
        assert!((m.scale() - 2.4).abs() < 1e-12);
        let (min, max) = m.scene_box_m(device.0, device.1);
        assert!(min.cmple(scene.0 + 1e-12).all() && max.cmpge(scene.1 - 1e-12).all());
        assert!((max.y - scene.1.y).abs() < 1e-12 && (min.y - scene.0.y).abs() < 1e-12);
        assert!(close(
            m.to_scene_position_m(DVec3::ZERO),
            (scene.0 + scene.1) / 2.0,
            1e-12
        ));
    }

    #[test]
    fn fitting_keeps_the_rotation_and_skips_a_planar_devices_flat_axis() {
        // Haply 2DIY-like: x in [-0.16, 0.16], y in [0, 0.16], z flat; volume 10 cm cube at the origin.
        let device = (DVec3::new(-0.16, 0.0, 0.0), DVec3::new(0.16, 0.16, 0.0));
        let scene = (DVec3::splat(-0.05), DVec3::splat(0.05));
        let m =
            WorkspaceMapping::fit(DMat3::IDENTITY, device.0, device.1, scene.0, scene.1).unwrap();
        assert!((m.scale() - 0.1 / 0.16).abs() < 1e-12);
        assert!(close(
            m.to_scene_position_m(DVec3::new(0.0, 0.08, 0.0)),
            DVec3::ZERO,
            1e-12
        ));
        // Rotated 90 degrees about z: the scene's x extent lies along the device's y.
        let r = rotation_from_degrees([0.0, 0.0, 90.0]);
        let wide = (DVec3::new(-0.2, -0.01, -0.01), DVec3::new(0.2, 0.01, 0.01));
        let m = WorkspaceMapping::fit(r, device.0, device.1, wide.0, wide.1).unwrap();
        assert!((m.scale() - 0.4 / 0.16).abs() < 1e-9, "{}", m.scale());
        assert_eq!(m.rotation(), r);
    }

    #[test]
    fn a_fitted_volume_is_reached_and_a_larger_one_is_not() {
        let device = (DVec3::splat(-0.1), DVec3::splat(0.1));
        let inside = (DVec3::splat(-0.05), DVec3::splat(0.05));
        let big = (DVec3::splat(-0.1), DVec3::splat(0.25));
        let identity = WorkspaceMapping::IDENTITY;
        assert!(identity.reaches(device.0, device.1, inside.0, inside.1));
        assert!(!identity.reaches(device.0, device.1, big.0, big.1));
        let fitted =
            WorkspaceMapping::fit(DMat3::IDENTITY, device.0, device.1, big.0, big.1).unwrap();
        assert!(fitted.reaches(device.0, device.1, big.0, big.1));
        // A planar device: the flat axis is not checked.
        let planar = (DVec3::new(-0.1, -0.1, 0.0), DVec3::new(0.1, 0.1, 0.0));
        assert!(identity.reaches(planar.0, planar.1, inside.0, inside.1));
        // A rotation moves a long box out of reach along the other axis.
        let long = (
            DVec3::new(-0.15, -0.01, -0.01),
            DVec3::new(0.15, 0.01, 0.01),
        );
        let narrow = (DVec3::new(-0.2, -0.05, -0.05), DVec3::new(0.2, 0.05, 0.05));
        assert!(identity.reaches(narrow.0, narrow.1, long.0, long.1));
        let turned =
            WorkspaceMapping::new(rotation_from_degrees([0.0, 0.0, 90.0]), 1.0, DVec3::ZERO)
                .unwrap();
        assert!(!turned.reaches(narrow.0, narrow.1, long.0, long.1));
    }

    #[test]
    fn fitting_refuses_boxes_that_cannot_be_fitted() {
        let unit = (DVec3::splat(-1.0), DVec3::splat(1.0));
        let point = DVec3::splat(0.3);
        let error =
            WorkspaceMapping::fit(DMat3::IDENTITY, unit.0, unit.1, point, point).unwrap_err();
        assert!(error.to_string().contains("single point"), "{error}");
        let error =
            WorkspaceMapping::fit(DMat3::IDENTITY, unit.1, unit.0, unit.0, unit.1).unwrap_err();
        assert!(error.to_string().contains("device workspace"), "{error}");
        let error = WorkspaceMapping::fit(
            DMat3::IDENTITY,
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(0.0, 0.0, -1.0),
            DVec3::new(0.0, 0.0, 1.0),
        )
        .unwrap_err();
        assert!(error.to_string().contains("no extent"), "{error}");
        let error = WorkspaceMapping::fit(
            DMat3::IDENTITY,
            unit.0,
            unit.1,
            DVec3::new(f64::NAN, 0.0, 0.0),
            unit.1,
        )
        .unwrap_err();
        assert!(error.to_string().contains("not finite"), "{error}");
    }
}
