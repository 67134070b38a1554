//! Unit tests of `arm`.

use super::*;
use crate::sim::DeviceEffects;

const DT_S: f64 = 1e-3;

fn config(path: HandPath, workspace: Workspace) -> SimArmConfig {
    SimArmConfig {
        arm: ArmParams {
            mass_kg: 0.1,
            damping_n_s_per_m: 1.0,
            workspace,
            substeps_per_tick: 10,
            wall_stiffness_n_per_m: 5000.0,
            wall_damping_n_s_per_m: 10.0,
            effects: DeviceEffects::default(),
        },
        hand: HandParams {
            stiffness_n_per_m: 400.0,
            damping_n_s_per_m: 8.0,
        },
        path,
        local_model: None,
    }
}

fn big_box() -> Workspace {
    Workspace::Box {
        min_m: DVec3::splat(-1.0),
        max_m: DVec3::splat(1.0),
    }
}

/// Runs `ticks` ticks at 1 kHz with a rendered force given per tick; returns the final arm.
fn run(
    mut arm: SimArm,
    ticks: u64,
    mut force: impl FnMut(u64, &SimArm) -> DVec3,
) -> (SimArm, bool) {
    let mut limit_hit = false;
    for tick in 0..ticks {
        let f = force(tick, &arm);
        let outcome = arm.step(tick as f64 * DT_S, DT_S, f).expect("valid step");
        limit_hit |= outcome.workspace_limit_hit;
    }
    (arm, limit_hit)
}

#[test]
fn hand_follows_a_line_with_the_documented_steady_state_lag() {
    let from = DVec3::new(-0.05, 0.0, 0.0);
    let to = DVec3::new(0.05, 0.02, 0.0);
    let path = HandPath::Line {
        from_m: from,
        to_m: to,
        duration_s: 2.0,
    };
    let cfg = config(path.clone(), big_box());
    let arm = SimArm::new(cfg.clone(), from).unwrap();
    // At t = 1 s (after 1000 ticks), transients (time constant 2 m / b = 22 ms) are gone.
    let (arm, _) = run(arm, 1000, |_, _| DVec3::ZERO);
    let velocity = (to - from) / 2.0;
    let expected_lag = cfg.arm.damping_n_s_per_m * velocity / cfg.hand.stiffness_n_per_m;
    let target = path.target_at(1.0).unwrap();
    let error = target - arm.position_m();
    assert!(
        (error - expected_lag).length() < 1e-9,
        "lag {error} expected {expected_lag}"
    );
    assert!((arm.velocity_m_per_s() - velocity).length() < 1e-9);
}

/// Scale 2, a quarter turn about z, a translation: the path and the start point are scene positions.
fn scene_mapping() -> WorkspaceMapping {
    WorkspaceMapping::new(
        crate::mapping::rotation_from_degrees([0.0, 0.0, 90.0]),
        2.0,
        DVec3::new(0.1, -0.05, 0.02),
    )
    .unwrap()
}

#[test]
fn a_path_in_the_scene_frame_is_followed_through_the_mapping() {
    let mapping = scene_mapping();
    let (from, to) = (DVec3::new(0.0, 0.0, 0.02), DVec3::new(0.2, 0.04, 0.02));
    let path = HandPath::Line {
        from_m: from,
        to_m: to,
        duration_s: 2.0,
    };
    let cfg = config(path.clone(), big_box());
    let mut arm = SimArm::new(cfg.clone(), from).unwrap();
    arm.use_scene_frame(mapping, from).unwrap();
    assert!((arm.position_m() - mapping.to_device_position_m(from)).length() < 1e-15);
    // The documented steady-state lag, in the device frame: the device target moves at Rᵀ V / s.
    let (arm, _) = run(arm, 1000, |_, _| DVec3::ZERO);
    let device_velocity = mapping.to_device_velocity_m_per_s((to - from) / 2.0);
    let expected_lag = cfg.arm.damping_n_s_per_m * device_velocity / cfg.hand.stiffness_n_per_m;
    let device_target = mapping.to_device_position_m(path.target_at(1.0).unwrap());
    let error = device_target - arm.position_m();
    assert!(
        (error - expected_lag).length() < 1e-9,
        "lag {error} expected {expected_lag}"
    );
    // Seen from the scene, the arm ends where the scene path ends.
    let (arm, _) = run(arm, 3000, |_, _| DVec3::ZERO);
    let end = mapping.to_scene_position_m(arm.position_m());
    assert!((end - to).length() < 1e-6, "{end}");
}

#[test]
fn a_scripted_force_in_the_scene_frame_is_rotated_back_not_scaled() {
    let mapping = scene_mapping();
    let force = DVec3::new(0.0, 0.1, 0.0);
    let path = HandPath::Force {
        profile: super::super::ForceProfile::Constant { force_n: force },
    };
    let cfg = config(path, big_box());
    let mut arm = SimArm::new(cfg.clone(), DVec3::ZERO).unwrap();
    arm.use_scene_frame(mapping, mapping.translation_m())
        .unwrap();
    assert_eq!(arm.position_m(), DVec3::ZERO);
    // Terminal velocity F / b (time constant m / b = 0.1 s), F = Rᵀ f: the scene's +y is the device's +x.
    let (arm, _) = run(arm, 1500, |_, _| DVec3::ZERO);
    let expected = DVec3::new(0.1, 0.0, 0.0) / cfg.arm.damping_n_s_per_m;
    assert!(
        (arm.velocity_m_per_s() - expected).length() < 1e-5,
        "{}",
        arm.velocity_m_per_s()
    );
    // A start point beyond f64's range in the device frame is refused, and nothing changes.
    let mut tiny = SimArm::new(cfg, DVec3::ZERO).unwrap();
    let shrink = WorkspaceMapping::new(glam::DMat3::IDENTITY, 1e-6, DVec3::ZERO).unwrap();
    assert!(tiny.use_scene_frame(shrink, DVec3::splat(1e303)).is_err());
    assert_eq!(tiny.position_m(), DVec3::ZERO);
    assert!(tiny.path_mapping.is_none());
}

#[test]
fn constant_rendered_force_balances_the_hand_spring_at_f_over_k() {
    let hold = DVec3::new(0.01, -0.02, 0.03);
    let cfg = config(HandPath::Hold { at_m: hold }, big_box());
    let arm = SimArm::new(cfg.clone(), hold).unwrap();
    let force = DVec3::new(0.5, -1.0, 2.0);
    let (arm, _) = run(arm, 2000, |_, _| force);
    let expected = hold + force / cfg.hand.stiffness_n_per_m;
    assert!(
        (arm.position_m() - expected).length() < 1e-12,
        "{} vs {expected}",
        arm.position_m()
    );
}

#[test]
fn workspace_box_limit_holds_within_force_over_wall_stiffness() {
    let workspace = Workspace::Box {
        min_m: DVec3::splat(-0.05),
        max_m: DVec3::splat(0.05),
    };
    // The hand tries to drag the arm 0.1 m past the +x face.
    let target = DVec3::new(0.15, 0.0, 0.0);
    let cfg = config(HandPath::Hold { at_m: target }, workspace);
    let arm = SimArm::new(cfg.clone(), DVec3::ZERO).unwrap();
    let mut deepest_m: f64 = 0.0;
    let (arm, limit_hit) = run(arm, 3000, |_, arm| {
        let x = arm.position_m();
        deepest_m = deepest_m.max((x - workspace.closest_point_m(x)).length());
        DVec3::ZERO
    });
    assert!(limit_hit);
    // Dynamic bound: the energy E = m v^2/2 + k_h |x - target|^2/2 + k_w d^2/2 only decreases (the
    // target is fixed and every damper dissipates), so k_w d^2/2 <= E(0) = k_h 0.15^2/2.
    let k_h = cfg.hand.stiffness_n_per_m;
    let k_w = cfg.arm.wall_stiffness_n_per_m;
    let energy_bound_m = (k_h * 0.15 * 0.15 / k_w).sqrt();
    assert!(
        deepest_m <= energy_bound_m,
        "{deepest_m} > {energy_bound_m}"
    );
    // At rest: k_h (0.15 - x) = k_w (x - 0.05), a penetration of F / k_w.
    let rest_x = (k_h * 0.15 + k_w * 0.05) / (k_h + k_w);
    assert!((arm.position_m().x - rest_x).abs() < 1e-9);
}

#[test]
fn workspace_sphere_limit_holds() {
    let workspace = Workspace::Sphere {
        center_m: DVec3::ZERO,
        radius_m: 0.05,
    };
    let path = HandPath::Circle {
        center_m: DVec3::ZERO,
        radius_m: 0.08,
        normal: DVec3::new(0.3, 0.1, 1.0),
        period_s: 1.0,
    };
    let cfg = config(path, workspace);
    let arm = SimArm::new(cfg.clone(), DVec3::ZERO).unwrap();
    let tolerance_m = cfg.hand.stiffness_n_per_m * 0.2 / cfg.arm.wall_stiffness_n_per_m;
    let (arm, limit_hit) = run(arm, 3000, |_, arm| {
        assert!(arm
            .config()
            .arm
            .workspace
            .contains_m(arm.position_m(), tolerance_m));
        DVec3::ZERO
    });
    assert!(limit_hit);
    assert!(arm.position_m().length() > 0.05);
}

#[test]
fn identical_runs_give_identical_bits() {
    let path = HandPath::Raster {
        origin_m: DVec3::new(-0.03, -0.03, 0.0),
        sweep_m: DVec3::new(0.06, 0.0, 0.0),
        step_m: DVec3::new(0.0, 0.06, 0.0),
        lines: 4,
        speed_m_per_s: 0.05,
    };
    let trajectory = || {
        let mut arm = SimArm::new(config(path.clone(), big_box()), DVec3::ZERO).unwrap();
        let mut bits = Vec::new();
        for tick in 0..2000u64 {
            let t = tick as f64 * DT_S;
            let push = DVec3::new(0.0, 0.0, -(arm.position_m().z.min(0.0)) * 800.0);
            arm.step(t, DT_S, push).unwrap();
            let p = arm.position_m();
            bits.extend([p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]);
        }
        bits
    };
    assert_eq!(trajectory(), trajectory());
}

#[test]
fn non_finite_force_is_treated_as_zero_and_counted() {
    let cfg = config(HandPath::Hold { at_m: DVec3::ZERO }, big_box());
    let mut arm = SimArm::new(cfg.clone(), DVec3::ZERO).unwrap();
    let mut twin = SimArm::new(cfg, DVec3::ZERO).unwrap();
    let outcome = arm.step(0.0, DT_S, DVec3::new(f64::NAN, 0.0, 1.0)).unwrap();
    twin.step(0.0, DT_S, DVec3::ZERO).unwrap();
    assert!(outcome.force_rejected);
    arm.step(DT_S, DT_S, DVec3::new(0.0, f64::INFINITY, 0.0))
        .unwrap();
    twin.step(DT_S, DT_S, DVec3::ZERO).unwrap();
    assert_eq!(arm.rejected_force_count(), 2);
    assert_eq!(arm.position_m(), twin.position_m());
    assert!(arm.position_m().is_finite());
}

#[test]
fn force_profile_drives_the_arm_against_its_damping() {
    let profile = super::super::ForceProfile::Constant {
        force_n: DVec3::new(0.2, 0.0, 0.0),
    };
    let cfg = config(HandPath::Force { profile }, Workspace::Unbounded);
    let arm = SimArm::new(cfg.clone(), DVec3::ZERO).unwrap();
    let (arm, _) = run(arm, 2000, |_, _| DVec3::ZERO);
    // Terminal velocity F / b_arm.
    let expected = 0.2 / cfg.arm.damping_n_s_per_m;
    assert!((arm.velocity_m_per_s().x - expected).abs() < 1e-9);
}

#[test]
fn bad_parameters_and_steps_are_rejected_with_their_names() {
    let mut cfg = config(HandPath::Hold { at_m: DVec3::ZERO }, big_box());
    cfg.arm.mass_kg = -1.0;
    let message = SimArm::new(cfg.clone(), DVec3::ZERO)
        .unwrap_err()
        .to_string();
    assert!(message.contains("arm.mass_kg"), "{message}");
    cfg.arm.mass_kg = 0.1;
    cfg.arm.workspace = Workspace::Box {
        min_m: DVec3::ONE,
        max_m: DVec3::ZERO,
    };
    assert_eq!(
        SimArm::new(cfg.clone(), DVec3::ZERO).unwrap_err(),
        SimError::InvertedBox
    );
    cfg.arm.workspace = big_box();
    assert!(SimArm::new(cfg.clone(), DVec3::splat(f64::NAN)).is_err());
    let mut arm = SimArm::new(cfg, DVec3::ZERO).unwrap();
    assert!(matches!(
        arm.step(0.0, 0.0, DVec3::ZERO),
        Err(SimError::InvalidTime { .. })
    ));
    assert!(matches!(
        arm.step(f64::NAN, DT_S, DVec3::ZERO),
        Err(SimError::InvalidTime { .. })
    ));
    // A 1 s tick with 10 substeps is far beyond the stable limit.
    assert!(matches!(
        arm.step(0.0, 1.0, DVec3::ZERO),
        Err(SimError::SubstepTooLong { .. })
    ));
}

#[test]
fn config_parses_from_toml_with_defaults() {
    let text = r#"
        [arm]
        mass_kg = 0.15
        damping_n_s_per_m = 0.5
        workspace = { shape = "box", min_m = [-0.1, -0.1, -0.1], max_m = [0.1, 0.1, 0.1] }

        [hand]
        stiffness_n_per_m = 300.0
        damping_n_s_per_m = 5.0

        [path]
        kind = "waypoints"
        points_m = [[0.0, 0.0, 0.0], [0.02, 0.0, -0.01]]
        speed_m_per_s = 0.02
    "#;
    let cfg: SimArmConfig = toml::from_str(text).expect("parses");
    assert_eq!(cfg.arm.substeps_per_tick, 10);
    assert_eq!(cfg.arm.wall_stiffness_n_per_m, 5000.0);
    assert!(SimArm::new(cfg, DVec3::ZERO).is_ok());
}

proptest::proptest! {
    /// Any finite force sequence keeps the state finite (the stable-substep check holds).
    #[test]
    fn state_stays_finite_under_bounded_forces(
        forces in proptest::collection::vec(
            (-50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0), 1..300)
    ) {
        let workspace = Workspace::Sphere { center_m: DVec3::ZERO, radius_m: 0.05 };
        let mut arm = SimArm::new(config(HandPath::Hold { at_m: DVec3::ZERO }, workspace), DVec3::ZERO)
            .unwrap();
        for (tick, (x, y, z)) in forces.into_iter().enumerate() {
            arm.step(tick as f64 * DT_S, DT_S, DVec3::new(x, y, z)).unwrap();
            proptest::prop_assert!(arm.position_m().is_finite());
            // 50 N * sqrt(3) against the wall: well inside a 0.05 m tolerance.
            proptest::prop_assert!(workspace.contains_m(arm.position_m(), 0.05));
        }
    }
}
