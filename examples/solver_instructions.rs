//! Instruction counts and quick timings of the exact solver on the benchmark's cases (benches/solver.rs), for
//! comparing two versions of the solver on a loaded machine, where instruction counts are the steadier measure.
//!
//! - `cargo run --release --example solver_instructions -- path|euler`: 10 rounds of the 2 000-tick exploration
//!   path (the exact solver, warm-started, or the paper's Euler solver).
//! - `... -- cold CASE REPS`: REPS cold solves of one case (`wedge5`, `wedge1`, `random10`, `random100`,
//!   `random1000`, `mixed3000`, `mixed10000`); prints the passes and the bound of one solve.
//! - `... -- seeds N COUNT`: one cold solve of each of COUNT other random scenes of N primitives.
//! - `... -- time`: median nanoseconds per solve of every case (31 samples of about 2 ms each).
//! - `... -- timeseeds N COUNT`: median nanoseconds per cold solve over the COUNT scenes of `seeds`.
//!
//! Instructions per solve: `valgrind --tool=callgrind --toggle-collect='*Solver::solve' target/release/examples/
//! solver_instructions cold random100 100`, divided by REPS (the scene set-up is not collected).
#[path = "../benches/util/timing.rs"]
mod timing;

use voxhap::haptics::baselines::euler;
use voxhap::haptics::bench_scenes::*;
use voxhap::haptics::*;

const K: f64 = 500.0;

fn path_ticks() -> Vec<(glam::DVec3, glam::DVec3, [Primitive; 2])> {
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
                stiffness_n_per_m: K,
                probe_m: probe,
                previous_proxy_m: Some(proxy),
                primitives: &prims,
            })
            .unwrap();
        ticks.push((probe, proxy, prims));
        nf = sol.force_n.z.abs();
        proxy = sol.proxy_m;
    }
    ticks
}

/// The benchmark's cold cases: name, probe, primitives.
fn case(name: &str) -> (glam::DVec3, Vec<Primitive>) {
    let wedge_probe = glam::DVec3::new(-0.0002, 0.002, 0.00001);
    match name {
        "wedge5" => (wedge_probe, thin_wedge(5.0).to_vec()),
        "wedge1" => (wedge_probe, thin_wedge(1.0).to_vec()),
        _ => {
            let n: usize = name
                .trim_start_matches("random")
                .trim_start_matches("mixed")
                .parse()
                .expect("case: wedge5, wedge1, randomN or mixedN");
            random_scene(n as u64, n)
        }
    }
}

const CASES: [&str; 7] = [
    "wedge5",
    "wedge1",
    "random10",
    "random100",
    "random1000",
    "mixed3000",
    "mixed10000",
];

/// Median nanoseconds per call, batches of about 2 ms (the benchmark's timer).
/// A cold problem at the benchmark's coupling stiffness (no previous proxy).
fn cold_problem(probe_m: glam::DVec3, primitives: &[Primitive]) -> Problem<'_> {
    Problem {
        stiffness_n_per_m: K,
        probe_m,
        previous_proxy_m: None,
        primitives,
    }
}

fn median_ns(mut f: impl FnMut()) -> f64 {
    let batch = timing::batch_for(&mut f);
    timing::median_ns(batch, f)
}

/// One exploration-path tick, warm-started from the solver's previous tick.
fn path_tick(solver: &mut Solver, tick: &(glam::DVec3, glam::DVec3, [Primitive; 2])) -> Solution {
    let (probe, previous, primitives) = tick;
    solver
        .solve(&Problem {
            stiffness_n_per_m: K,
            probe_m: *probe,
            previous_proxy_m: Some(*previous),
            primitives,
        })
        .unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which = args.first().map(String::as_str).unwrap_or_default();
    match which {
        "cold" => {
            let (probe, primitives) = case(args.get(1).map(String::as_str).unwrap_or("random10"));
            let reps: usize = args.get(2).map_or(1, |r| r.parse().expect("REPS"));
            let problem = cold_problem(probe, &primitives);
            let mut solver = Solver::with_capacity(SolverConfig::default(), primitives.len());
            let mut last = None;
            for _ in 0..reps {
                solver.reset();
                last = Some(solver.solve(std::hint::black_box(&problem)).unwrap());
            }
            let sol = last.expect("REPS >= 1");
            println!(
                "passes {} (newton {}), rounds {}, bound {:e}, {:?}",
                sol.sweeps, sol.newton_passes, sol.active_set_rounds, sol.error_bound_m, sol.status
            );
        }
        "seeds" => {
            // One cold solve of each of COUNT random scenes of N primitives (seeds 1 to COUNT, not the
            // benchmark's): the passes in total, to judge a change beyond the benchmark's one scene per size.
            let n: usize = args.get(1).map_or(100, |v| v.parse().expect("N"));
            let count: u64 = args.get(2).map_or(20, |v| v.parse().expect("COUNT"));
            let mut solver = Solver::with_capacity(SolverConfig::default(), n);
            let (mut passes, mut uncertified) = (0, 0);
            for seed in 1..=count {
                let (probe, primitives) = random_scene(seed * 1_000_003 + n as u64, n);
                let problem = cold_problem(probe, &primitives);
                solver.reset();
                let sol = solver.solve(&problem).unwrap();
                passes += sol.sweeps;
                uncertified += u32::from(sol.status != SolveStatus::Certified);
            }
            println!("passes {passes} in {count} solves, {uncertified} not certified");
        }
        "timeseeds" => {
            // Median nanoseconds per cold solve over COUNT random scenes of N primitives (the scenes of
            // `seeds`, each solved once per round): a timing beyond the benchmark's one scene per size.
            let n: usize = args.get(1).map_or(10, |v| v.parse().expect("N"));
            let count: u64 = args.get(2).map_or(100, |v| v.parse().expect("COUNT"));
            let scenes: Vec<_> = (1..=count)
                .map(|seed| random_scene(seed * 1_000_003 + n as u64, n))
                .collect();
            let mut solver = Solver::with_capacity(SolverConfig::default(), n);
            let ns = median_ns(|| {
                for (probe, primitives) in &scenes {
                    solver.reset();
                    let problem = cold_problem(*probe, primitives);
                    std::hint::black_box(solver.solve(std::hint::black_box(&problem)).unwrap());
                }
            }) / count as f64;
            println!("{n} primitives, {count} scenes: {ns:.0} ns per solve");
        }
        "time" => {
            let ticks = path_ticks();
            let mut solver = Solver::with_capacity(SolverConfig::default(), 2);
            let path_ns = median_ns(|| {
                for tick in &ticks {
                    std::hint::black_box(path_tick(&mut solver, tick));
                }
            }) / ticks.len() as f64;
            println!("path {path_ns:.0} ns per tick");
            for name in CASES {
                let (probe, primitives) = case(name);
                let problem = cold_problem(probe, &primitives);
                let mut solver = Solver::with_capacity(SolverConfig::default(), primitives.len());
                let ns = median_ns(|| {
                    solver.reset();
                    std::hint::black_box(solver.solve(std::hint::black_box(&problem)).unwrap());
                });
                println!("{name} {ns:.0} ns");
            }
        }
        _ => {
            let ticks = path_ticks();
            let mut acc = glam::DVec3::ZERO;
            let mut solver = Solver::default();
            for _ in 0..10 {
                for tick in &ticks {
                    let (probe, prev, prims) = tick;
                    acc += match which {
                        "path" | "exact" => path_tick(&mut solver, tick).proxy_m,
                        "euler" => {
                            euler::solve(K, *probe, *prev, prims, &euler::EulerConfig::default())
                                .proxy_m
                        }
                        _ => glam::DVec3::ZERO,
                    };
                }
            }
            println!("{acc}");
        }
    }
}
