//! The servo-path rule, proved with the counting allocator: the exact solver allocates nothing once its workspace
//! has the scene's size, and volume sampling never allocates.

use crate::util::alloc::count_allocations;
use glam::DVec3;
use voxhap::haptics::{Primitive, Problem, SolveStatus, Solver, SolverConfig};

fn scene(tick: usize, n: usize) -> Vec<Primitive> {
    let t = tick as f64 * 1e-3;
    let mut prims = vec![
        Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap(),
        Primitive::plane(DVec3::ZERO, DVec3::new(0.0175, 0.0, -1.0), 2.0).unwrap(),
    ];
    for i in 0..n.saturating_sub(2) {
        let a = i as f64 + t;
        let p = DVec3::new(0.003 * a.cos(), 0.003 * a.sin(), 0.001 * (2.0 * a).cos());
        prims.push(match i % 3 {
            0 => Primitive::point(p, 0.3).unwrap(),
            1 => Primitive::line(p, DVec3::new(a.sin(), 1.0, 0.2), 0.4).unwrap(),
            _ => Primitive::directed(DVec3::new(1.0, a.cos(), 0.0), 0.1).unwrap(),
        });
    }
    prims
}

/// Warm ticks and, every tenth tick, a cold solve of the same size.
#[test]
fn solving_allocates_nothing_after_warm_up() {
    let n = 40;
    let scenes: Vec<Vec<Primitive>> = (0..200).map(|tick| scene(tick, n)).collect();
    let mut solver = Solver::with_capacity(SolverConfig::default(), n);
    let mut results = Vec::with_capacity(scenes.len());
    let ((), events) = count_allocations(|| {
        let mut proxy = DVec3::ZERO;
        for (tick, prims) in scenes.iter().enumerate() {
            let t = tick as f64 * 1e-3;
            let probe = DVec3::new(
                0.01 * (3.0 * t).sin(),
                0.004 * t,
                -0.002 + 0.003 * (5.0 * t).cos(),
            );
            // Every tenth tick starts cold (no previous dual or proxy): the primal method's cold start and the
            // dual sized afresh must not allocate either.
            let cold = tick % 10 == 0;
            if cold {
                solver.reset();
            }
            let problem = Problem {
                stiffness_n_per_m: 500.0,
                probe_m: probe,
                previous_proxy_m: (!cold).then_some(proxy),
                primitives: prims,
            };
            let sol = solver.solve(&problem).unwrap();
            proxy = sol.proxy_m;
            results.push(sol.status);
        }
    });
    assert_eq!(events, 0, "the solver allocated on the servo path");
    assert_eq!(results.len(), 200);
    assert!(
        results.iter().all(|s| *s == SolveStatus::Certified),
        "{results:?}"
    );
}

/// Volume sampling runs every tick on the servo thread: it must not allocate either.
#[test]
fn volume_sampling_allocates_nothing() {
    use voxhap::volume::{procedural, Grid};
    let density = procedural::sphere(0.03, Grid::centred_cube([48; 3], 0.05).unwrap()).unwrap();
    let flow =
        procedural::rankine_vortex(0.01, 0.05, Grid::centred_cube([32; 3], 0.05).unwrap()).unwrap();
    let mut acc = 0.0;
    let ((), events) = count_allocations(|| {
        for i in 0..2000 {
            let t = i as f64 * 1e-3;
            // Inside, on the edge of and outside the grid, and one non-finite position.
            let p = DVec3::new(
                0.07 * (3.0 * t).sin(),
                0.05 * (2.0 * t).cos(),
                0.04 * (5.0 * t).sin(),
            );
            let (v, g) = density.sample_with_gradient(p);
            acc += v + g.x + density.gradient(p).y + density.sample(p);
            acc +=
                flow.sample(p).z + flow.curl(p).z + flow.divergence(p) + flow.jacobian(p).x_axis.x;
        }
        acc += density.sample(DVec3::NAN) + flow.curl(DVec3::INFINITY).x;
    });
    assert_eq!(events, 0, "volume sampling allocated");
    assert!(acc.is_finite());
}
