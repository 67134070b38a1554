//! Instruction-count comparison helper: `valgrind --tool=callgrind` on `cargo run --release --example diag -- exact|euler`.
use voxhap::haptics::baselines::euler;
use voxhap::haptics::bench_scenes::*;
use voxhap::haptics::*;
fn main() {
    let which = std::env::args().nth(1).unwrap_or_default();
    let mut solver = Solver::default();
    let mut proxy = exploration_probe(0);
    proxy.z = 0.0;
    let mut nf = 0.0;
    let mut ticks = Vec::new();
    for i in 0..2000 {
        let probe = exploration_probe(i);
        let prims = exploration_primitives(proxy, 0.4 * nf);
        let sol = solver
            .solve(&Problem {
                stiffness_n_per_m: 500.0,
                probe_m: probe,
                previous_proxy_m: Some(proxy),
                primitives: &prims,
            })
            .unwrap();
        ticks.push((probe, proxy, prims));
        nf = sol.force_n.z.abs();
        proxy = sol.proxy_m;
    }
    let mut acc = glam::DVec3::ZERO;
    let mut solver = Solver::default();
    for _ in 0..10 {
        for (probe, prev, prims) in &ticks {
            acc += match which.as_str() {
                "exact" => {
                    solver
                        .solve(&Problem {
                            stiffness_n_per_m: 500.0,
                            probe_m: *probe,
                            previous_proxy_m: Some(*prev),
                            primitives: prims,
                        })
                        .unwrap()
                        .proxy_m
                }
                "euler" => {
                    euler::solve(500.0, *probe, *prev, prims, &euler::EulerConfig::default())
                        .proxy_m
                }
                _ => glam::DVec3::ZERO,
            };
        }
    }
    println!("{acc}");
}
