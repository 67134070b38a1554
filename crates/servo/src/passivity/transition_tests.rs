use super::*;

/// Moves the probe from `from_z` to `to_z` in small steps with the proxy at `proxy_z` (a plane at the proxy's
/// height when the probe is below it, the probe itself above), returning the work the spring did on the probe
/// (J): the energy it gave back to the hand.
fn leave(transition: &mut CouplingTransition, k: f64, proxy_z: f64, from_z: f64, to_z: f64) -> f64 {
    let steps = 20_000;
    let mut work = 0.0;
    let mut z = from_z;
    for i in 1..=steps {
        let probe = DVec3::new(0.0, 0.0, z);
        let proxy = DVec3::new(0.0, 0.0, proxy_z.max(z));
        let anchor = transition
            .anchor(probe, proxy, 1e-3)
            .map_or(proxy, |(a, _)| a);
        let force = k * (anchor - probe);
        let next = from_z + (to_z - from_z) * i as f64 / steps as f64;
        work += force.z * (next - z);
        z = next;
    }
    work
}

/// A stiffness raised from k0 to k1 with the spring pressed by s0 keeps the force, and gives back on leaving
/// `k0^2 s0^2 / (2 k1)`, less than the `k0 s0^2 / 2` it held; applied at once it would give back `k1 s0^2 / 2`.
#[test]
fn a_stiffer_spring_in_contact_gives_back_no_more_than_the_old_one_held() {
    let (k0, k1, s0) = (500.0, 4000.0, 0.002);
    let probe = DVec3::new(0.0, 0.0, -s0);
    let mut transition = CouplingTransition::new();
    transition.begin(probe, DVec3::ZERO, k0, DVec3::ZERO, k1);
    assert!(transition.active());
    let (anchor, velocity) = transition.anchor(probe, DVec3::ZERO, 1e-3).unwrap();
    assert!(
        (k1 * (anchor - probe).z - k0 * s0).abs() < 1e-12,
        "force kept: {anchor}"
    );
    assert_eq!(velocity, DVec3::ZERO);
    let given_back = leave(&mut transition, k1, 0.0, -s0, 0.001);
    let expected = k0 * k0 * s0 * s0 / (2.0 * k1);
    assert!(
        (given_back - expected).abs() < 1e-3 * expected,
        "{given_back} vs {expected}"
    );
    assert!(!transition.active());
    // Applied at once (the check can fail): the new spring gives back k1 s0^2 / 2.
    let at_once = leave(&mut CouplingTransition::new(), k1, 0.0, -s0, 0.001);
    assert!((at_once - 0.5 * k1 * s0 * s0).abs() < 1e-3 * at_once);
}

/// A plane that appears above a probe 3 mm below it: the force starts at zero and stays zero as the probe
/// leaves straight out (the anchor follows it), so nothing is given back but, on the step where the transition
/// ends, at most the zero-order hold's excess of one step `k dz^2` (here `dz` = 5 mm / 20 000).
#[test]
fn a_plane_appearing_above_the_probe_pushes_nothing_out() {
    let (k, depth) = (1000.0, 0.003);
    let probe = DVec3::new(0.0, 0.0, -depth);
    let mut transition = CouplingTransition::new();
    transition.begin(probe, probe, k, DVec3::ZERO, k);
    assert!(transition.active());
    let given_back = leave(&mut transition, k, 0.0, -depth, 0.002);
    let dz = 0.005 / 20_000.0;
    assert!(given_back.abs() <= 2.0 * k * dz * dz, "{given_back}");
    assert!(!transition.active());
    let at_once = leave(&mut CouplingTransition::new(), k, 0.0, -depth, 0.002);
    assert!((at_once - 0.5 * k * depth * depth).abs() < 1e-3 * at_once);
}

/// A softer spring, or a mode switched off, holds less energy: applied at once.
#[test]
fn changes_that_lower_the_energy_apply_at_once() {
    let probe = DVec3::new(0.0, 0.0, -0.002);
    let mut transition = CouplingTransition::new();
    transition.begin(probe, DVec3::ZERO, 4000.0, DVec3::ZERO, 500.0);
    assert!(!transition.active());
    transition.begin(probe, DVec3::ZERO, 1000.0, probe, 1000.0);
    assert!(!transition.active());
    assert_eq!(transition.introduced(), 0);
}
