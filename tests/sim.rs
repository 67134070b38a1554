//! `voxhap sim` and the sims/ scenarios end to end: every shipped scenario runs, the multi-modal scene is
//! certified on every tick by the exact solver and shows the constraint approach's artifact, runs are
//! byte-for-byte deterministic, and the MRI brain sim runs when the shared data is there (skips otherwise).

use std::path::{Path, PathBuf};
use std::process::Command;
use voxhap::haptics::tick::SolverKind;
use voxhap::record::{create_trace_writer, read_trace, Trace, TraceFormat, TraceMeta};
use voxhap::sim::{self, LoadedScenario, SimSummary};

fn sims_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sims")
}

/// Runs a scenario through the library into `out` with a fixed creation time.
fn run_to(name: &str, solver: SolverKind, out: &Path, format: TraceFormat) -> (SimSummary, Trace) {
    let loaded = LoadedScenario::from_file(&sims_dir().join(name)).unwrap();
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
    let summary = sim::run(&loaded, solver, writer.as_mut(), |_| {}).unwrap();
    writer.finish().unwrap();
    (summary, read_trace(out).unwrap())
}

#[test]
fn every_shipped_scenario_parses_and_the_procedural_ones_run_certified() {
    let dir = tempfile::tempdir().unwrap();
    let mut names: Vec<String> = std::fs::read_dir(sims_dir())
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert!(names.len() >= 6, "{names:?}");
    for name in &names {
        voxhap::sim::Scenario::read(&sims_dir().join(name)).unwrap();
        if name.starts_with("brain") {
            continue; // needs the shared data; see the brain test
        }
        let (summary, trace) = run_to(
            name,
            SolverKind::Exact,
            &dir.path().join(format!("{name}.csv")),
            TraceFormat::Csv,
        );
        assert_eq!(trace.samples.len() as u64, summary.ticks, "{name}");
        assert!(
            summary.max_error_bound_m <= 1e-9,
            "{name}: bound {}",
            summary.max_error_bound_m
        );
        // Every scene touches something: some tick had primitives and a force.
        assert!(
            trace
                .samples
                .iter()
                .any(|s| s.primitives().iter().any(|&c| c > 0)),
            "{name}"
        );
        assert!(summary.max_force_n > 0.1, "{name}: {}", summary.max_force_n);
    }
}

#[test]
fn multimodal_exact_trace_is_certified_and_the_constraint_approach_loses_the_surface() {
    let dir = tempfile::tempdir().unwrap();
    let (exact, trace) = run_to(
        "multimodal.toml",
        SolverKind::Exact,
        &dir.path().join("e.csv"),
        TraceFormat::Csv,
    );
    assert_eq!(trace.mode_names, ["surface", "vector_follow", "viscosity"]);
    let worst = trace
        .samples
        .iter()
        .map(|s| s.error_bound_m)
        .fold(0.0, f64::max);
    assert!(worst <= 1e-9, "certificate bound {worst} m");
    assert_eq!(exact.certified_ticks, exact.ticks);
    // The multi-modal part: most ticks have the surface plane and the flow line at once.
    let both = trace
        .samples
        .iter()
        .filter(|s| s.primitives()[0] == 1 && s.primitives()[1] == 1)
        .count();
    assert!(
        both > trace.samples.len() / 2,
        "{both} ticks with surface and flow"
    );

    let (_, constraint) = run_to(
        "multimodal.toml",
        SolverKind::Constraint,
        &dir.path().join("c.csv"),
        TraceFormat::Csv,
    );
    assert!(constraint
        .samples
        .iter()
        .all(|s| s.error_bound_m == f64::INFINITY));
    // In the second half (steady circling) the exact proxy rides on the 3 cm ball; the constraint approach's
    // proxy has fallen inside it, with the probe.
    let half = trace.samples.len() / 2;
    let mean_radius = |t: &Trace| {
        t.samples[half..]
            .iter()
            .map(|s| s.proxy_m.length())
            .sum::<f64>()
            / (t.samples.len() - half) as f64
    };
    let (exact_r, constraint_r) = (mean_radius(&trace), mean_radius(&constraint));
    assert!(
        exact_r > 0.0295,
        "exact proxy at {exact_r} m from the centre"
    );
    assert!(
        constraint_r < exact_r - 0.001,
        "constraint proxy at {constraint_r} m vs exact {exact_r} m"
    );
}

#[test]
fn two_runs_write_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    for format in [TraceFormat::Csv, TraceFormat::Mcap] {
        let a = dir.path().join(format!("a.{format}"));
        let b = dir.path().join(format!("b.{format}"));
        run_to("friction_sliding.toml", SolverKind::Exact, &a, format);
        run_to("friction_sliding.toml", SolverKind::Exact, &b, format);
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "{format} traces differ"
        );
    }
}

#[test]
fn cli_runs_are_deterministic_apart_from_the_sidecar_timestamp() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = sims_dir().join("vortex_core.toml");
    let run = |out: &Path, solver: &str| {
        let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
            .arg("sim")
            .arg(&scenario)
            .arg("--out")
            .arg(out)
            .args(["--solver", solver, "--start-utc-ns", "1700000000000000000"])
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        // Not a terminal: no progress bar, nothing on stderr; one summary line on stdout.
        assert!(
            output.stderr.is_empty(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        String::from_utf8(output.stdout).unwrap()
    };
    let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
    let summary = run(&a, "exact");
    assert!(
        summary.contains("8000 ticks") && summary.contains("8000 certified"),
        "{summary}"
    );
    run(&b, "exact");
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
    let sidecar = |p: &Path| {
        let mut v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(voxhap::record::sidecar_path(p)).unwrap())
                .unwrap();
        v.as_object_mut().unwrap().remove("created_utc");
        assert_eq!(v["start_utc_ns"], 1_700_000_000_000_000_000i64);
        v.as_object_mut().unwrap().remove("trace_file");
        v
    };
    assert_eq!(sidecar(&a), sidecar(&b));
    assert_eq!(sidecar(&a)["solver"], "exact-dual");
    let euler = run(&dir.path().join("e.mcap"), "euler");
    assert!(
        euler.contains("solver euler") && euler.contains("uncertified"),
        "{euler}"
    );
}

#[test]
fn cli_errors_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(sims_dir().join("sphere_surface.toml"))
        .unwrap()
        .replace("[[0.45, 0.0], [0.5, 2.0]]", "[[0.5, 0.0], [0.45, 2.0]]");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, text).unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .arg("sim")
        .arg(&bad)
        .arg("--out")
        .arg(dir.path().join("x.csv"))
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("modes[0].transfer") && stderr.contains("x must increase"),
        "{stderr}"
    );
    assert!(
        !dir.path().join("x.csv").exists(),
        "no trace for a refused scenario"
    );
}

#[test]
fn brain_surface_exploration_on_the_mni_template() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mni152_t1_1mm.nii.gz");
    if !data.exists() {
        eprintln!(
            "skipping brain_surface_exploration_on_the_mni_template: {} is absent",
            data.display()
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (summary, trace) = run_to(
        "brain_surface.toml",
        SolverKind::Exact,
        &dir.path().join("b.mcap"),
        TraceFormat::Mcap,
    );
    assert_eq!(summary.certified_ticks, summary.ticks);
    // The proxy rides the cortex: in contact for a good part of the raster, never deeper than s/k below it.
    let contact = trace
        .samples
        .iter()
        .filter(|s| s.primitives()[0] == 1 && s.force_n.length() > 0.05)
        .count();
    assert!(
        contact > trace.samples.len() / 4,
        "{contact} of {} ticks in contact",
        trace.samples.len()
    );
    assert!(summary.max_force_n <= 2.0 + 1e-9, "{}", summary.max_force_n);
}
