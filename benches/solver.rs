//! Solver benchmarks: the exact solver against the paper's adaptive Euler solver, side by side on the same
//! inputs (criterion), followed by a summary table of median times and position errors.
//!
//! Cases: a plane plus friction point along a 1 kHz exploration path (2000 ticks, warm start from the previous
//! tick), thin wedges of 5 and 1 degrees, and 10, 100 and 1000 random primitives (cold start).
//!
//! Errors are measured against a high-precision reference: the exact solver run cold with a 1e-14 m tolerance,
//! whose own certificate proves it (the bound is printed). For the exact solver the table also prints the largest
//! certified bound it reported.
//!
//! Run: `cargo bench --bench solver` (add `-- --quick` for a shorter run).

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use glam::DVec3;
use std::hint::black_box;
use std::time::Instant;
use voxhap::haptics::baselines::euler::{self, EulerConfig};
use voxhap::haptics::bench_scenes::{
    exploration_primitives, exploration_probe, random_primitives, thin_wedge, SplitMix,
};
use voxhap::haptics::{Primitive, Problem, SolveStatus, Solver, SolverConfig};

const K: f64 = 500.0;
const PATH_TICKS: usize = 2000;
const FRICTION_MU: f64 = 0.4;

/// One tick's inputs, identical for both solvers.
struct Tick {
    probe: DVec3,
    previous_proxy: DVec3,
    primitives: Vec<Primitive>,
}

/// The exploration path's inputs, generated once by running the exact solver along it (the friction point is
/// the previous proxy, so the inputs depend on the answers; both solvers then see the same inputs).
fn exploration_path() -> Vec<Tick> {
    let mut solver = Solver::default();
    let mut proxy = exploration_probe(0);
    proxy.z = 0.0;
    let mut normal_force = 0.0;
    let mut ticks = Vec::with_capacity(PATH_TICKS);
    for i in 0..PATH_TICKS {
        let probe = exploration_probe(i);
        let primitives = exploration_primitives(proxy, FRICTION_MU * normal_force).to_vec();
        let sol = solver
            .solve(&Problem {
                stiffness_n_per_m: K,
                probe_m: probe,
                previous_proxy_m: Some(proxy),
                primitives: &primitives,
            })
            .expect("valid problem");
        ticks.push(Tick {
            probe,
            previous_proxy: proxy,
            primitives,
        });
        normal_force = sol.force_n.z.abs();
        proxy = sol.proxy_m;
    }
    ticks
}

fn reference(tick: &Tick) -> (DVec3, f64) {
    let mut solver = Solver::new(SolverConfig {
        tolerance_m: 1e-14,
        ..SolverConfig::default()
    });
    let sol = solver
        .solve(&Problem {
            stiffness_n_per_m: K,
            probe_m: tick.probe,
            previous_proxy_m: None,
            primitives: &tick.primitives,
        })
        .expect("valid problem");
    (sol.proxy_m, sol.error_bound_m)
}

fn exact_path(solver: &mut Solver, ticks: &[Tick]) -> (Vec<DVec3>, f64) {
    let mut worst_bound: f64 = 0.0;
    let answers = ticks
        .iter()
        .map(|t| {
            let sol = solver
                .solve(&Problem {
                    stiffness_n_per_m: K,
                    probe_m: t.probe,
                    previous_proxy_m: Some(t.previous_proxy),
                    primitives: &t.primitives,
                })
                .expect("valid problem");
            worst_bound = worst_bound.max(sol.error_bound_m);
            sol.proxy_m
        })
        .collect();
    (answers, worst_bound)
}

fn euler_path(ticks: &[Tick]) -> Vec<DVec3> {
    ticks
        .iter()
        .map(|t| {
            euler::solve(
                K,
                t.probe,
                t.previous_proxy,
                &t.primitives,
                &EulerConfig::default(),
            )
            .proxy_m
        })
        .collect()
}

/// Median nanoseconds per call of `f` over 51 samples of `batch` calls each.
fn median_ns(batch: usize, mut f: impl FnMut()) -> f64 {
    let mut samples: Vec<f64> = (0..51)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..batch {
                f();
            }
            start.elapsed().as_nanos() as f64 / batch as f64
        })
        .collect();
    samples.sort_by(f64::total_cmp);
    samples[samples.len() / 2]
}

struct Row {
    case: String,
    exact_ns: f64,
    euler_ns: f64,
    exact_error_m: f64,
    exact_bound_m: f64,
    euler_error_m: f64,
    reference_bound_m: f64,
}

fn single_case(
    name: &str,
    probe: DVec3,
    primitives: &[Primitive],
    c: &mut Criterion,
    rows: &mut Vec<Row>,
) {
    let tick = Tick {
        probe,
        previous_proxy: probe,
        primitives: primitives.to_vec(),
    };
    let (reference_proxy, reference_bound) = reference(&tick);
    let problem = Problem {
        stiffness_n_per_m: K,
        probe_m: probe,
        previous_proxy_m: None,
        primitives,
    };
    let mut solver = Solver::with_capacity(SolverConfig::default(), primitives.len());
    let mut group = c.benchmark_group(name);
    group.bench_function("exact", |b| {
        b.iter(|| {
            solver.reset();
            black_box(solver.solve(black_box(&problem)).expect("valid"))
        })
    });
    group.bench_function("euler", |b| {
        b.iter(|| {
            black_box(euler::solve(
                K,
                black_box(probe),
                probe,
                primitives,
                &EulerConfig::default(),
            ))
        })
    });
    group.finish();

    solver.reset();
    let exact = solver.solve(&problem).expect("valid");
    let euler = euler::solve(K, probe, probe, primitives, &EulerConfig::default());
    let batch = if primitives.len() >= 1000 { 3 } else { 200 };
    let exact_ns = median_ns(batch, || {
        solver.reset();
        black_box(solver.solve(black_box(&problem)).expect("valid"));
    });
    let euler_ns = median_ns(batch, || {
        black_box(euler::solve(
            K,
            black_box(probe),
            probe,
            primitives,
            &EulerConfig::default(),
        ));
    });
    assert_ne!(
        exact.status,
        SolveStatus::BudgetExhausted,
        "{name}: {exact:?}"
    );
    rows.push(Row {
        case: name.to_string(),
        exact_ns,
        euler_ns,
        exact_error_m: (exact.proxy_m - reference_proxy).length(),
        exact_bound_m: exact.error_bound_m,
        euler_error_m: (euler.proxy_m - reference_proxy).length(),
        reference_bound_m: reference_bound,
    });
}

fn benches(c: &mut Criterion) {
    let mut rows = Vec::new();

    // The exploration path, warm-started tick to tick.
    let ticks = exploration_path();
    let references: Vec<(DVec3, f64)> = ticks.iter().map(reference).collect();
    let mut group = c.benchmark_group("exploration_path_2000_ticks");
    group.bench_function("exact", |b| {
        b.iter_batched(
            || Solver::with_capacity(SolverConfig::default(), 2),
            |mut solver| black_box(exact_path(&mut solver, &ticks)),
            BatchSize::SmallInput,
        )
    });
    group.bench_function("euler", |b| b.iter(|| black_box(euler_path(&ticks))));
    group.finish();
    let mut solver = Solver::with_capacity(SolverConfig::default(), 2);
    let (exact_answers, exact_bound) = exact_path(&mut solver, &ticks);
    let euler_answers = euler_path(&ticks);
    let max_error = |answers: &[DVec3]| {
        answers
            .iter()
            .zip(&references)
            .map(|(a, (r, _))| (*a - *r).length())
            .fold(0.0, f64::max)
    };
    let exact_ns = median_ns(3, || {
        let mut solver = Solver::with_capacity(SolverConfig::default(), 2);
        black_box(exact_path(&mut solver, &ticks));
    }) / PATH_TICKS as f64;
    let euler_ns = median_ns(3, || {
        black_box(euler_path(&ticks));
    }) / PATH_TICKS as f64;
    rows.push(Row {
        case: "exploration path (per tick, max error)".into(),
        exact_ns,
        euler_ns,
        exact_error_m: max_error(&exact_answers),
        exact_bound_m: exact_bound,
        euler_error_m: max_error(&euler_answers),
        reference_bound_m: references.iter().map(|r| r.1).fold(0.0, f64::max),
    });

    for angle in [5.0, 1.0] {
        single_case(
            &format!("wedge_{angle}_degrees"),
            DVec3::new(-0.0002, 0.002, 0.00001),
            &thin_wedge(angle),
            c,
            &mut rows,
        );
    }
    for n in [10usize, 100, 1000] {
        let mut rng = SplitMix(n as u64);
        let primitives = random_primitives(&mut rng, n);
        let probe = rng.vec(0.02);
        single_case(
            &format!("random_{n}_primitives"),
            probe,
            &primitives,
            c,
            &mut rows,
        );
    }

    println!();
    println!("Summary (median ns per solve, measured side by side in this run; errors in metres against the reference)");
    println!(
        "{:<42} {:>11} {:>11} {:>8} {:>11} {:>11} {:>11} {:>11}",
        "case",
        "exact ns",
        "euler ns",
        "speedup",
        "exact err",
        "exact bound",
        "euler err",
        "ref bound"
    );
    for r in &rows {
        println!(
            "{:<42} {:>11.0} {:>11.0} {:>7.1}x {:>11.2e} {:>11.2e} {:>11.2e} {:>11.2e}",
            r.case,
            r.exact_ns,
            r.euler_ns,
            r.euler_ns / r.exact_ns,
            r.exact_error_m,
            r.exact_bound_m,
            r.euler_error_m,
            r.reference_bound_m
        );
    }
}

fn config() -> Criterion {
    Criterion::default()
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2))
        .sample_size(30)
}

criterion_group! { name = solver; config = config(); targets = benches }
criterion_main!(solver);
