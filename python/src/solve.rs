//! `voxhap._voxhap.solve`: the one proxy problem of a JSON scene file, solved and timed as `voxhap solve --json`
//! solves it (voxhap-io's `scene_solve`: the same solvers, budget and timing), answered as the same JSON object.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use voxhap_io::scene::Scene;
use voxhap_io::scene_solve::{solve_timed, SceneSolveConfig, SceneSolver};

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Solves the one proxy problem of a JSON scene file (as `voxhap solve SCENE --json`) with `solver`
/// (`exact`, `euler` or `constraint`) and returns the answer as JSON text: proxy, force, status, bound,
/// iterations and `time_ns`, the median wall time.
#[pyfunction]
#[pyo3(signature = (scene, solver = "exact"))]
pub fn solve(py: Python<'_>, scene: std::path::PathBuf, solver: &str) -> PyResult<String> {
    let solver = SceneSolver::from_name(solver).map_err(value_error)?;
    let scene = Scene::load(&scene).map_err(|e| value_error(voxhap_record::error_chain(&e)))?;
    py.detach(|| {
        let timed = solve_timed(&scene, solver, &SceneSolveConfig::DEFAULT).map_err(value_error)?;
        serde_json::to_string_pretty(&timed.to_json()).map_err(value_error)
    })
}
