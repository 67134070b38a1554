//! `voxhap._voxhap.solve`: the one proxy problem of a JSON scene file, solved as `voxhap solve --json`
//! solves it (the same solvers and budget, the median time of up to 101 cold solves within 2 s), answered
//! as the same JSON object.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use serde_json::json;
use std::time::Instant;
use voxhap_core::clock::MonotonicClock;
use voxhap_core::haptics::baselines::{constraint, euler};
use voxhap_core::haptics::solver::{Solver, SolverConfig};
use voxhap_io::scene::Scene;

/// Times reported are the median of up to this many solves of the same scene (each from a cold start)...
const TIMING_RUNS: usize = 101;
/// ... or of those that fit in this many seconds (at least one).
const TIMING_WALL_S: f64 = 2.0;

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// One solve of `scene` by `solver` as the JSON fields of `voxhap solve --json` (without the time).
fn solve_once(
    scene: &Scene,
    solver_name: &str,
    solver: &mut Solver,
) -> PyResult<serde_json::Value> {
    let start = scene.previous_proxy_m.unwrap_or(scene.probe_m);
    let baseline = match solver_name {
        "exact" => {
            solver.reset();
            let sol = solver
                .solve_with_clock(&scene.problem(), &MonotonicClock::new())
                .map_err(value_error)?;
            return Ok(json!({
                "solver": solver_name,
                "proxy": sol.proxy_m.to_array(),
                "force": sol.force_n.to_array(),
                "iterations": sol.sweeps + sol.active_set_rounds,
                "sweeps": sol.sweeps,
                "newton_passes": sol.newton_passes,
                "active_set_rounds": sol.active_set_rounds,
                "gap": sol.gap_j,
                "error_bound": sol.error_bound_m,
                "status": sol.status,
            }));
        }
        "euler" => euler::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
            &euler::EulerConfig::default(),
        ),
        "constraint" => constraint::solve(
            scene.stiffness_n_per_m,
            scene.probe_m,
            start,
            &scene.primitives,
        ),
        other => {
            return Err(PyValueError::new_err(format!(
                "solver {other:?}: expected exact, euler or constraint"
            )))
        }
    };
    Ok(json!({
        "solver": solver_name,
        "proxy": baseline.proxy_m.to_array(),
        "force": baseline.force_n.to_array(),
        "iterations": baseline.iterations,
        "residual": baseline.residual_n,
    }))
}

/// Solves the one proxy problem of a JSON scene file (as `voxhap solve SCENE --json`) with `solver`
/// (`exact`, `euler` or `constraint`) and returns the answer as JSON text: proxy, force, status, bound,
/// iterations and `time_ns`, the median wall time.
#[pyfunction]
#[pyo3(signature = (scene, solver = "exact"))]
pub fn solve(py: Python<'_>, scene: std::path::PathBuf, solver: &str) -> PyResult<String> {
    if !["exact", "euler", "constraint"].contains(&solver) {
        return Err(PyValueError::new_err(format!(
            "solver {solver:?}: expected exact, euler or constraint"
        )));
    }
    let scene = Scene::load(&scene).map_err(|e| value_error(voxhap_record::error_chain(&e)))?;
    py.detach(|| {
        let config = SolverConfig::default();
        let mut exact = Solver::with_capacity(config, scene.primitives.len());
        let mut times = Vec::with_capacity(TIMING_RUNS);
        let mut answer = None;
        let wall = Instant::now();
        for _ in 0..TIMING_RUNS {
            if answer.is_some() && wall.elapsed().as_secs_f64() >= TIMING_WALL_S {
                break;
            }
            let started = Instant::now();
            let result = solve_once(&scene, solver, &mut exact)?;
            times.push(u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX));
            answer = Some(result);
        }
        times.sort_unstable();
        let mut answer = answer.ok_or_else(|| PyValueError::new_err("no solve ran"))?;
        answer["time_ns"] = json!(times[times.len() / 2]);
        serde_json::to_string_pretty(&answer).map_err(value_error)
    })
}
