//! `voxhap._voxhap`: the native half of the `voxhap` Python package (python/voxhap/__init__.py is the
//! other half). It exposes the library's own trace reader and sim loop; Python turns their Parquet output
//! into pandas DataFrames. Where it sits: beside the `voxhap` command, over the same library calls
//! (`voxhap::record`, `voxhap::sim`), so a trace read or a sim run from Python is exactly what the CLI gives.
//! `session.rs` runs a live session with the simulated arm (`voxhap.Session`).

mod session;

use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use std::path::PathBuf;
use voxhap::record::{
    create_trace_writer_with, error_chain, read_trace, OutputPolicy, TraceFormat, TraceMeta,
};

/// Reads a trace (CSV, MCAP or Parquet, also one cut off by a crash) and writes it as a finished Parquet
/// file at `out`. Returns the reader's warnings (what was skipped and why).
#[pyfunction]
fn trace_to_parquet(path: PathBuf, out: PathBuf) -> PyResult<Vec<String>> {
    let trace = read_trace(&path).map_err(|e| PyValueError::new_err(error_chain(&e)))?;
    let meta = match &trace.sidecar {
        Some(sidecar) => sidecar.meta.clone(),
        None => TraceMeta::new(
            trace.mode_names.clone(),
            1000.0,
            serde_json::Value::Null,
            "unknown (no sidecar)",
            "unknown (no sidecar)",
        ),
    };
    let policy = OutputPolicy {
        overwrite: true,
        inputs: vec![path.clone()],
    };
    let mut writer = create_trace_writer_with(&out, TraceFormat::Parquet, &meta, &policy)
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    for sample in &trace.samples {
        writer
            .write_sample(sample)
            .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    }
    writer
        .finish()
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    Ok(trace.warnings)
}

/// Runs the sim `scenario` (a TOML file) with `overrides` (`key=value`, as `voxhap sim --set`) and writes
/// its trace as Parquet to `out`. Returns (ticks, certified ticks, largest force in N).
#[pyfunction]
#[pyo3(signature = (scenario, out, overrides = Vec::new(), duration_s = None, rate_hz = None))]
fn sim(
    scenario: PathBuf,
    out: PathBuf,
    overrides: Vec<String>,
    duration_s: Option<f64>,
    rate_hz: Option<f64>,
) -> PyResult<(u64, u64, f64)> {
    let loaded = voxhap::cli::sim::load_scenario(&scenario, &overrides, duration_s, rate_hz)
        .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let solver = loaded.scenario.solver.kind;
    let scenario_json =
        serde_json::to_value(&loaded.scenario).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        scenario_json,
        loaded.volume_description.clone(),
        voxhap::cli::sim::solver_label(solver),
    );
    let policy = OutputPolicy {
        overwrite: true,
        inputs: voxhap::cli::sim::scenario_inputs(&scenario, &loaded),
    };
    let mut writer = create_trace_writer_with(&out, TraceFormat::Parquet, &meta, &policy)
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    let summary = voxhap::sim::run(&loaded, solver, writer.as_mut(), |_| {})
        .map_err(|e| PyValueError::new_err(error_chain(&e)))?;
    writer
        .finish()
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    Ok((summary.ticks, summary.certified_ticks, summary.max_force_n))
}

/// Solves the one proxy problem of a JSON scene file (as `voxhap solve SCENE --json`) with `solver`
/// (`exact`, `euler` or `constraint`) and returns the answer as JSON text: proxy, force, status, bound.
#[pyfunction]
#[pyo3(signature = (scene, solver = "exact"))]
fn solve(scene: PathBuf, solver: &str) -> PyResult<String> {
    use voxhap::cli::solve::SolverChoice;
    let choice = match solver {
        "exact" => SolverChoice::Exact,
        "euler" => SolverChoice::Euler,
        "constraint" => SolverChoice::Constraint,
        other => {
            return Err(PyValueError::new_err(format!(
                "solver {other:?}: expected exact, euler or constraint"
            )))
        }
    };
    let scene = voxhap::haptics::scene::Scene::load(&scene)
        .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    voxhap::cli::solve::report(
        &scene,
        choice,
        true,
        voxhap::haptics::solver::SolverConfig::default(),
    )
    .map_err(|e| PyValueError::new_err(format!("{e:#}")))
}

#[pymodule]
fn _voxhap(module: &Bound<'_, PyModule>) -> PyResult<()> {
    module.add_function(wrap_pyfunction!(trace_to_parquet, module)?)?;
    module.add_function(wrap_pyfunction!(sim, module)?)?;
    module.add_function(wrap_pyfunction!(solve, module)?)?;
    module.add_class::<session::NativeSession>()?;
    Ok(())
}
