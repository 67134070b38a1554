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

/// A replay ends with its probe held still at the last sample. Replaying `sims/friction_sliding.toml` stopped
/// mid-slide (2 s in) does that while the proxy slides: friction holds it a fraction of a nanometre from where
/// the pull just equals mu N, where the solver used to end every tick after the end `Stalled` (952 of 2957 ticks of
/// `serve --device replay:...`). The replay device's positions through the tick (untimed, so the solver stops on
/// its sweep budget only and the result does not depend on this machine's load): every tick, through the end
/// and a second held after it, is certified within the scene's solver tolerance.
#[test]
fn every_tick_of_a_replay_is_certified_through_its_end() {
    use voxhap::device::HapticDevice;
    use voxhap::haptics::tick::{tick, TickState, TickStatus, TickWorkspace};
    let dir = tempfile::tempdir().unwrap();
    let trace_path = dir.path().join("friction.csv");
    let scene = "sims/friction_sliding.toml";
    let recorded = voxhap()
        .args(["sim", scene, "--duration", "2", "--out"])
        .arg(&trace_path)
        .output()
        .unwrap();
    assert!(
        recorded.status.success(),
        "{}",
        String::from_utf8_lossy(&recorded.stderr)
    );
    let trace = voxhap::record::read_trace(&trace_path).unwrap();
    let samples = trace.samples.len();
    assert_eq!(samples, 2000);
    let mut replay = voxhap::servo::device::ReplayDevice::new(&trace, false).unwrap();
    replay.open().unwrap();
    let setup = voxhap::servo::setup::SceneSetup::read(std::path::Path::new(scene)).unwrap();
    let render = setup.build_scene().unwrap();
    let config = setup.solver_config(1_000_000, 0.3);
    let mut workspace = TickWorkspace::new(&render, setup.solver_kind(), config);
    let mut state = TickState::new(replay.read_state().unwrap().position_m);
    let mut held_still_in_contact = 0;
    for i in 0..samples + 1000 {
        let probe = replay.read_state().unwrap().position_m;
        let out = tick(&mut state, &render, probe, 1e-3, &mut workspace);
        assert!(
            out.status == TickStatus::Certified && out.error_bound_m <= config.tolerance_m,
            "tick {i} of {samples} replayed: {:?}, bound {:e} m, {} sweeps",
            out.status,
            out.error_bound_m,
            out.sweeps
        );
        if i >= samples && out.modes.primitives()[1] > 0 {
            held_still_in_contact += 1;
        }
    }
    // The case this is about: the probe held at the end is on the ball, with friction acting.
    assert!(held_still_in_contact >= 999, "{held_still_in_contact}");
}
