//! Recordings checked by independent readers: the `mcap` Python package (`.ci/mcap_scene_check.py`) on the
//! files of every MCAP writer, and the size of a sim's trace against its estimate.

use super::*;

/// Runs `.ci/mcap_scene_check.py` (the `mcap` Python package, an MCAP reader independent of voxhap's;
/// .ci/run installs it) on `path`, expecting `pictures` volume pictures; its JSON report, or `None` (with
/// a visible SKIPPED line naming `test`) without python3 and `mcap`. Panics when the script's checks fail.
pub(crate) fn python_mcap_scene_check(
    test: &str,
    path: &std::path::Path,
    pictures: usize,
) -> Option<serde_json::Value> {
    let has_mcap = Command::new("python3")
        .args(["-c", "import mcap"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !has_mcap {
        // CI (.ci/run) installs it: a missing reader there is a failure, not a skip.
        assert!(
            std::env::var("CI").map_or(true, |ci| ci != "true"),
            "{test}: python3 with the `mcap` package is missing in CI"
        );
        eprintln!(
            "SKIPPED {test}: python3 with the `mcap` package is not available (pip install mcap)"
        );
        return None;
    }
    let root = env!("CARGO_MANIFEST_DIR");
    let script = format!("{root}/.ci/mcap_scene_check.py");
    let layout = format!("{root}/contrib/foxglove/voxhap-layout.json");
    let mut command = Command::new("python3");
    if pictures == 0 {
        command.arg(script).arg("--viewer-only").arg(path);
    } else {
        command
            .arg(script)
            .arg(path)
            .arg(layout)
            .arg(pictures.to_string());
    }
    let output = command.output().unwrap();
    assert!(
        output.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    Some(serde_json::from_slice(&output.stdout).unwrap())
}

/// The scene topics of a recording, read by the `mcap` Python package in `.ci/mcap_scene_check.py`: every
/// topic the shipped layout shows is there, at its rate.
#[test]
fn python_mcap_reads_the_scene_topics_of_a_recorded_session() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.mcap");
    let session = sim_session(Some((path.clone(), TraceFormat::Mcap)));
    std::thread::sleep(Duration::from_millis(2000));
    session.stop();
    let Some(report) = python_mcap_scene_check(
        "python_mcap_reads_the_scene_topics_of_a_recorded_session",
        &path,
        1,
    ) else {
        return;
    };
    // The script's own checks passed; these tie its view to the layout Rust reads.
    let layout: serde_json::Value = serde_json::from_str(SHIPPED_LAYOUT).unwrap();
    for topic in layout_topics(&layout).unwrap() {
        assert!(
            report["counts"][&topic].as_u64().unwrap_or(0) > 0,
            "{topic} not in the recording as Python reads it: {report}"
        );
    }
    // At most 60 Hz of tick time; fewer on a busy machine (the scene follows the servo's snapshots).
    let scene_hz = report["rates_hz"]["/voxhap/primitives"].as_f64().unwrap();
    assert!(scene_hz > 0.0 && scene_hz <= 62.0, "{scene_hz} Hz");
    assert_eq!(
        report["schemas"]["/voxhap/volume"],
        serde_json::json!(["foxglove.SceneUpdate", "protobuf", "protobuf"])
    );
}

/// Every MCAP writer's file opens in Foxglove Studio and Lichtblick as the `mcap` Python package checks it
/// (`.ci/mcap_scene_check.py --viewer-only`: every chunk holds indexed messages, the statistics' start is the
/// first message's log time, every JSON schema passes the viewers' reader): `voxhap sim --out` and `voxhap
/// trace repair` of a file cut mid-way (`serve --record` is checked by the test above). Before the writer fix
/// both failed: the first chunk held no message.
#[test]
fn sim_and_repaired_mcap_files_meet_what_the_foxglove_viewers_need() {
    let test = "sim_and_repaired_mcap_files_meet_what_the_foxglove_viewers_need";
    let dir = tempfile::tempdir().unwrap();
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/sims/sphere_surface.toml");
    let sim = dir.path().join("sim.mcap");
    let out = voxhap(&[
        "sim",
        scenario,
        "--out",
        sim.to_str().unwrap(),
        "--duration",
        "2",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    if python_mcap_scene_check(test, &sim, 0).is_none() {
        return;
    }
    let bytes = std::fs::read(&sim).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let repaired = dir.path().join("repaired.mcap");
    let out = voxhap(&[
        "trace",
        "repair",
        cut.to_str().unwrap(),
        "--out",
        repaired.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report = python_mcap_scene_check(test, &repaired, 0).unwrap();
    assert!(report["chunks"].as_u64().unwrap() >= 1, "{report}");
}

/// A sim's MCAP trace, with its scene topics (the volume picture, slices, scene updates), stays within the
/// size `voxhap sim` estimates before it starts (`--max-trace-bytes` relies on that estimate), at the
/// scenario's rate and at a tenth of it (the slices come per second of tick time, not per tick).
#[test]
fn a_sim_recording_with_its_scene_topics_stays_within_the_size_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/sims/sphere_surface.toml");
    for rate in ["1000", "100"] {
        let path = dir.path().join(format!("sim-{rate}.mcap"));
        let out = voxhap(&[
            "sim",
            scenario,
            "--out",
            path.to_str().unwrap(),
            "--duration",
            "2",
            "--rate",
            rate,
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let rate_hz: f64 = rate.parse().unwrap();
        let estimate = voxhap::record::estimate_trace_bytes(
            TraceFormat::Mcap,
            1,
            (2.0 * rate_hz) as u64,
            rate_hz,
        );
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(
            size <= estimate && size * 2 > estimate / 2,
            "{rate} Hz: {size} bytes written, {estimate} estimated"
        );
        let slices = mcap::Summary::read(&std::fs::read(&path).unwrap())
            .unwrap()
            .unwrap()
            .channels
            .values()
            .filter(|c| c.topic.starts_with("/voxhap/volume/slice_"))
            .count();
        assert_eq!(slices, 3);
    }
}
