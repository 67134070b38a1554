//! What the server sends and accepts: the tracking stream in RAS millimetres with valid CRCs and the force in
//! newtons, an IMAGE that needs the token and replaces the first volume, a protocol-3 probe target moving the
//! hand, and `serve` running the server without HTTP.

use crate::util::igtl_client::{
    image_content, pack, read, status, string_content, transform_content, translation_mm, Fixture,
    TOKEN,
};
use glam::DVec3;
use std::io::Write;
use std::time::{Duration, Instant};
use voxhap::servo::{ControlCommand, SessionApi};

#[test]
fn the_stream_carries_ras_millimetres_with_valid_crcs_and_the_force_in_newtons() {
    let fixture = Fixture::start();
    // Hold the simulated hand still so the probe can be compared with the session's own state.
    fixture
        .api
        .control(ControlCommand::SetHandTarget {
            position_m: Some([0.0, 0.0, 0.08]),
        })
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let mut stream = fixture.connect();
    let first = read(&mut stream);
    assert_eq!(
        (first.kind.as_str(), first.device.as_str()),
        ("STATUS", "voxhap")
    );
    let mut devices = Vec::new();
    let mut probe = None;
    let mut force = None;
    while devices.len() < 40 {
        let message = read(&mut stream);
        assert_eq!(
            message.version, 1,
            "header version 1 until the client speaks 2"
        );
        if message.kind != "TRANSFORM" {
            continue;
        }
        match message.device.as_str() {
            "Probe" => probe = Some(translation_mm(&message.content)),
            "Force" => force = Some(translation_mm(&message.content)),
            _ => {}
        }
        devices.push(message.device);
    }
    for name in ["Probe", "Proxy", "ProbeVelocity", "Force"] {
        assert!(
            devices.iter().any(|d| d == name),
            "{name} missing: {devices:?}"
        );
    }
    let snapshot = fixture.api.snapshot().unwrap();
    let probe = probe.unwrap();
    assert!(
        (probe - snapshot.probe_m * 1000.0).length() < 0.5,
        "IGTL probe {probe} mm, session {} m",
        snapshot.probe_m
    );
    assert!(
        (probe - DVec3::new(0.0, 0.0, 80.0)).length() < 5.0,
        "{probe}"
    );
    let force = force.unwrap();
    assert!(
        (force - snapshot.sent_force_n).length() < 0.05,
        "IGTL force {force} N, session {} N",
        snapshot.sent_force_n
    );
}

#[test]
fn an_image_needs_the_token_and_then_replaces_the_first_volume() {
    let fixture = Fixture::start();
    let mut stream = fixture.connect();
    let before = fixture.api.scene().volumes[0].clone();
    let image = pack(1, "IMAGE", "CT", &image_content([10.0, 0.0, 0.0], 0), &[]);
    stream.write_all(&image).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 5, "{message}");
    assert!(message.contains("token"), "{message}");
    assert_eq!(fixture.api.scene().volumes[0], before);

    // A corrupted CRC is answered with 9 and the connection goes on.
    let mut corrupt = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    let last = corrupt.len() - 1;
    corrupt[last] ^= 0x20;
    stream.write_all(&corrupt).unwrap();
    assert_eq!(status(&mut stream, "Login").0, 9);

    let login = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    stream.write_all(&login).unwrap();
    assert_eq!(status(&mut stream, "Login").0, 1);
    stream.write_all(&image).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 1, "{message}");
    let volume = fixture.api.scene().volumes[0].clone();
    assert_eq!(volume.dims, [16, 12, 8]);
    // Centre (10, 0, 0) mm, 2 mm voxels: voxel 0 at centre - 2 mm x (15, 11, 7) / 2.
    let expected_min = DVec3::new(-5.0, -11.0, -7.0) / 1000.0;
    assert!(
        (volume.min_m - expected_min).length() < 1e-9,
        "{}",
        volume.min_m
    );
    assert!((volume.max_m - DVec3::new(25.0, 11.0, 7.0) / 1000.0).length() < 1e-9);
    // Values 0 to 99 hold the built-in surface's 0.45 .. 0.5 ramp: its transfer is kept.
    assert!(!message.contains("transfer"), "{message}");
    let transfer = |api: &voxhap::servo::SessionShared| {
        let scene = api.scene();
        let surface = scene
            .modes
            .iter()
            .find(|m| m.display_name() == "surface")
            .unwrap();
        surface.transfer.as_ref().unwrap().points().to_vec()
    };
    assert_eq!(transfer(&fixture.api), vec![[0.45, 0.0], [0.5, 2.0]]);
    // Values 1000 to 1099 do not: the surface is fitted to them (0 N at 45 %, 2 N at 50 % of the range).
    let shifted = pack(
        1,
        "IMAGE",
        "CT",
        &image_content([10.0, 0.0, 0.0], 1000),
        &[],
    );
    stream.write_all(&shifted).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 1, "{message}");
    assert!(message.contains("did not fit"), "{message}");
    assert_eq!(transfer(&fixture.api), vec![[1044.55, 0.0], [1049.5, 2.0]]);
}

/// An IMAGE whose metadata `volume` names no volume of the scene is answered with STATUS 4 (not found, the
/// OpenIGTLink STATUS code table) naming the volumes there are, and nothing is loaded (docs/slicer.md lists it).
#[test]
fn an_image_for_a_volume_the_scene_lacks_is_answered_with_status_4() {
    let fixture = Fixture::start();
    let mut stream = fixture.connect();
    let before = fixture.api.scene().volumes.clone();
    let image = pack(
        2,
        "IMAGE",
        "CT",
        &image_content([10.0, 0.0, 0.0], 0),
        &[("token", TOKEN), ("volume", "nothing")],
    );
    stream.write_all(&image).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 4, "{message}");
    assert!(message.contains("nothing"), "{message}");
    assert_eq!(fixture.api.scene().volumes, before);
}

#[test]
fn a_protocol_3_probe_target_with_a_metadata_token_moves_the_hand() {
    let fixture = Fixture::start();
    let mut stream = fixture.connect();
    let target = pack(
        2,
        "TRANSFORM",
        "ProbeTarget",
        &transform_content([5.0, -10.0, 60.0]),
        &[],
    );
    stream.write_all(&target).unwrap();
    assert_eq!(status(&mut stream, "ProbeTarget").0, 5);
    assert_eq!(fixture.api.snapshot().unwrap().hand_target_m, None);
    let target = pack(
        2,
        "TRANSFORM",
        "ProbeTarget",
        &transform_content([5.0, -10.0, 60.0]),
        &[("token", TOKEN)],
    );
    stream.write_all(&target).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let hand = fixture.api.snapshot().unwrap().hand_target_m;
        if let Some(hand) = hand {
            assert!(
                (hand - DVec3::new(0.005, -0.010, 0.060)).length() < 1e-6,
                "{hand}"
            );
            break;
        }
        assert!(Instant::now() < deadline, "the hand target was never set");
        std::thread::sleep(Duration::from_millis(10));
    }
    // The stream now comes in header version 2.
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let message = read(&mut stream);
        if message.kind == "TRANSFORM" && message.version == 2 {
            assert_eq!(message.content.len(), 48);
            break;
        }
        assert!(Instant::now() < deadline, "no version-2 stream");
    }
}

/// `voxhap serve --igtl` without the HTTP server: `--token` is accepted and the token in use is printed.
#[test]
fn serve_runs_the_igtl_server_without_http_and_prints_its_token() {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "serve",
            "--igtl",
            "127.0.0.1:0",
            "--no-http",
            "--no-foxglove",
            "--token",
            "given-token-123",
            "--duration",
            "0.5",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("igtl: listening on 127.0.0.1:"), "{stdout}");
    assert!(
        stdout
            .lines()
            .any(|l| l == "igtl: control token given-token-123"),
        "{stdout}"
    );
    assert!(!stdout.contains("http: listening"), "{stdout}");
    // A remote address needs --igtl-allow-remote, and nothing starts without it.
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "serve",
            "--igtl",
            "0.0.0.0:0",
            "--no-http",
            "--no-foxglove",
            "--duration",
            "0.5",
        ])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--igtl-allow-remote"));
}
