//! Property tests: the exact solver against the slow, independent reference minimiser on random scenes, and
//! the certificate against the true error.

use glam::DVec3;
use proptest::prelude::*;
use voxhap::haptics::primitive::total_energy_j;
use voxhap::haptics::reference;
use voxhap::haptics::{Primitive, Problem, SolveStatus, Solver};

/// Coordinates drawn partly from a small lattice so that coincident primitives, probes exactly on kinks and
/// parallel planes come up often, and partly at random.
fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => (-2i32..=2).prop_map(|i| i as f64 * 0.002),
        3 => -0.01f64..0.01,
    ]
}

fn vector() -> impl Strategy<Value = DVec3> {
    (coordinate(), coordinate(), coordinate()).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

fn direction() -> impl Strategy<Value = DVec3> {
    prop_oneof![
        Just(DVec3::Z),
        Just(DVec3::X),
        Just(DVec3::new(0.0175, 0.0, 1.0)),
        (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0).prop_map(|(x, y, z)| DVec3::new(x, y, z + 0.05)),
    ]
}

fn strength() -> impl Strategy<Value = f64> {
    prop_oneof![1 => Just(0.0), 4 => 0.0f64..3.0]
}

fn primitive() -> impl Strategy<Value = Primitive> {
    (0u8..4, vector(), direction(), strength()).prop_map(|(kind, position, direction, strength)| {
        match kind {
            0 => Primitive::point(position, strength).unwrap(),
            1 => Primitive::line(position, direction, strength).unwrap(),
            2 => Primitive::plane(position, direction, strength).unwrap(),
            _ => Primitive::directed(direction, strength * 0.3).unwrap(),
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn exact_solver_matches_the_reference_and_its_certificate_holds(
        prims in prop::collection::vec(primitive(), 0..9),
        probe in vector(),
        k in prop_oneof![Just(500.0), 50.0f64..3000.0],
    ) {
        let mut solver = Solver::default();
        let problem = Problem { stiffness_n_per_m: k, probe_m: probe, previous_proxy_m: None, primitives: &prims };
        let sol = solver.solve(&problem).unwrap();
        prop_assert_eq!(sol.status, SolveStatus::Certified, "{:?}", sol);
        prop_assert!(sol.error_bound_m <= 1e-12);
        let reference = reference::minimise(k, probe, &prims);
        let error = (sol.proxy_m - reference.proxy_m).length();
        // The certificate must bound the distance to the true minimiser, which lies within the reference's own
        // bound of the reference answer.
        prop_assert!(
            error <= sol.error_bound_m + reference.error_bound_m,
            "error {:e} > bound {:e} + reference bound {:e}", error, sol.error_bound_m, reference.error_bound_m
        );
        // And no point the reference found has lower energy.
        let e_exact = total_energy_j(k, probe, &prims, sol.proxy_m);
        let e_reference = total_energy_j(k, probe, &prims, reference.proxy_m);
        prop_assert!(e_exact <= e_reference + 1e-15, "{} > {}", e_exact, e_reference);
        // The force sent to the device is the coupling at the proxy.
        prop_assert!((sol.force_n - k * (sol.proxy_m - probe)).length() <= 1e-12 * (1.0 + sol.force_n.length()));
    }

    /// Warm-starting from any previous proxy gives the same answer.
    #[test]
    fn warm_start_does_not_change_the_answer(
        prims in prop::collection::vec(primitive(), 1..7),
        probe in vector(),
        previous in vector(),
    ) {
        let mut cold = Solver::default();
        let mut warm = Solver::default();
        let a = cold.solve(&Problem { stiffness_n_per_m: 500.0, probe_m: probe, previous_proxy_m: None, primitives: &prims }).unwrap();
        let b = warm.solve(&Problem { stiffness_n_per_m: 500.0, probe_m: probe, previous_proxy_m: Some(previous), primitives: &prims }).unwrap();
        prop_assert!((a.proxy_m - b.proxy_m).length() <= a.error_bound_m + b.error_bound_m);
    }
}
