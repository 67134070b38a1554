//! Replay through the real binary: `voxhap serve --device replay:TRACE` plays a trace once by default and
//! says so on stderr when it reaches the end.

use std::process::Command;

fn voxhap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
}

/// Runs `voxhap serve --device DEVICE` on the sphere scene for `seconds`, with no servers; its stderr.
fn serve(device: &str, seconds: &str) -> String {
    let output = voxhap()
        .args([
            "serve",
            "--device",
            device,
            "--scene",
            "sims/sphere_surface.toml",
        ])
        .args(["--no-http", "--no-foxglove", "--duration", seconds])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "{stderr}");
    stderr
}

#[test]
fn a_play_once_replay_says_where_the_trace_ended_and_how_to_repeat_it() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("short.csv");
    let recorded = voxhap()
        .args([
            "sim",
            "sims/sphere_surface.toml",
            "--duration",
            "0.3",
            "--out",
        ])
        .arg(&trace)
        .output()
        .unwrap();
    assert!(
        recorded.status.success(),
        "{}",
        String::from_utf8_lossy(&recorded.stderr)
    );
    let device = format!("replay:{}", trace.display());
    let stderr = serve(&device, "2");
    let expected = format!(
        "replay: end of {} after 300 samples (0.299 s); holding the last position; use --device {device},loop to repeat",
        trace.display()
    );
    assert_eq!(
        stderr.matches(&expected).count(),
        1,
        "once, at the end: {stderr}"
    );
    // A looping replay never ends, so it never says so.
    let stderr = serve(&format!("{device},loop"), "1");
    assert!(!stderr.contains("replay: end of"), "{stderr}");
}
