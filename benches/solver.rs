//! Solver benchmarks: the exact solver against the paper's adaptive Euler solver, side by side on the same
//! inputs in one run, printed as the Markdown table that docs/solver.md quotes (with the machine and the date).
//!
//! Cases: a plane plus friction point along a 1 kHz exploration path (2000 ticks, warm start from the previous
//! tick), thin wedges of 5 and 1 degrees, 10, 100 and 1000 random primitives and 3 000 and 10 000 mixed
//! primitives (cold start; all four kinds, seeded, crates/solver/src/bench_scenes.rs).
//!
//! Columns: the exact solver with its defaults (certified to 1e-12 m); Euler with its defaults (the paper's stop,
//! `|f_res| <= 1e-3 N` or 100 iterations); and Euler asked for the exact solver's accuracy (`|f_res| <= k 1e-12 m`,
//! up to 10^5 iterations), which it reaches only where nothing sits on a kink. Errors are true errors against the
//! double-double reference minimiser (crates/solver/src/reference.rs), whose own bound is printed.
//!
//! Run: `cargo bench --bench solver` (about 16 s on a 2-vCPU EPYC VM once built, most of it the dual method on
//! the 10 000-primitive case). Times are medians of repeated solves measured in
//! this process, one case after the other, so the ratios are side by side.
//!
//! It prints two tables: the summary (the exact solver against Euler at both stops, with the speed goal for the
//! case and whether this run met it, decided here from the measured median) and the full table. With
//! `VOXHAP_BENCH_DOCS=1` it also writes them into README.md (the summary) and docs/solver.md (both), between
//! the `<!-- solver-bench:... -->` markers, so the tables in the docs are the bench's output, never typed.
//! tests/docs_reference.rs checks the blocks: present, one run in both files, every speed-up and "met" agreeing
//! with its row.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::haptics::baselines::euler::{self, EulerConfig};
use voxhap::haptics::bench_scenes::{
    exploration_primitives, exploration_probe, random_scene, thin_wedge,
};
use voxhap::haptics::reference;
use voxhap::haptics::{Primitive, Problem, Solver, SolverConfig};

mod util;
use util::timing::{batch_for, median_ns};

const K: f64 = 500.0;
const PATH_TICKS: usize = 2000;
const FRICTION_MU: f64 = 0.4;
/// The exact solver without its primal Newton method: dual block sweeps and the dual active-set finish.
const DUAL_ONLY: SolverConfig = SolverConfig {
    primal_newton: false,
    ..SOLVER_DEFAULTS
};
const SOLVER_DEFAULTS: SolverConfig = SolverConfig::DEFAULT;

/// Euler "to the same accuracy": a residual force of k times the exact solver's tolerance.
const EULER_ACCURATE: EulerConfig = EulerConfig {
    max_iterations: 100_000,
    force_tolerance_n: K * 1e-12,
};

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

struct Row {
    case: String,
    exact_ns: f64,
    exact_error_m: f64,
    exact_bound_m: f64,
    dual_ns: f64,
    dual_error_m: f64,
    dual_bound_m: f64,
    euler_ns: f64,
    euler_error_m: f64,
    accurate_ns: f64,
    accurate_error_m: f64,
    reference_bound_m: f64,
}

/// Prints a row as soon as it is measured (on stderr), so that a long run shows progress.
fn report(row: Row, rows: &mut Vec<Row>) {
    eprintln!("bench solver: {}", markdown_row(&row));
    rows.push(row);
}

/// Issue 14's goal for a case (median time per solve, cold start except the path), if it has one.
fn goal_ns(case: &str) -> Option<f64> {
    match case {
        "exploration path (per tick, worst tick)" => Some(100.0),
        "10 random primitives" => Some(500.0),
        "100 random primitives" => Some(10_000.0),
        "1000 random primitives" => Some(100_000.0),
        "3000 mixed primitives" => Some(1_000_000.0),
        _ => None,
    }
}

/// The summary table's header (tests/docs_reference.rs reads the tables by it).
const SUMMARY_HEADER: &str = "| case | exact | its bound | Euler (paper stop) | its error | speed-up | Euler to 1e-12 m | its error | speed-up | goal | met |";

/// The Euler columns both tables end with (before the summary's goal, the full table's reference bound): Euler
/// with the paper's stop and Euler to 1e-12 m, each its time, its error and the exact solver's speed-up.
fn euler_cells(r: &Row) -> String {
    format!(
        "{} | {:.1e} | {:.2}x | {} | {:.1e} | {:.2}x",
        time(r.euler_ns),
        r.euler_error_m,
        r.euler_ns / r.exact_ns,
        time(r.accurate_ns),
        r.accurate_error_m,
        r.accurate_ns / r.exact_ns,
    )
}

fn summary_row(r: &Row) -> String {
    let goal = goal_ns(&r.case);
    format!(
        "| {} | {} | {:.1e} | {} | {} | {} |",
        r.case,
        time(r.exact_ns),
        r.exact_bound_m,
        euler_cells(r),
        goal.map_or_else(|| "-".to_owned(), |g| format!("< {}", time(g))),
        match goal {
            None => "-",
            Some(g) if r.exact_ns < g => "yes",
            Some(_) => "no",
        }
    )
}

/// Replaces the text between `<!-- solver-bench:NAME begin -->` and `<!-- solver-bench:NAME end -->` in `path`
/// (relative to the crate root) by `text`. The file is written to a temporary beside it and renamed over it, so
/// an interrupted run leaves the old file whole. A missing marker is an error naming the file and the marker.
fn write_block(path: &str, name: &str, text: &str) -> Result<(), String> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    let old = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let begin = format!("<!-- solver-bench:{name} begin -->\n");
    let end = format!("<!-- solver-bench:{name} end -->");
    let start = old
        .find(&begin)
        .ok_or_else(|| format!("{}: no marker `{}`", path.display(), begin.trim()))?
        + begin.len();
    let stop = old[start..]
        .find(&end)
        .ok_or_else(|| format!("{}: no marker `{end}` after its begin", path.display()))?
        + start;
    let new = format!("{}{text}{}", &old[..start], &old[stop..]);
    let temporary = path.with_extension("md.bench-tmp");
    std::fs::write(&temporary, new).map_err(|e| format!("{}: {e}", temporary.display()))?;
    std::fs::rename(&temporary, &path).map_err(|e| format!("{}: {e}", path.display()))
}

fn markdown_row(r: &Row) -> String {
    format!(
        "| {} | {} | {:.1e} | {:.1e} | {} | {:.1e} | {:.1e} | {:.2}x | {} | {:.0e} |",
        r.case,
        time(r.exact_ns),
        r.exact_error_m,
        r.exact_bound_m,
        time(r.dual_ns),
        r.dual_error_m,
        r.dual_bound_m,
        r.dual_ns / r.exact_ns,
        euler_cells(r),
        r.reference_bound_m
    )
}

fn single_case(name: &str, probe: DVec3, primitives: &[Primitive], rows: &mut Vec<Row>) {
    let reference = reference::minimise(K, probe, primitives);
    let problem = Problem {
        stiffness_n_per_m: K,
        probe_m: probe,
        previous_proxy_m: None,
        primitives,
    };
    let mut solver = Solver::with_capacity(SolverConfig::default(), primitives.len());
    let mut exact = || {
        solver.reset();
        black_box(solver.solve(black_box(&problem)).expect("valid"))
    };
    let answer = exact();
    let batch = batch_for(|| {
        exact();
    });
    let exact_ns = median_ns(batch, || {
        exact();
    });
    let mut dual_solver = Solver::with_capacity(DUAL_ONLY, primitives.len());
    let mut dual = || {
        dual_solver.reset();
        black_box(dual_solver.solve(black_box(&problem)).expect("valid"))
    };
    let dual_answer = dual();
    let batch = batch_for(|| {
        dual();
    });
    let dual_ns = median_ns(batch, || {
        dual();
    });
    let euler_with =
        |config: &EulerConfig| euler::solve(K, black_box(probe), probe, primitives, config);
    let euler = euler_with(&EulerConfig::default());
    let batch = batch_for(|| {
        black_box(euler_with(&EulerConfig::default()));
    });
    let euler_ns = median_ns(batch, || {
        black_box(euler_with(&EulerConfig::default()));
    });
    let accurate = euler_with(&EULER_ACCURATE);
    let batch = batch_for(|| {
        black_box(euler_with(&EULER_ACCURATE));
    });
    let accurate_ns = median_ns(batch, || {
        black_box(euler_with(&EULER_ACCURATE));
    });
    report(
        Row {
            case: name.to_string(),
            exact_ns,
            exact_error_m: reference.distance_m(answer.proxy_m),
            exact_bound_m: answer.error_bound_m,
            dual_ns,
            dual_error_m: reference.distance_m(dual_answer.proxy_m),
            dual_bound_m: dual_answer.error_bound_m,
            euler_ns,
            euler_error_m: reference.distance_m(euler.proxy_m),
            accurate_ns,
            accurate_error_m: reference.distance_m(accurate.proxy_m),
            reference_bound_m: reference.error_bound_m,
        },
        rows,
    );
}

fn path_case(rows: &mut Vec<Row>) {
    let ticks = exploration_path();
    let references: Vec<_> = ticks
        .iter()
        .map(|t| reference::minimise(K, t.probe, &t.primitives))
        .collect();
    let run_exact = |solver: &mut Solver| -> Vec<(DVec3, f64)> {
        ticks
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
                (sol.proxy_m, sol.error_bound_m)
            })
            .collect()
    };
    let run_euler = |config: &EulerConfig| -> Vec<DVec3> {
        ticks
            .iter()
            .map(|t| euler::solve(K, t.probe, t.previous_proxy, &t.primitives, config).proxy_m)
            .collect()
    };
    let max_error = |answers: &[DVec3]| {
        answers
            .iter()
            .zip(&references)
            .map(|(a, r)| r.distance_m(*a))
            .fold(0.0, f64::max)
    };
    let exact = run_exact(&mut Solver::with_capacity(SolverConfig::default(), 2));
    let exact_ns = median_ns(3, || {
        black_box(run_exact(&mut Solver::with_capacity(
            SolverConfig::default(),
            2,
        )));
    }) / PATH_TICKS as f64;
    let dual = run_exact(&mut Solver::with_capacity(DUAL_ONLY, 2));
    let dual_ns = median_ns(3, || {
        black_box(run_exact(&mut Solver::with_capacity(DUAL_ONLY, 2)));
    }) / PATH_TICKS as f64;
    let dual_points: Vec<DVec3> = dual.iter().map(|e| e.0).collect();
    let euler_ns = median_ns(3, || {
        black_box(run_euler(&EulerConfig::default()));
    }) / PATH_TICKS as f64;
    let accurate_ns = median_ns(1, || {
        black_box(run_euler(&EULER_ACCURATE));
    }) / PATH_TICKS as f64;
    let exact_points: Vec<DVec3> = exact.iter().map(|e| e.0).collect();
    report(
        Row {
            case: "exploration path (per tick, worst tick)".into(),
            exact_ns,
            exact_error_m: max_error(&exact_points),
            exact_bound_m: exact.iter().map(|e| e.1).fold(0.0, f64::max),
            dual_ns,
            dual_error_m: max_error(&dual_points),
            dual_bound_m: dual.iter().map(|e| e.1).fold(0.0, f64::max),
            euler_ns,
            euler_error_m: max_error(&run_euler(&EulerConfig::default())),
            accurate_ns,
            accurate_error_m: max_error(&run_euler(&EULER_ACCURATE)),
            reference_bound_m: references
                .iter()
                .map(|r| r.error_bound_m)
                .fold(0.0, f64::max),
        },
        rows,
    );
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_owned())
        })
        .unwrap_or_else(|| "unknown CPU".to_owned());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let date = std::process::Command::new("date")
        .args(["-u", "+%Y-%m-%d %H:%M UTC"])
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .unwrap_or_default();
    format!("{cpu}, {cores} logical CPUs, {date}")
}

fn time(ns: f64) -> String {
    if ns >= 1e6 {
        format!("{:.2} ms", ns / 1e6)
    } else if ns >= 1e3 {
        format!("{:.1} us", ns / 1e3)
    } else {
        format!("{ns:.0} ns")
    }
}

fn benches(_c: &mut Criterion) {
    let mut rows = Vec::new();
    path_case(&mut rows);
    for angle in [5.0, 1.0] {
        single_case(
            &format!("wedge {angle} degrees"),
            DVec3::new(-0.0002, 0.002, 0.00001),
            &thin_wedge(angle),
            &mut rows,
        );
    }
    for (label, n) in [
        ("random", 10usize),
        ("random", 100),
        ("random", 1000),
        ("mixed", 3000),
        ("mixed", 10_000),
    ] {
        let (probe, primitives) = random_scene(n as u64, n);
        single_case(
            &format!("{n} {label} primitives"),
            probe,
            &primitives,
            &mut rows,
        );
    }

    let title = format!(
        "Solver benchmark (cargo bench --bench solver): {}",
        machine()
    );
    let mut summary = String::new();
    summary.push_str(&format!("{title}\n"));
    summary.push_str("Median time per solve, cold start except the path; bounds and errors in m (errors against the double-double reference); goals are the solver's speed targets.\n\n");
    summary.push_str(&format!("{SUMMARY_HEADER}\n"));
    summary.push_str("|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in &rows {
        summary.push_str(&format!("{}\n", summary_row(r)));
    }
    let mut full = String::new();
    full.push_str(&format!("{title}\n"));
    full.push_str("Median time per solve, cold start except the path; true errors (m) against the double-double reference.\n\n");
    full.push_str("| case | exact | exact error | exact bound | exact, dual method only | its error | its bound | speed-up | Euler (paper stop) | Euler error | speed-up | Euler to 1e-12 m | its error | speed-up | reference bound |\n");
    full.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in &rows {
        full.push_str(&format!("{}\n", markdown_row(r)));
    }
    println!();
    println!("{summary}");
    println!("{full}");
    if std::env::var_os("VOXHAP_BENCH_DOCS").is_some_and(|v| v == "1") {
        let fenced = |table: &str| format!("```text\n{table}```\n");
        for (path, name, text) in [
            ("README.md", "summary", fenced(&summary)),
            ("docs/solver.md", "summary", fenced(&summary)),
            ("docs/solver.md", "full", fenced(&full)),
        ] {
            match write_block(path, name, &text) {
                Ok(()) => eprintln!("bench solver: wrote the {name} table into {path}"),
                Err(e) => {
                    eprintln!("bench solver: could not write the {name} table: {e}");
                    std::process::exit(1);
                }
            }
        }
    }
}

fn config() -> Criterion {
    Criterion::default()
}

criterion_group! { name = solver; config = config(); targets = benches }
criterion_main!(solver);
