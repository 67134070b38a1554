//! Workspace mapping, device profiles and `voxhap calibrate`, through the real binary: calibration against
//! the simulated arm and against `voxhap mock-device` on a pseudo-terminal (the voxhap protocol), the
//! never-overwrite rule, and `serve --device-profile` / `--fit-volume` / a scene's `[device]` table.

use crate::util::mock_process::MockProcess;
use std::process::{Command, Output};
use voxhap::device::profile::DeviceProfile;

fn voxhap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .expect("run voxhap")
}

/// `voxhap serve` for 0.3 s without servers, with `args`.
fn serve(args: &[&str]) -> Output {
    let mut all = vec!["serve", "--no-http", "--no-foxglove", "--duration", "0.3"];
    all.extend_from_slice(args);
    voxhap(&all)
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

#[test]
fn calibrate_on_the_simulated_arm_writes_a_profile_and_never_overwrites_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("arm.toml");
    let out_str = out.to_str().unwrap();
    let run = voxhap(&[
        "calibrate",
        "--device",
        "sim",
        "--out",
        out_str,
        "--seconds",
        "1",
    ]);
    assert!(run.status.success(), "{}", text(&run));
    let profile = DeviceProfile::read(&out).unwrap();
    let (min, max) = profile.workspace_m.expect("a measured box");
    // The simulated hand circles: the box has extent in x and y.
    assert!(
        max.x - min.x > 0.005 && max.y - min.y > 0.005,
        "{min} {max}"
    );
    // A second run without --force refuses and leaves the file as it was.
    let before = std::fs::read(&out).unwrap();
    let again = voxhap(&[
        "calibrate",
        "--device",
        "sim",
        "--out",
        out_str,
        "--seconds",
        "0.2",
    ]);
    assert_eq!(again.status.code(), Some(1), "{}", text(&again));
    assert!(text(&again).contains("--force"), "{}", text(&again));
    assert_eq!(std::fs::read(&out).unwrap(), before);
    // With --force it is replaced.
    let forced = voxhap(&[
        "calibrate",
        "--device",
        "sim",
        "--out",
        out_str,
        "--seconds",
        "0.5",
        "--force",
        "--name",
        "again",
    ]);
    assert!(forced.status.success(), "{}", text(&forced));
    assert_eq!(DeviceProfile::read(&out).unwrap().name, "again");
}

#[test]
fn calibrate_against_the_mock_device_on_a_pseudo_terminal() {
    let mock = MockProcess::start(&["--pty"]);
    let path = mock.path.clone();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mock.toml");
    let run = voxhap(&[
        "calibrate",
        "--device",
        &format!("mock:{path}"),
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "1.5",
    ]);
    drop(mock);
    assert!(run.status.success(), "{}", text(&run));
    let profile = DeviceProfile::read(&out).unwrap();
    assert_eq!(profile.device.as_deref(), Some("mock"));
    let (min, max) = profile.workspace_m.unwrap();
    assert!((max - min).max_element() > 0.0, "{min} {max}");
}

#[test]
fn serve_applies_a_profile_fits_the_volume_and_names_bad_keys() {
    let fitted = serve(&[
        "--device-profile",
        "sim",
        "--fit-volume",
        "--volume",
        "builtin:sphere",
    ]);
    assert!(fitted.status.success(), "{}", text(&fitted));
    assert!(
        text(&fitted).contains("notice: device profile sim: scene = "),
        "{}",
        text(&fitted)
    );

    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[limits]\nmax_force_n = -2\n").unwrap();
    let refused = serve(&["--device-profile", bad.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(
        text(&refused).contains("limits.max_force_n: -2 must be finite and > 0"),
        "{}",
        text(&refused)
    );

    // A scene's [device] table, with a key that does not exist.
    let scene = dir.path().join("scene.toml");
    let builtin = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/sims/scenes/explore.toml"
    ))
    .unwrap();
    std::fs::write(
        &scene,
        format!("{builtin}\n[device]\n[device.mapping]\nscael = 2\n"),
    )
    .unwrap();
    let refused = serve(&["--scene", scene.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(1), "{}", text(&refused));
    assert!(
        text(&refused).contains("[device]: mapping.scael"),
        "{}",
        text(&refused)
    );
    std::fs::write(
        &scene,
        format!("{builtin}\n[device]\n[device.mapping]\nscale = 2\n"),
    )
    .unwrap();
    let served = serve(&["--scene", scene.to_str().unwrap()]);
    assert!(served.status.success(), "{}", text(&served));
    assert!(
        text(&served).contains("scene = 2.0000 x R x device"),
        "{}",
        text(&served)
    );
}
