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

/// `docs/solve.md`'s Output block with the figures that vary from run to run (time, gap, bound) left out.
fn masked(text: &str) -> Vec<String> {
    text.lines()
        .map(|line| match line.split_once(' ') {
            Some((key @ ("time" | "gap" | "error"), _)) => key.to_owned(),
            _ => line.to_owned(),
        })
        .collect()
}

#[test]
fn solve_prints_the_text_report_docs_solve_md_shows() {
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/solve.md")).unwrap();
    let block = doc
        .split("## Output\n\n```\n")
        .nth(1)
        .and_then(|rest| rest.split("\n```").next())
        .expect("docs/solve.md has an Output block");
    let out = voxhap(&["solve", "--scene", &example()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(masked(&text), masked(block));
    assert!(text.trim_end().ends_with("m (certified)"), "{text}");
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

/// 3 000 mixed primitives (a scene that takes far longer than a budget to solve fully): with a small budget `solve` returns
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

/// A scene file of `primitives` (the documented schema), with an optional previous proxy.
fn scene_json(
    k: f64,
    probe: glam::DVec3,
    previous: Option<glam::DVec3>,
    primitives: &[voxhap::haptics::Primitive],
) -> String {
    use voxhap::haptics::PrimitiveKind;
    let primitives: Vec<serde_json::Value> = primitives
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
    let mut scene =
        serde_json::json!({"k": k, "probe": probe.to_array(), "primitives": primitives});
    if let Some(previous) = previous {
        scene["previous_proxy"] = serde_json::json!(previous.to_array());
    }
    scene.to_string()
}

/// On 10 000 mixed primitives (the benchmark's scene) the start (`y`, the probe plus the directed forces over
/// k) is 0.32 m from the answer; a budget-cut solve that returns its last iterate can be far worse (a proxy
/// 7.2 m away with 3.6 kN after `--max-sweeps 2`). Every budget-cut answer has at most the start's energy
/// (computed here from the primitives' energy terms, crates/solver/src/primitive.rs) and a bound that holds against
/// the double-double reference minimiser.
#[test]
fn a_budget_cut_solve_returns_no_worse_a_point_than_its_start() {
    use voxhap::haptics::primitive::total_energy_j;
    use voxhap::haptics::PrimitiveKind;
    let k = 500.0;
    let (probe, primitives) = voxhap::haptics::bench_scenes::random_scene(10_000, 10_000);
    let directed: glam::DVec3 = primitives
        .iter()
        .filter(|p| p.kind() == PrimitiveKind::Directed)
        .map(|p| p.strength_n() * p.direction())
        .sum();
    let y = probe + directed / k;
    let previous = probe + glam::DVec3::new(-0.004, 0.001, 0.002);
    let reference = voxhap::haptics::reference::minimise(k, probe, &primitives);
    let dir = tempfile::tempdir().unwrap();
    for (previous_proxy, start) in [(None, y), (Some(previous), previous)] {
        let path = dir.path().join("mixed10000.json");
        std::fs::write(&path, scene_json(k, probe, previous_proxy, &primitives)).unwrap();
        for budget in [
            ["--max-sweeps", "1"],
            ["--max-sweeps", "2"],
            ["--max-sweeps", "3"],
            ["--budget-ms", "0.5"],
            ["--budget-ms", "0.05"],
        ] {
            let mut args = vec!["solve", "--scene", path.to_str().unwrap(), "--json"];
            args.extend(budget);
            let out = voxhap(&args);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let proxy: [f64; 3] = serde_json::from_value(v["proxy"].clone()).unwrap();
            let force: [f64; 3] = serde_json::from_value(v["force"].clone()).unwrap();
            let proxy = glam::DVec3::from_array(proxy);
            let e_start = total_energy_j(k, probe, &primitives, start);
            let e_answer = total_energy_j(k, probe, &primitives, proxy);
            assert!(
                e_answer <= e_start + 1e-9 * e_start.abs().max(1.0),
                "{budget:?}, start {start:?}: energy {e_answer} J > {e_start} J at the start: {v}"
            );
            let bound = v["error_bound"].as_f64().expect("a finite bound");
            let error = reference.distance_m(proxy);
            assert!(
                error <= bound + reference.error_bound_m,
                "{budget:?}: true error {error:e} m > bound {bound:e} m: {v}"
            );
            let coupling = k * (proxy - probe);
            assert!(
                (glam::DVec3::from_array(force) - coupling).length()
                    <= 1e-9 * (1.0 + coupling.length()),
                "{v}"
            );
        }
    }
}

/// Finite values that overflow the energy or the force (a stiffness, a probe, a strength of 1e300) are refused
/// with the file, the field, the value and the range; values at the range's ends are accepted.
#[test]
fn degenerate_scene_values_are_refused_with_the_field_and_the_range() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.json");
    let cases = [
        (
            r#"{"k": 1e300, "probe": [0, 0, 0], "primitives": []}"#,
            "scene.json: k: 1e300 N/m is out of range: give a number from 0.001 to 10000000 N/m",
        ),
        (
            r#"{"k": 1e-300, "probe": [0, 0, 0], "primitives": []}"#,
            "scene.json: k: 1e-300 N/m is out of range",
        ),
        (
            r#"{"k": 500, "probe": [0, 0, 0], "previous_proxy": [0, -2000, 0], "primitives": []}"#,
            "scene.json: previous_proxy: [0.0, -2000.0, 0.0] is out of range: each of x, y, z must be from -1000 to 1000 m",
        ),
        (
            r#"{"k": 500, "probe": [0, 0, 0], "primitives": [{"type": "plane", "position": [0, 0, 1e300], "direction": [0, 0, 1], "strength": 1}]}"#,
            "scene.json: primitives[0].position: [0.0, 0.0, 1e300] is out of range",
        ),
        (
            r#"{"k": 500, "probe": [0, 0, 0], "primitives": [{"type": "directed", "direction": [0, 0, 1], "strength": 1e300}]}"#,
            "scene.json: primitives[0].strength: 1e300 N is out of range: give a number from 0 to 1000000 N",
        ),
    ];
    for (scene, expected) in cases {
        std::fs::write(&path, scene).unwrap();
        let out = voxhap(&["solve", "--scene", path.to_str().unwrap(), "--json"]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{scene}: {stderr}");
        assert!(stderr.contains(expected), "{scene}: {stderr}");
    }
    // The ends of the ranges are accepted and solve to finite numbers.
    std::fs::write(
        &path,
        r#"{"k": 10000000, "probe": [1000, -1000, 1000], "previous_proxy": [-1000, 1000, -1000], "primitives": [{"type": "point", "position": [1000, 1000, -1000], "strength": 1000000}, {"type": "directed", "direction": [1, 0, 0], "strength": 1000000}]}"#,
    )
    .unwrap();
    let out = voxhap(&["solve", "--scene", path.to_str().unwrap(), "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let force: [f64; 3] = serde_json::from_value(v["force"].clone()).unwrap();
    assert!(force.iter().all(|f| f.is_finite()), "{v}");
}
