//! `voxhap solve` and the default run (`voxhap` with no subcommand serves), through the real binary.

use std::process::Command;

fn voxhap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .expect("run voxhap")
}

fn example() -> String {
    format!(
        "{}/sims/scenes/plane_point.json",
        env!("CARGO_MANIFEST_DIR")
    )
}

#[test]
fn solve_prints_json_with_the_documented_keys() {
    let out = voxhap(&["solve", "--scene", &example(), "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let proxy: Vec<f64> = serde_json::from_value(v["proxy"].clone()).unwrap();
    let force: Vec<f64> = serde_json::from_value(v["force"].clone()).unwrap();
    assert!(
        (proxy[0] - 0.002).abs() < 1e-12 && proxy[1].abs() < 1e-12 && proxy[2].abs() < 1e-12,
        "{proxy:?}"
    );
    assert!(
        (force[0] + 0.5).abs() < 1e-9 && (force[2] - 1.0).abs() < 1e-9,
        "{force:?}"
    );
    assert!(v["iterations"].as_u64().unwrap() >= 1);
    assert!(v["time_ns"].as_u64().unwrap() > 0);
    assert!(v["gap"].as_f64().unwrap() >= 0.0);
    assert!(v["error_bound"].as_f64().unwrap() <= 1e-9);
    assert_eq!(v["status"], "certified");
}

#[test]
fn baselines_print_json_without_a_certificate() {
    for solver in ["euler", "constraint"] {
        let out = voxhap(&["solve", "--scene", &example(), "--solver", solver, "--json"]);
        assert!(out.status.success());
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(v["solver"], solver);
        assert_eq!(v["proxy"].as_array().unwrap().len(), 3);
        assert!(v.get("gap").is_none() && v.get("error_bound").is_none());
    }
}

#[test]
fn no_subcommand_serves_the_simulated_arm_until_sigterm() {
    // `voxhap` alone is `voxhap serve` (with its flags): it runs until a signal, then exits 0 and
    // prints the servo statistics. Port 0 and no live view, so parallel tests and a real server on 8080
    // or 8765 do not collide.
    let mut child = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(["--http", "127.0.0.1:0", "--no-foxglove"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run voxhap");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "voxhap with no subcommand exited instead of serving"
    );
    // SAFETY: kill(2) on our own child's pid.
    let rc = unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    assert_eq!(rc, 0);
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("no subcommand given"), "{stdout}");
    assert!(stdout.contains("device sim"), "{stdout}");
    assert!(stdout.contains("lateness"), "{stdout}");
    assert!(
        stdout.contains("http: listening on http://127.0.0.1:"),
        "{stdout}"
    );
    assert!(stdout.contains("http: control token "), "{stdout}");
    assert!(stdout.contains("/?token="), "{stdout}");
}

#[test]
fn malformed_scenes_name_the_field() {
    let dir = std::env::temp_dir().join(format!("voxhap-cli-solve-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.json");
    std::fs::write(&path, r#"{"k": 500, "probe": [0,0,0], "primitives": [{"type": "plane", "position": [0,0,0], "direction": [0,0,1], "strength": "lots"}]}"#).unwrap();
    let out = voxhap(&["solve", "--scene", path.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("bad.json: primitives[0].strength: invalid type"),
        "{err}"
    );

    let out = voxhap(&[
        "solve",
        "--scene",
        dir.join("missing.json").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr)
        .unwrap()
        .contains("cannot read scene file"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// 3 000 mixed primitives (the issue's scene that did not finish in 60 s): with a small budget `solve` returns
/// promptly with its best answer, its bound and its status.
#[test]
fn solve_never_hangs_and_reports_its_budget_status() {
    use voxhap::haptics::bench_scenes::{random_primitives, SplitMix};
    use voxhap::haptics::PrimitiveKind;
    let mut rng = SplitMix(3000);
    let primitives: Vec<serde_json::Value> = random_primitives(&mut rng, 3000)
        .iter()
        .map(|p| {
            let mut v = serde_json::json!({"type": p.kind().name(), "strength": p.strength_n()});
            if p.kind() != PrimitiveKind::Directed {
                v["position"] = serde_json::json!(p.position_m().to_array());
            }
            if p.kind() != PrimitiveKind::Point {
                v["direction"] = serde_json::json!(p.direction().to_array());
            }
            v
        })
        .collect();
    let scene =
        serde_json::json!({"k": 500.0, "probe": [0.001, -0.002, 0.003], "primitives": primitives});
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mixed.json");
    std::fs::write(&path, scene.to_string()).unwrap();
    let started = std::time::Instant::now();
    let out = voxhap(&[
        "solve",
        "--scene",
        path.to_str().unwrap(),
        "--json",
        "--max-sweeps",
        "3",
        "--budget-ms",
        "50",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        started.elapsed() < std::time::Duration::from_secs(30),
        "took {:?}",
        started.elapsed()
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["sweeps"].as_u64().unwrap() <= 3, "{v}");
    let status = v["status"].as_str().unwrap();
    assert!(status == "budget_exhausted" || status == "certified", "{v}");
    // JSON has no infinity: an infinite bound is printed as null, a finite one must be a number >= 0.
    assert!(v["error_bound"].is_null() || v["error_bound"].as_f64().unwrap() >= 0.0);

    let out = voxhap(&[
        "solve",
        "--scene",
        path.to_str().unwrap(),
        "--max-sweeps",
        "0",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-sweeps"));
}
