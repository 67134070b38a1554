//! Runs are byte-for-byte deterministic (library and command line), errors name the key, and the command line's
//! overrides, `--fail-on`, `compare` and `sweep` do what sims/README.md says.

use crate::util::sim::{run_to, sims_dir, voxhap};
use std::path::Path;
use std::process::Command;
use voxhap::haptics::tick::SolverKind;
use voxhap::record::{read_trace, TraceFormat};

#[test]
fn two_runs_write_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    // The same file name in two folders: a Parquet trace embeds its sidecar, which names the trace file.
    let (dir_a, dir_b) = (dir.path().join("a"), dir.path().join("b"));
    std::fs::create_dir_all(&dir_a).unwrap();
    std::fs::create_dir_all(&dir_b).unwrap();
    for format in [TraceFormat::Csv, TraceFormat::Mcap, TraceFormat::Parquet] {
        let a = dir_a.join(format!("run.{format}"));
        let b = dir_b.join(format!("run.{format}"));
        run_to("friction_sliding.toml", SolverKind::Exact, &a, format);
        run_to("friction_sliding.toml", SolverKind::Exact, &b, format);
        assert!(
            std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
            "{format} traces differ"
        );
    }
}

/// Blanks the value of every `"created_utc":"YYYY-MM-DDThh:mm:ssZ"` in `bytes` (same length, so the rest of the
/// file lines up) and counts them.
fn mask_created_utc(mut bytes: Vec<u8>) -> (Vec<u8>, usize) {
    let key = br#""created_utc":""#;
    let (mut count, mut at) = (0, 0);
    while let Some(found) = bytes[at..].windows(key.len()).position(|w| w == key) {
        let start = at + found + key.len();
        let end = (start + "2026-01-31T12:00:00Z".len()).min(bytes.len());
        bytes[start..end].fill(b'#');
        count += 1;
        at = end;
    }
    (bytes, count)
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
    // A Parquet trace carries its sidecar (which names the trace file) in its footer metadata, so there the
    // creation time is inside the file: apart from those bytes two runs to the same name are the same.
    let (pa, pb) = (dir.path().join("1"), dir.path().join("2"));
    std::fs::create_dir_all(&pa).unwrap();
    std::fs::create_dir_all(&pb).unwrap();
    let (pa, pb) = (pa.join("run.parquet"), pb.join("run.parquet"));
    run(&pa, "exact");
    run(&pb, "exact");
    let (pa, stamps) = mask_created_utc(std::fs::read(&pa).unwrap());
    let (pb, _) = mask_created_utc(std::fs::read(&pb).unwrap());
    assert!(
        stamps > 0,
        "no embedded sidecar timestamp in the Parquet trace"
    );
    assert!(
        pa == pb,
        "Parquet traces differ beyond the sidecar's created_utc"
    );
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

/// `sim --set/--duration/--rate` change the scenario (recorded in the sidecar); `--fail-on uncertified`
/// exits 3 for a baseline solver after writing the trace; `compare` exits 0 for equal traces and 1 with a
/// readable report for different ones.
#[test]
fn overrides_fail_on_and_compare_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = sims_dir().join("vortex_core.toml");
    let run = |out: &Path, extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "sim".as_ref(),
            scenario.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--start-utc-ns".as_ref(),
            "0".as_ref(),
        ];
        args.extend(extra.iter().map(std::ffi::OsStr::new));
        voxhap(&args)
    };
    let a = dir.path().join("a.csv");
    let output = run(
        &a,
        &[
            "--duration",
            "0.5",
            "--rate",
            "2000",
            "--set",
            "k_n_per_m=400",
        ],
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let trace = read_trace(&a).unwrap();
    assert_eq!(trace.samples.len(), 1000);
    let sidecar = trace.sidecar.unwrap();
    assert_eq!(sidecar.meta.rate_hz, 2000.0);
    assert_eq!(sidecar.meta.scenario["k_n_per_m"], 400.0);
    // A bad key is refused naming it, before anything is written.
    let bad = dir.path().join("bad.csv");
    let output = run(&bad, &["--set", "k_n_per_mm=400"]);
    assert_eq!(output.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&output.stderr).contains("k_n_per_mm"));
    assert!(!bad.exists());
    // --fail-on.
    let euler = dir.path().join("euler.csv");
    let output = run(
        &euler,
        &[
            "--duration",
            "0.2",
            "--solver",
            "euler",
            "--fail-on",
            "uncertified,overrun",
        ],
    );
    assert_eq!(
        output.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(String::from_utf8_lossy(&output.stderr).contains("uncertified: 200 of 200 ticks"));
    assert!(read_trace(&euler).unwrap().sidecar.unwrap().complete);
    let exact = dir.path().join("exact.csv");
    let output = run(
        &exact,
        &["--duration", "0.2", "--fail-on", "uncertified,device-error"],
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // compare.
    let b = dir.path().join("b.csv");
    assert!(run(
        &b,
        &[
            "--duration",
            "0.5",
            "--rate",
            "2000",
            "--set",
            "k_n_per_m=400"
        ]
    )
    .status
    .success());
    let same = voxhap(&["compare".as_ref(), a.as_os_str(), b.as_os_str()]);
    assert!(
        same.status.success(),
        "{}",
        String::from_utf8_lossy(&same.stderr)
    );
    let c = dir.path().join("c.csv");
    assert!(run(
        &c,
        &[
            "--duration",
            "0.5",
            "--rate",
            "2000",
            "--set",
            "k_n_per_m=410"
        ]
    )
    .status
    .success());
    let differ = voxhap(&[
        "compare".as_ref(),
        a.as_os_str(),
        c.as_os_str(),
        "--tol".as_ref(),
        "force=1e-6,proxy=1e-6".as_ref(),
    ]);
    assert_eq!(differ.status.code(), Some(1));
    let report = String::from_utf8_lossy(&differ.stderr);
    assert!(
        report.contains("force") && report.contains("DIFFERS"),
        "{report}"
    );
    let loose = voxhap(&[
        "compare".as_ref(),
        a.as_os_str(),
        c.as_os_str(),
        "--tol".as_ref(),
        "all=1".as_ref(),
    ]);
    assert!(
        loose.status.success(),
        "{}",
        String::from_utf8_lossy(&loose.stderr)
    );
}

/// `sweep` runs every combination, one trace per point with the values in its sidecar, and a summary.
#[test]
fn sweep_runs_every_combination_in_parallel() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("sweep");
    let output = voxhap(&[
        "sweep".as_ref(),
        sims_dir().join("friction_sliding.toml").as_os_str(),
        "--set".as_ref(),
        "k_n_per_m=200,500,1000".as_ref(),
        "--set".as_ref(),
        "modes[1].mu=0.3,0.5".as_ref(),
        "--duration".as_ref(),
        "0.3".as_ref(),
        "--jobs".as_ref(),
        "2".as_ref(),
        "--out-dir".as_ref(),
        out_dir.as_os_str(),
    ]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("6 points (2 jobs)"), "{stdout}");
    let summary = std::fs::read_to_string(out_dir.join("sweep.csv")).unwrap();
    assert_eq!(summary.lines().count(), 7);
    for index in 0..6 {
        let trace = read_trace(&out_dir.join(format!("point-{index:03}.csv"))).unwrap();
        assert_eq!(trace.samples.len(), 300);
        let scenario = trace.sidecar.unwrap().meta.scenario;
        let k = [200.0, 500.0, 1000.0][index / 2];
        let mu = [0.3, 0.5][index % 2];
        assert_eq!(scenario["k_n_per_m"], k, "point {index}");
        assert_eq!(scenario["modes"][1]["mu"], mu, "point {index}");
    }
    // Again without --force: refused, nothing replaced.
    let again = voxhap(&[
        "sweep".as_ref(),
        sims_dir().join("friction_sliding.toml").as_os_str(),
        "--set".as_ref(),
        "k_n_per_m=200".as_ref(),
        "--out-dir".as_ref(),
        out_dir.as_os_str(),
    ]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
}
