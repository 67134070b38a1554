//! Helpers of the `voxhap sim` tests (tests/sim/): the sims/ directory, a library run of a scenario into a trace
//! with a fixed creation time, and a run of the `voxhap` binary.

use std::path::{Path, PathBuf};
use std::process::Command;
use voxhap::haptics::tick::SolverKind;
use voxhap::record::{create_trace_writer, read_trace, Trace, TraceFormat, TraceMeta, TraceSample};
use voxhap::sim::{self, LoadedScenario, Scenario, SimSummary};

/// The repository's sims/ directory.
pub fn sims_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sims")
}

/// Runs a scenario through the library into `out` with a fixed creation time.
pub fn run_to(
    name: &str,
    solver: SolverKind,
    out: &Path,
    format: TraceFormat,
) -> (SimSummary, Trace) {
    let loaded = LoadedScenario::from_file(&sims_dir().join(name)).unwrap();
    run_loaded(&loaded, solver, out, format)
}

/// Runs a loaded scenario through the library into `out` with a fixed creation time.
pub fn run_loaded(
    loaded: &LoadedScenario,
    solver: SolverKind,
    out: &Path,
    format: TraceFormat,
) -> (SimSummary, Trace) {
    let mut meta = TraceMeta::new(
        loaded.scene.mode_names().to_vec(),
        loaded.scenario.rate_hz,
        serde_json::to_value(&loaded.scenario).unwrap(),
        loaded.volume_description.clone(),
        solver.name(),
    );
    meta.created_utc = "2000-01-01T00:00:00Z".to_owned();
    meta.start_utc_ns = 946_684_800_000_000_000;
    let mut writer = create_trace_writer(out, format, &meta).unwrap();
    let summary = sim::run(loaded, solver, writer.as_mut(), |_| {}).unwrap();
    writer.finish().unwrap();
    (summary, read_trace(out).unwrap())
}

/// Runs a scenario's text (`origin` names it in errors; its files are looked up in sims/) with the exact
/// solver into a temporary CSV trace; returns the summary, the trace's samples and the loaded scenario.
pub fn run_text(text: &str, origin: &str) -> (SimSummary, Vec<TraceSample>, Scenario) {
    let scenario = Scenario::parse(text, origin).unwrap_or_else(|e| panic!("{origin}: {e}"));
    let loaded = scenario
        .load(&sims_dir(), origin)
        .unwrap_or_else(|e| panic!("{origin}: {e}"));
    let dir = tempfile::tempdir().unwrap();
    let (summary, trace) = run_loaded(
        &loaded,
        SolverKind::Exact,
        &dir.path().join("t.csv"),
        TraceFormat::Csv,
    );
    (summary, trace.samples, loaded.scenario)
}

/// Runs the `voxhap` binary with `args` and collects its output.
pub fn voxhap(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .unwrap()
}
