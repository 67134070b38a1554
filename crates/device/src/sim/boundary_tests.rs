//! The simulated arm's stability boundary against the exact zero-order-hold analysis ([`super::zoh_exact`],
//! computed from first principles, not from the arm's integrator nor from any cap function). The arm's
//! boundary is found by bisection on runs: the amplitude at the end of a run against its start.

use super::zoh_exact::{exact_boundary, exact_boundary_no_delay};
use super::*;
use glam::DVec3;

/// A released arm (no hand spring, no workspace wall) of mass `m` and damping `b` with these effects: the
/// plant `m x'' + b x' = F` of the analyses (shared with the effects tests).
pub(super) fn released_arm(
    m: f64,
    b: f64,
    substeps: u32,
    effects: DeviceEffects,
    start_m: DVec3,
) -> SimArm {
    let config = SimArmConfig {
        arm: ArmParams {
            mass_kg: m,
            damping_n_s_per_m: b,
            workspace: Workspace::Unbounded,
            substeps_per_tick: substeps,
            wall_stiffness_n_per_m: 0.0,
            wall_damping_n_s_per_m: 0.0,
            effects,
        },
        hand: HandParams {
            stiffness_n_per_m: 1.0,
            damping_n_s_per_m: 0.0,
        },
        path: HandPath::Force {
            profile: ForceProfile::Constant {
                force_n: DVec3::ZERO,
            },
        },
        local_model: None,
    };
    SimArm::new(config, start_m).unwrap()
}

/// Does the released arm under the sampled spring `k` settle? A run of 4000 ticks from 1 mm: the largest
/// excursion in the last 500 ticks against the first 500.
fn arm_is_stable(m: f64, b: f64, rate_hz: f64, substeps: u32, latency_s: f64, k: f64) -> bool {
    let dt = 1.0 / rate_hz;
    let effects = DeviceEffects {
        latency_s,
        ..DeviceEffects::default()
    };
    let mut arm = released_arm(m, b, substeps, effects, DVec3::new(1e-3, 0.0, 0.0));
    let ticks = 4000;
    let (mut first, mut last) = (0.0f64, 0.0f64);
    for n in 0..ticks {
        let x = arm.position_m();
        if n < 500 {
            first = first.max(x.x.abs());
        }
        if n >= ticks - 500 {
            last = last.max(x.x.abs());
        }
        if !x.is_finite() || x.x.abs() > 1e3 {
            return false;
        }
        arm.step(n as f64 * dt, dt, -k * x).unwrap();
    }
    last < first
}

fn arm_boundary(m: f64, b: f64, rate_hz: f64, substeps: u32, latency_s: f64, guess: f64) -> f64 {
    let (mut lo, mut hi) = (guess / 4.0, guess * 4.0);
    assert!(arm_is_stable(m, b, rate_hz, substeps, latency_s, lo));
    assert!(!arm_is_stable(m, b, rate_hz, substeps, latency_s, hi));
    for _ in 0..14 {
        let mid = (lo * hi).sqrt();
        if arm_is_stable(m, b, rate_hz, substeps, latency_s, mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo * hi).sqrt()
}

/// The closed form agrees with the polynomial test (a check of the test's own two analyses), with the
/// 2 003 N/m of the released default arm at 1 kHz, and with an independent root computation for 1 ms latency.
#[test]
fn the_two_exact_analyses_agree() {
    let closed = exact_boundary_no_delay(0.1, 1.0, 1e-3);
    assert!((closed - 2003.3).abs() < 0.5, "{closed}");
    let polynomial = exact_boundary(0.1, 1.0, 1e-3, 0);
    assert!((polynomial / closed - 1.0).abs() < 1e-9, "{polynomial}");
    // One tick of latency: 668.51 N/m (numpy's polynomial roots, bisected, give 668.513).
    let one_tick = exact_boundary(0.1, 1.0, 1e-3, 1);
    assert!((one_tick - 668.513).abs() < 0.01, "{one_tick}");
}

/// The simulated arm's boundary at `rate_hz` with `ticks` ticks of latency and `substeps` physics steps per
/// tick is within 5 % of `exact`.
fn assert_sim_arm_within_5_percent(
    m: f64,
    b: f64,
    rate_hz: f64,
    ticks: usize,
    substeps: u32,
    exact: f64,
) {
    let latency_s = ticks as f64 * (1.0 / rate_hz);
    let sim = arm_boundary(m, b, rate_hz, substeps, latency_s, exact);
    assert!(
        (sim / exact - 1.0).abs() < 0.05,
        "{rate_hz} Hz, {ticks} ticks late, {substeps} substeps: sim {sim:.1} N/m, exact {exact:.1} N/m"
    );
}

#[test]
fn the_sim_arm_boundary_is_within_5_percent_of_the_exact_zoh_boundary_at_every_rate_and_substep() {
    let (m, b) = (0.1, 1.0);
    for rate_hz in [250.0, 1000.0, 4000.0] {
        for substeps in [1, 2, 10, 100] {
            let exact = exact_boundary_no_delay(m, b, 1.0 / rate_hz);
            assert_sim_arm_within_5_percent(m, b, rate_hz, 0, substeps, exact);
        }
    }
}

#[test]
fn with_latency_the_sim_arm_boundary_is_within_5_percent_of_the_exact_analysis() {
    let (m, b) = (0.1, 1.0);
    for (rate_hz, ticks) in [(1000.0, 1), (1000.0, 2), (4000.0, 4)] {
        let t = 1.0 / rate_hz;
        let exact = exact_boundary(m, b, t, ticks);
        for substeps in [1, 10] {
            assert_sim_arm_within_5_percent(m, b, rate_hz, ticks, substeps, exact);
        }
    }
}

/// The physics cap (b / (T/2 + tau)) never exceeds the exact boundary and stays within 5 % of it for the
/// released arm: the caps are safe and not needlessly low.
#[test]
fn the_physics_cap_sits_just_inside_the_exact_boundary() {
    let (m, b) = (0.1, 1.0);
    for rate_hz in [250.0, 1000.0, 4000.0] {
        let t = 1.0 / rate_hz;
        for ticks in [0usize, 1, 2] {
            let physics = crate::physics::DevicePhysics {
                damping_n_s_per_m: b,
                latency_s: ticks as f64 * t,
                position_resolution_m: 0.0,
                coulomb_friction_n: 0.0,
                source: "test",
            };
            let cap = physics.max_stiffness_n_per_m(t);
            let exact = exact_boundary(m, b, t, ticks);
            assert!(
                cap <= exact && cap > 0.95 * exact,
                "{rate_hz} Hz, {ticks} ticks: cap {cap:.1}, exact {exact:.1}"
            );
        }
    }
}

/// A latency that is not a whole number of ticks (the force changes within a tick): the sim arm's boundary
/// is within 5 % of the library's exact figure ([`super::zoh_boundary`], which splits the tick where the
/// force changes), with 1 and 10 substeps.
#[test]
fn with_a_fraction_of_a_tick_of_latency_the_sim_arm_boundary_is_within_5_percent_of_the_exact_analysis(
) {
    let (m, b) = (0.1, 1.0);
    for (rate_hz, latency_s) in [(1000.0, 0.0005), (1000.0, 0.0013), (4000.0, 0.0006)] {
        let exact = super::zoh_boundary(m, b, 1.0 / rate_hz, latency_s).unwrap();
        for substeps in [1, 10] {
            let sim = arm_boundary(m, b, rate_hz, substeps, latency_s, exact);
            assert!(
                (sim / exact - 1.0).abs() < 0.05,
                "{rate_hz} Hz, latency {latency_s} s, {substeps} substeps: sim {sim:.1} N/m, exact {exact:.1} N/m"
            );
        }
    }
}
