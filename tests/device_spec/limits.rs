//! Plausibility and limits (position glitches, absurd velocities, the stiffness cap) and devices with fewer
//! degrees of freedom (SPEC 6.8).

use crate::util::spec_device::{ForceRecord, SpecDeviceConfig, SpecDeviceHandle, Trigger};
use crate::util::spec_serve::{
    assert_force_invariants, assert_slew_limited, forces_after_trigger, run_on_scene_until,
    run_until_ok, summary, take_turn, tapping_to, tapping_until, BALL_RADIUS_M, FLOWING,
    INSIDE_X_M,
};
use std::sync::Arc;

// ---------------------------------------------------------------------------------------------------------------
// Plausibility and limits.

#[test]
fn a_position_glitch_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    // In light contact (3 mm inside the wall, about 1.5 N), then the encoder jumps 1 cm deeper: the coupling would
    // jump to the host's limit in one tick.
    let config = SpecDeviceConfig {
        position_glitch: Some((FLOWING, [-0.01, 0.0, 0.0])),
        ..tapping_until(BALL_RADIUS_M - 0.003, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "contact, the glitch, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    let forces = device.forces();
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 0.5),
        "no contact before the glitch (the test needs one): {}",
        summary(&forces)
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

/// The handle for the velocity tests: it taps into light contact (3 mm inside the wall, about 1.5 N) and stays
/// there once force flows, so the velocity comes while the host renders force (in free space the device could not
/// tell whether the host had engaged yet).
fn light_contact_until_force_flows() -> SpecDeviceConfig {
    tapping_until(BALL_RADIUS_M - 0.003, FLOWING)
}

#[test]
fn an_absurd_velocity_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        velocity_override: Some((FLOWING, [1e30, 0.0, 0.0])),
        ..light_contact_until_force_flows()
    };
    let device = run_until_ok(
        config,
        5.0,
        "force flowing, the velocity, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

#[test]
fn an_inconsistent_velocity_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        velocity_override: Some((FLOWING, [0.5, 0.0, 0.0])),
        ..light_contact_until_force_flows()
    };
    let device = run_until_ok(
        config,
        5.0,
        "force flowing, the velocity, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

#[test]
fn the_devices_stiffness_cap_holds_from_the_first_tick() {
    let _turn = take_turn();
    let cap_n_per_m = 50.0f32;
    // 0.3 N is 60 % of what the cap allows 1 cm inside the wall, and a tenth of what k = 500 N/m would give there.
    let contact = Trigger::ForceAbove(0.3);
    let config = SpecDeviceConfig {
        max_stiffness_n_per_m: cap_n_per_m,
        ..tapping_until(INSIDE_X_M, contact)
    };
    let device = run_until_ok(
        config,
        0.0,
        "contact, then 500 host ticks (the ramp done)",
        forces_after_trigger(contact, 500),
    );
    let forces = device.forces();
    // 1 cm inside the wall, plus the smooth edge of the ball (two voxels of 1.6 mm) as margin.
    let penetration_m = BALL_RADIUS_M - INSIDE_X_M + 0.0035;
    let bound_n = cap_n_per_m * penetration_m;
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 0.2),
        "the wall was never felt (the test needs contact): {}",
        summary(&forces)
    );
    assert!(
        device.max_force_n() <= bound_n,
        "force above {cap_n_per_m} N/m x {penetration_m} m = {bound_n} N: {}",
        summary(&forces)
    );
}

// ---------------------------------------------------------------------------------------------------------------
// Degrees of freedom (SPEC 6.8): a 2-DOF device uses x and y, a 1-DOF device x alone; the host ignores the other
// components of State and sends them as 0 in SetForce. What such a device should feel is the part of the scene's
// 3-D coupling force along its axes, at a probe on its plane or line (docs/devices/README.md).

/// A scene `[device]` table that puts the device's origin at `translation_m` in the scene (no rotation, scale 1):
/// a 2-DOF device's plane z = 0 becomes the scene plane z = `translation_m[2]`, a 1-DOF device's x axis the scene
/// line through `translation_m` along x.
fn device_offset(translation_m: [f64; 3]) -> String {
    format!("[device]\nname = \"offset\"\n[device.mapping]\ntranslation_m = {translation_m:?}\n")
}

/// The device's declared box for `dof` (SPEC 6.8: the unused axes have no extent).
fn workspace_for(dof: u8) -> ([f32; 3], [f32; 3]) {
    let default = SpecDeviceConfig::default();
    let flat = |v: [f32; 3]| {
        let mut v = v;
        for component in v.iter_mut().skip(usize::from(dof)) {
            *component = 0.0;
        }
        v
    };
    (flat(default.workspace_min_m), flat(default.workspace_max_m))
}

/// A `dof`-DOF device (position and force) declaring `max_force_n`, its handle tapping into the ball to `end_x_m`.
fn device_with_dof(dof: u8, max_force_n: f32, end_x_m: f32) -> SpecDeviceConfig {
    let (workspace_min_m, workspace_max_m) = workspace_for(dof);
    SpecDeviceConfig {
        position_dof: dof,
        force_dof: dof,
        workspace_min_m,
        workspace_max_m,
        max_force_n,
        handle: tapping_to(end_x_m),
        ..SpecDeviceConfig::default()
    }
}

/// Runs `serve` on the ball scene plus `scene_tail` until the device has received a SetForce with x of at least
/// `x_target_n`, or 3 000 SetForce after a light contact (0.3 N applied; a host that never gets there fails the
/// checks after it). The handle keeps tapping, so that a host that starts engagement over gets free space again.
fn run_for_x_force(
    config: SpecDeviceConfig,
    scene_tail: &str,
    x_target_n: f32,
) -> SpecDeviceHandle {
    let contact = Trigger::ForceAbove(0.3);
    let after_contact = forces_after_trigger(contact, 3_000);
    let config = SpecDeviceConfig {
        // A no-op at contact: it makes the device watch for (and log) the trigger.
        call_at: Some((contact, Arc::new(|| {}))),
        ..config
    };
    let (device, status, output) = run_on_scene_until(
        config,
        0.0,
        scene_tail,
        "a SetForce with the expected x, or 3000 host ticks after contact",
        move |device| {
            after_contact(device) || device.forces().iter().any(|f| f.force_n[0] >= x_target_n)
        },
    );
    assert!(status.success(), "serve failed: {output}");
    device
}

/// The SetForce frames whose components beyond the first `dof` are not exactly +0.0.
fn with_unused_components(forces: &[ForceRecord], dof: u8) -> Vec<ForceRecord> {
    forces
        .iter()
        .filter(|f| {
            f.force_n[usize::from(dof)..]
                .iter()
                .any(|c| c.to_bits() != 0)
        })
        .copied()
        .collect()
}

/// The device-side checks every DOF test makes: unused components exactly +0.0 in every SetForce, finite, never
/// above `max_force_n`, slew-limited, zero while not Enabled; and x reached `x_target_n` (the force along the
/// device's axes is what the clamp limits, not the 3-D force it was part of).
fn assert_dof_invariants(device: &SpecDeviceHandle, dof: u8, max_force_n: f32, x_target_n: f32) {
    let forces = device.forces();
    let bad = with_unused_components(&forces, dof);
    assert!(
        bad.is_empty(),
        "{} SetForce with a non-zero component beyond the first {dof} to a {dof}-DOF device (first {:?}); {}",
        bad.len(),
        bad.first(),
        summary(&forces)
    );
    assert_force_invariants(device, max_force_n);
    assert_slew_limited(device);
    let best_x = forces.iter().map(|f| f.force_n[0]).fold(0.0f32, f32::max);
    assert!(
        best_x >= x_target_n,
        "the largest force along x was {best_x} N, expected at least {x_target_n} N; {}",
        summary(&forces)
    );
}

/// A well-behaved 2-DOF device whose plane cuts the ball 1.5 cm above its centre, pressed in to x = 1.5 cm (8.8 mm
/// inside the wall; the 3-D force, about 4.4 N, points 45 degrees out of the plane). It receives x and y only,
/// z exactly 0, and the clamp to its 2 N acts on that in-plane force: x reaches 2 N (clamping the 3-D force first
/// and dropping z afterwards left it at 1.57 N).
#[test]
fn a_two_dof_device_receives_x_and_y_only_clamped_as_sent() {
    receives_its_axes_only_clamped_as_sent(2, [0.0, 0.0, 0.015]);
}

/// A well-behaved 1-DOF device whose line runs 1 cm off the ball's centre in y and in z, pressed in to x = 1.5 cm:
/// the 3-D force (about 4.7 N) has large y and z parts; the device receives x only, y and z exactly 0, and x
/// reaches its 2 N clamp.
#[test]
fn a_one_dof_device_receives_x_only_clamped_as_sent() {
    receives_its_axes_only_clamped_as_sent(1, [0.0, 0.01, 0.01]);
}

/// A `dof`-DOF device of 2 N, its axes mapped `offset_m` from the scene's origin, pressed in to x = 1.5 cm: x
/// reaches 1.9 N, with [`assert_dof_invariants`] on everything it received.
fn receives_its_axes_only_clamped_as_sent(dof: u8, offset_m: [f64; 3]) {
    let _turn = take_turn();
    let (max_force_n, target_n) = (2.0, 1.9);
    let device = run_for_x_force(
        device_with_dof(dof, max_force_n, 0.015),
        &device_offset(offset_m),
        target_n,
    );
    assert_dof_invariants(&device, dof, max_force_n, target_n);
}

/// A device that breaks SPEC 6.8 and reports garbage in the State components its DOF leaves unused (a constant
/// 2 cm of position and 0.5 m/s of velocity) is rendered as if they were 0: pressed 1 cm into the wall on the
/// ball's equator it renders about 5 N along x (k = 500 N/m) and gets its full 3 N, not the 0.63 N of the upper
/// slope at z = 2 cm (2-DOF), nor nothing at (2, 2, 2) cm outside the ball (1-DOF).
fn garbage_in_unused_state_components_is_ignored(dof: u8) {
    let _turn = take_turn();
    let (max_force_n, target_n) = (3.0, 2.9);
    let config = SpecDeviceConfig {
        unused_components: Some(([0.02; 3], [0.5; 3])),
        ..device_with_dof(dof, max_force_n, INSIDE_X_M)
    };
    let device = run_for_x_force(config, "", target_n);
    assert_dof_invariants(&device, dof, max_force_n, target_n);
}

#[test]
fn a_two_dof_devices_garbage_z_in_state_is_ignored() {
    garbage_in_unused_state_components_is_ignored(2);
}

#[test]
fn a_one_dof_devices_garbage_y_and_z_in_state_are_ignored() {
    garbage_in_unused_state_components_is_ignored(1);
}
