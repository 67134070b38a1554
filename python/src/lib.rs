//! `voxhap._voxhap`: the native half of the `voxhap` Python package (python/voxhap/ is the other half).
//! It exposes the library's own sim loop, solver and live session, and the parts of its trace code that
//! `voxhap.read_trace` needs (`trace.rs`): pandas and pyarrow read Parquet and CSV traces themselves, and
//! this module reads MCAP (and cut-off Parquet) traces into columns in memory. Where it sits: beside the
//! `voxhap` command, over the same library crates (voxhap-servo, voxhap-record, voxhap-io, voxhap-core;
//! not the HTTP server nor the command line), so a trace read or a sim run from Python is exactly what the
//! CLI gives. `session.rs` runs a live session with the simulated arm (`voxhap.Session`).

mod session;
mod solve;
mod trace;

use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use std::path::{Path, PathBuf};
use voxhap_core::haptics::tick::SolverKind;
use voxhap_record::{create_trace_writer_with, error_chain, OutputPolicy, TraceFormat, TraceMeta};
use voxhap_servo::sim::LoadedScenario;

/// The scenario file with `overrides` (`key=value`), `duration_s` and `rate_hz` applied, validated and
/// loaded, as `voxhap sim --set/--duration/--rate` loads it (errors name the file and the key).
fn load_scenario(
    path: &Path,
    set: &[String],
    duration_s: Option<f64>,
    rate_hz: Option<f64>,
) -> PyResult<LoadedScenario> {
    let error = |e: &dyn std::error::Error| PyValueError::new_err(error_chain(e));
    let mut overrides = set.to_vec();
    if let Some(duration) = duration_s {
        overrides.push(format!("duration_s={duration:?}"));
    }
    if let Some(rate) = rate_hz {
        overrides.push(format!("rate_hz={rate:?}"));
    }
    if overrides.is_empty() {
        return LoadedScenario::from_file(path).map_err(|e| error(&e));
    }
    let origin = path.display().to_string();
    let text = voxhap_io::read_text_file(path)
        .map_err(|e| PyValueError::new_err(format!("cannot read scenario file {origin}: {e}")))?;
    let text = voxhap_servo::sim::overrides::apply_overrides(&text, &overrides)
        .map_err(|e| PyValueError::new_err(format!("{origin}: overrides: {}", error_chain(&e))))?;
    let scenario =
        voxhap_servo::sim::Scenario::parse_edited(&text, &format!("{origin} (with --set)"))
            .map_err(|e| error(&e))?;
    let base_dir = path.parent().unwrap_or(Path::new(""));
    scenario.load(base_dir, &origin).map_err(|e| error(&e))
}

/// The solver label recorded in the trace metadata (as `voxhap sim` records it).
fn solver_label(solver: SolverKind) -> &'static str {
    match solver {
        SolverKind::Exact => "exact-dual",
        SolverKind::Euler => "euler-baseline",
        SolverKind::Constraint => "constraint-baseline",
    }
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
    let loaded = load_scenario(&scenario, &overrides, duration_s, rate_hz)?;
    let solver = loaded.scenario.solver.kind;
    let scenario_json =
        serde_json::to_value(&loaded.scenario).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        scenario_json,
        loaded.volume_description.clone(),
        solver_label(solver),
    );
    // The run's inputs (the scenario and the volume files it names) are never an output.
    let base = scenario.parent().unwrap_or(Path::new(""));
    let mut inputs = vec![scenario.clone()];
    inputs.extend(
        loaded
            .scenario
            .volumes
            .iter()
            .filter_map(|v| v.file.as_ref().map(|f| base.join(f))),
    );
    let policy = OutputPolicy {
        overwrite: true,
        inputs,
    };
    let mut writer = create_trace_writer_with(&out, TraceFormat::Parquet, &meta, &policy)
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    let summary = voxhap_servo::sim::run(&loaded, solver, writer.as_mut(), |_| {})
        .map_err(|e| PyValueError::new_err(error_chain(&e)))?;
    writer
        .finish()
        .map_err(|e| PyOSError::new_err(error_chain(&e)))?;
    Ok((summary.ticks, summary.certified_ticks, summary.max_force_n))
}

#[pymodule]
fn _voxhap(module: &Bound<'_, PyModule>) -> PyResult<()> {
    module.add_function(wrap_pyfunction!(trace::read_trace_columns, module)?)?;
    module.add_function(wrap_pyfunction!(trace::trace_columns, module)?)?;
    module.add_function(wrap_pyfunction!(trace::csv_mode_names, module)?)?;
    module.add_function(wrap_pyfunction!(trace::sidecar_check, module)?)?;
    module.add_function(wrap_pyfunction!(trace::flag_bits, module)?)?;
    module.add_function(wrap_pyfunction!(sim, module)?)?;
    module.add_function(wrap_pyfunction!(solve::solve, module)?)?;
    module.add_class::<session::NativeSession>()?;
    Ok(())
}
