use voxhap::haptics::bench_scenes::*;
use voxhap::haptics::*;
fn main() {
    let n: usize = std::env::args().nth(1).unwrap().parse().unwrap();
    let mut rng = SplitMix(n as u64);
    let prims = random_primitives(&mut rng, n);
    let probe = rng.vec(0.02);
    let mut solver = Solver::with_capacity(SolverConfig::default(), n);
    let sol = solver
        .solve(&Problem {
            stiffness_n_per_m: 500.0,
            probe_m: probe,
            previous_proxy_m: None,
            primitives: &prims,
        })
        .unwrap();
    println!(
        "n={n} sweeps={} rounds={} bound={:e} status={:?}",
        sol.sweeps, sol.active_set_rounds, sol.error_bound_m, sol.status
    );
}
