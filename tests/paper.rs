//! Reproductions of the paper's figures that compare methods (the single-method ones, Figures 4 and 6, are unit
//! tests of the solver in crates/solver/src/tests.rs).

use glam::DVec3;
use voxhap::haptics::baselines::{constraint, euler};
use voxhap::haptics::{Primitive, Problem, Solver};

const K: f64 = 500.0;

/// Figure 2 and eq. 7: two zero-strength constraints that are not orthogonal. Zero strength means they should
/// not hold the proxy at all, so the proxy must reach the probe. The constraint approach adds each constraint's
/// movement and leaves the proxy short of the probe; the primitives do not.
#[test]
fn zero_strength_non_orthogonal_constraints() {
    let angle = 45f64.to_radians();
    let prims = [
        Primitive::plane(DVec3::ZERO, DVec3::X, 0.0).unwrap(),
        Primitive::plane(DVec3::ZERO, DVec3::new(angle.cos(), angle.sin(), 0.0), 0.0).unwrap(),
    ];
    // The probe moves 2 mm along the direction between the two normals' difference (where sum P_i < 1).
    let previous = DVec3::ZERO;
    let direction = (prims[0].direction() - prims[1].direction()).normalize();
    let probe = previous + 0.002 * direction;

    let constrained = constraint::solve(K, probe, previous, &prims);
    let shortfall = (probe - constrained.proxy_m).length();
    // Eq. 7: the movement along d is (1 - cos 45deg) |d| = 0.29 |d|, so the proxy is 1.41 mm short.
    let expected_shortfall = 0.002 * angle.cos();
    assert!(
        (shortfall - expected_shortfall).abs() < 1e-12,
        "shortfall {shortfall}"
    );
    assert!(
        constrained.force_n.length() > 0.7,
        "the user feels {} N from nothing",
        constrained.force_n.length()
    );

    let mut solver = Solver::default();
    let exact = solver
        .solve(&Problem {
            stiffness_n_per_m: K,
            probe_m: probe,
            previous_proxy_m: Some(previous),
            primitives: &prims,
        })
        .unwrap();
    assert!((exact.proxy_m - probe).length() <= exact.error_bound_m);
    assert!(exact.force_n.length() < 1e-9);
}

/// Orthogonal constraints: the constraint approach and the primitives agree (the case the constraint approach
/// was designed for).
#[test]
fn orthogonal_constraints_agree() {
    let prims = [
        Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap(),
        Primitive::line(DVec3::ZERO, DVec3::X, 0.5).unwrap(),
    ];
    // The line constrains y and z (0.5 N), the plane z (2 N). The probe moves along x (free) and y (held by the
    // line alone), so no two constraints act on the same direction and both methods must agree.
    let probe = DVec3::new(0.004, 0.0005, 0.0);
    let constrained = constraint::solve(K, probe, DVec3::ZERO, &prims);
    let mut solver = Solver::default();
    let exact = solver
        .solve(&Problem {
            stiffness_n_per_m: K,
            probe_m: probe,
            previous_proxy_m: None,
            primitives: &prims,
        })
        .unwrap();
    assert!(
        (constrained.proxy_m - exact.proxy_m).length() <= 1e-12,
        "{constrained:?} vs {exact:?}"
    );
}

/// docs/design.md ("Kinks are part of the answer"): the paper's Euler solver stalls at a kink and misplaces the
/// proxy; the exact solver needs one projection. k = 500 N/m, a plane (2 N) and a point (0.5 N) at the previous proxy.
#[test]
fn euler_stalls_where_the_exact_solver_does_not() {
    let prims = [
        Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap(),
        Primitive::point(DVec3::ZERO, 0.5).unwrap(),
    ];
    let probe = DVec3::new(0.003, 0.0, -0.002);
    let mut solver = Solver::default();
    let exact = solver
        .solve(&Problem {
            stiffness_n_per_m: K,
            probe_m: probe,
            previous_proxy_m: Some(DVec3::ZERO),
            primitives: &prims,
        })
        .unwrap();
    // On the plane, held back by the point: x = 3 mm - 0.5/500 = 2 mm.
    assert!((exact.proxy_m - DVec3::new(0.002, 0.0, 0.0)).length() <= exact.error_bound_m);
    let stalled = euler::solve(
        K,
        probe,
        DVec3::ZERO,
        &prims,
        &euler::EulerConfig::default(),
    );
    let euler_error = (stalled.proxy_m - exact.proxy_m).length();
    assert!(euler_error > 1e-4, "Euler error {euler_error}");
    assert!(stalled.iterations >= 30, "{stalled:?}");
}
