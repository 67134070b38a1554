//! The command line's care for files and crashes: `voxhap sim` and `voxhap serve` never overwrite an
//! existing trace without `--force` and never an input of the run even with it; a sim whose trace would
//! be too large refuses with the estimate; a sim killed with SIGKILL leaves a trace (CSV, MCAP, Parquet)
//! that reads up to the kill and that `voxhap trace repair` rewrites as a finished one.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};
use voxhap::record::read_trace;

fn voxhap(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .unwrap()
}

fn sims_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sims")
}

/// A copy of a shipped scenario in `dir` with `edit` applied to its text.
fn scenario_copy(dir: &Path, name: &str, edit: impl Fn(String) -> String) -> PathBuf {
    let text = std::fs::read_to_string(sims_dir().join(name)).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, edit(text)).unwrap();
    path
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn sim_never_overwrites_without_force_and_never_its_scenario() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario_copy(dir.path(), "vortex_core.toml", |t| {
        t.replace("duration_s = 8.0", "duration_s = 0.2")
    });
    let original = std::fs::read(&scenario).unwrap();
    let out = dir.path().join("run.csv");
    let run = |out: &Path, force: bool| {
        let mut args = vec![
            "sim".as_ref(),
            scenario.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ];
        if force {
            args.push("--force".as_ref());
        }
        voxhap(&args)
    };
    assert!(run(&out, false).status.success());
    let first = std::fs::read(&out).unwrap();
    // Again: refused, file untouched.
    std::fs::write(&out, b"keep me").unwrap();
    let again = run(&out, false);
    assert!(!again.status.success());
    assert!(
        stderr(&again).contains("exists") && stderr(&again).contains("--force"),
        "{}",
        stderr(&again)
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"keep me");
    // With --force: replaced.
    assert!(run(&out, true).status.success());
    assert_eq!(std::fs::read(&out).unwrap().len(), first.len());
    // The scenario as output, under another spelling, even with --force: refused, scenario intact.
    let same = dir.path().join(".").join("vortex_core.toml");
    let clobber = run(&same, true);
    assert!(!clobber.status.success());
    assert!(
        stderr(&clobber).contains("is an input"),
        "{}",
        stderr(&clobber)
    );
    assert_eq!(std::fs::read(&scenario).unwrap(), original);
}

#[test]
fn serve_never_records_over_its_scene() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scenario_copy(dir.path(), "sphere_surface.toml", |t| t);
    let original = std::fs::read(&scene).unwrap();
    let output = voxhap(&[
        "serve".as_ref(),
        "--scene".as_ref(),
        scene.as_os_str(),
        "--record".as_ref(),
        scene.as_os_str(),
        "--force".as_ref(),
        "--duration".as_ref(),
        "1".as_ref(),
    ]);
    assert!(!output.status.success());
    assert!(
        stderr(&output).contains("is an input"),
        "{}",
        stderr(&output)
    );
    assert_eq!(std::fs::read(&scene).unwrap(), original);
}

#[test]
fn a_sim_whose_trace_would_be_too_large_refuses_with_the_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario_copy(dir.path(), "sphere_surface.toml", |t| {
        t.replace("rate_hz = 1000.0", "rate_hz = 100000.0")
    });
    let out = dir.path().join("huge.csv");
    let started = Instant::now();
    // 15 minutes at 100 kHz: 9e7 ticks, inside the tick limit, tens of GB.
    let output = voxhap(&[
        "sim".as_ref(),
        scenario.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--duration".as_ref(),
        "900".as_ref(),
    ]);
    assert!(!output.status.success());
    let text = stderr(&output);
    assert!(
        text.contains("would take about")
            && text.contains("GB")
            && text.contains("--max-trace-bytes"),
        "{text}"
    );
    assert!(!out.exists(), "nothing written");
    assert!(started.elapsed() < Duration::from_secs(30));
}

/// Runs a long sim, kills it with SIGKILL once its trace has grown, and checks what is left.
fn kill_mid_run(extension: &str) {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario_copy(dir.path(), "sphere_surface.toml", |t| {
        t.replace("duration_s = 6.0", "duration_s = 3000.0")
    });
    let out = dir.path().join(format!("killed.{extension}"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .arg("sim")
        .arg(&scenario)
        .arg("--out")
        .arg(&out)
        .args(["--max-trace-bytes", "100000000000"])
        .spawn()
        .unwrap();
    let started = Instant::now();
    // 6 MB: past an MCAP trace's volume picture (1 MB) and a few flushed 1000-tick chunks (1.3 MB each
    // with the scene topics).
    while std::fs::metadata(&out).map_or(0, |m| m.len()) < 6_000_000 {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "the sim wrote too little"
        );
        assert!(child.try_wait().unwrap().is_none(), "the sim ended early");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let trace = read_trace(&out).unwrap();
    assert!(
        trace.samples.len() > 1000,
        "{} samples",
        trace.samples.len()
    );
    for (i, s) in trace.samples.iter().enumerate() {
        assert_eq!(s.tick, i as u64);
    }
    let sidecar = trace.sidecar.as_ref().unwrap();
    assert!(!sidecar.complete);
    // MCAP and Parquet are always unfinished after a kill (no summary, no footer); CSV may end on a
    // whole line.
    if extension != "csv" {
        assert_eq!(trace.warnings.len(), 1, "{:?}", trace.warnings);
    }
    let repaired = dir.path().join(format!("fixed.{extension}"));
    let output = voxhap(&[
        "trace".as_ref(),
        "repair".as_ref(),
        out.as_os_str(),
        "--out".as_ref(),
        repaired.as_os_str(),
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let fixed = read_trace(&repaired).unwrap();
    assert!(fixed.warnings.is_empty());
    assert_eq!(fixed.samples, trace.samples);
    let fixed_sidecar = fixed.sidecar.unwrap();
    assert!(fixed_sidecar.complete && fixed_sidecar.repaired.is_some());
    // The default output name, and no overwrite of the input.
    let default = voxhap(&["trace".as_ref(), "repair".as_ref(), out.as_os_str()]);
    assert!(default.status.success(), "{}", stderr(&default));
    assert!(dir
        .path()
        .join(format!("killed.repaired.{extension}"))
        .exists());
}

#[test]
fn a_killed_csv_sim_reads_up_to_the_kill_and_repairs() {
    kill_mid_run("csv");
}

#[test]
fn a_killed_mcap_sim_reads_up_to_the_kill_and_repairs() {
    kill_mid_run("mcap");
}

#[test]
fn a_killed_parquet_sim_reads_up_to_the_kill_and_repairs() {
    kill_mid_run("parquet");
}

/// `serve --fail-on uncertified` exits 3 after a clean stop when a baseline solver ran (no tick certified),
/// and 0 with the exact solver.
#[test]
fn serve_fail_on_exits_3_only_when_a_condition_occurred() {
    let dir = tempfile::tempdir().unwrap();
    let euler = scenario_copy(dir.path(), "vortex_core.toml", |t| {
        t.replace(
            "k_n_per_m = 500.0\n",
            "k_n_per_m = 500.0\n\n[solver]\nkind = \"euler\"\n",
        )
    });
    let serve = |scene: &Path| {
        voxhap(&[
            "serve".as_ref(),
            "--scene".as_ref(),
            scene.as_os_str(),
            "--duration".as_ref(),
            "0.3".as_ref(),
            "--no-http".as_ref(),
            "--no-foxglove".as_ref(),
            "--fail-on".as_ref(),
            "uncertified,disconnect,device-error".as_ref(),
        ])
    };
    let failed = serve(&euler);
    assert_eq!(failed.status.code(), Some(3), "{}", stderr(&failed));
    assert!(
        stderr(&failed).contains("--fail-on: uncertified"),
        "{}",
        stderr(&failed)
    );
    let exact = serve(&sims_dir().join("vortex_core.toml"));
    assert!(exact.status.success(), "{}", stderr(&exact));
}
