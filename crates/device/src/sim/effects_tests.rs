//! Tests of the device effects through the arm (`effects`): each checked against Newton on a free mass
//! (`x = x0 + v0 t + F t^2 / (2 m)`), so the expected values come from the equations, not the integrator.

use super::*;
use crate::sim::{ArmParams, SimArm};

const DT_S: f64 = 1e-3;
const MASS_KG: f64 = 0.2;

/// A free mass (no damping, no hand, unbounded) with these effects.
fn free_arm(effects: DeviceEffects, start_m: DVec3) -> SimArm {
    crate::sim::boundary_tests::released_arm(MASS_KG, 0.0, 3, effects, start_m)
}

#[test]
fn reported_positions_are_rounded_to_the_resolution_and_the_truth_is_kept() {
    let start = DVec3::new(0.012_345_67, -0.000_051, 0.0);
    let arm = free_arm(
        DeviceEffects {
            position_resolution_m: 1e-4,
            ..DeviceEffects::default()
        },
        start,
    );
    let reported = arm.position_m();
    assert!(
        (reported - DVec3::new(0.0123, -0.0001, 0.0)).length() < 1e-15,
        "{reported}"
    );
    assert_eq!(arm.true_position_m(), start);
}

#[test]
fn a_force_acts_only_after_the_latency() {
    let mut arm = free_arm(
        DeviceEffects {
            latency_s: 2e-3,
            ..DeviceEffects::default()
        },
        DVec3::ZERO,
    );
    let f = DVec3::new(0.5, 0.0, 0.0);
    arm.step(0.0, DT_S, f).unwrap();
    arm.step(DT_S, DT_S, DVec3::ZERO).unwrap();
    assert_eq!(arm.true_position_m(), DVec3::ZERO, "nothing acts for 2 ms");
    arm.step(2.0 * DT_S, DT_S, DVec3::ZERO).unwrap();
    // The 0.5 N sent at t = 0 acts over [2 ms, 3 ms): x = F T^2 / (2 m).
    let expected = 0.5 * DT_S * DT_S / (2.0 * MASS_KG);
    assert!((arm.true_position_m().x - expected).abs() < 1e-18);
}

#[test]
fn applied_forces_are_rounded_to_the_force_resolution() {
    let mut arm = free_arm(
        DeviceEffects {
            force_resolution_n: 0.01,
            ..DeviceEffects::default()
        },
        DVec3::ZERO,
    );
    arm.step(0.0, DT_S, DVec3::new(0.0149, 0.0151, 0.004))
        .unwrap();
    let expected = DVec3::new(0.01, 0.02, 0.0) * (DT_S * DT_S / (2.0 * MASS_KG));
    assert!((arm.true_position_m() - expected).length() < 1e-18);
}

#[test]
fn the_velocity_estimate_is_the_difference_of_reported_positions_over_the_window() {
    let mut arm = free_arm(
        DeviceEffects {
            position_resolution_m: 1e-5,
            velocity_window_ticks: 5,
            ..DeviceEffects::default()
        },
        DVec3::ZERO,
    );
    // One tick of 1 N, then coasting: v = F T / m = 5 mm/s.
    arm.step(0.0, DT_S, DVec3::X).unwrap();
    for n in 1..20 {
        arm.step(n as f64 * DT_S, DT_S, DVec3::ZERO).unwrap();
    }
    let v_true = DT_S / MASS_KG;
    let estimate = arm.velocity_m_per_s().x;
    // Within one resolution step over the window, and not the exact velocity (it is quantised).
    assert!(
        (estimate - v_true).abs() <= 1e-5 / (5.0 * DT_S) + 1e-12,
        "{estimate}"
    );
    assert!((arm.true_velocity_m_per_s().x - v_true).abs() < 1e-15);
}

#[test]
fn jittered_samples_stay_within_the_jitter_and_a_large_jitter_is_refused() {
    let jitter = 1e-4;
    let mut arm = free_arm(
        DeviceEffects {
            period_jitter_s: jitter,
            jitter_seed: 7,
            ..DeviceEffects::default()
        },
        DVec3::ZERO,
    );
    // Start the motion with one tick of force, then coast at constant speed v: each tick's length
    // T + j_{n+1} - j_n is read back from the distance covered.
    arm.step(0.0, DT_S, DVec3::new(MASS_KG / DT_S, 0.0, 0.0))
        .unwrap();
    let v = arm.true_velocity_m_per_s().x;
    let mut offsets = Vec::new();
    let mut previous = arm.true_position_m().x;
    for n in 1..200 {
        arm.step(n as f64 * DT_S, DT_S, DVec3::ZERO).unwrap();
        let x = arm.true_position_m().x;
        offsets.push((x - previous) / v - DT_S);
        previous = x;
    }
    assert!(offsets.iter().all(|d| d.abs() <= 2.0 * jitter + 1e-12));
    assert!(
        offsets.iter().any(|d| d.abs() > 1e-6),
        "the period does vary"
    );
    let mut bad = free_arm(
        DeviceEffects {
            period_jitter_s: 5e-4,
            ..DeviceEffects::default()
        },
        DVec3::ZERO,
    );
    let error = bad.step(0.0, DT_S, DVec3::ZERO).unwrap_err().to_string();
    assert!(error.contains("arm.period_jitter_s"), "{error}");
}

#[test]
fn a_preset_fills_only_its_sourced_figures_and_names_what_it_lacks() {
    // WoodenHaptics' figures from its chai3d extension's parts (preset.rs shows the calculation): mB (0.051 /
    // 0.205)^2 + mC = 0.1205 kg, and 0.205 m x 2 pi / (2000 x 12) = 0.0537 mm.
    let wooden: ArmParams = toml::from_str(
        "preset = \"woodenhaptics\"\ndamping_n_s_per_m = 0.5\nworkspace = { shape = \"unbounded\" }",
    )
    .unwrap();
    let mass = 0.170 * (0.051f64 / 0.205).powi(2) + 0.110;
    assert!((wooden.mass_kg - mass).abs() < 5e-4, "{}", wooden.mass_kg);
    let resolution = 0.205 * std::f64::consts::TAU / (2000.0 * 12.0);
    assert!((wooden.effects.position_resolution_m - resolution).abs() < 1e-7);
    let written: ArmParams = toml::from_str(
        "preset = \"woodenhaptics\"\nmass_kg = 0.3\ndamping_n_s_per_m = 0.5\nworkspace = { shape = \"unbounded\" }",
    )
    .unwrap();
    assert_eq!(written.mass_kg, 0.3, "a written key wins");
    let error = toml::from_str::<ArmParams>(
        "preset = \"falcon\"\ndamping_n_s_per_m = 0.5\nworkspace = { shape = \"unbounded\" }",
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("missing field `mass_kg`") && error.contains("no sourced figure"),
        "{error}"
    );
}
