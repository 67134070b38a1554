//! A real-time servo session driven through `SessionApi`: commands taken or refused whole, a recording
//! finished on stop, a real device's hand left alone, modes switched off.

use glam::DVec3;
use std::time::Duration;
use voxhap::haptics::modes::{ModeConfig, ModeKind, TransferFunction};
use voxhap::record::{read_trace, TraceFormat};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{ControlCommand, ControlError, Session, SessionApi, SessionConfig, Snapshot};

/// A command the session must refuse, and the error kind it must refuse it with.
type RefusedCase = (ControlCommand, fn(&ControlError) -> bool);

fn session(record: Option<std::path::PathBuf>) -> Session {
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
    config.rt = voxhap::servo::rt::RtMode::Off;
    config.record = record.map(|p| (p, TraceFormat::Csv));
    Session::start(config).unwrap()
}

fn wait_for_tick(api: &dyn SessionApi, tick: u64) -> Snapshot {
    for _ in 0..500 {
        if let Some(s) = api.snapshot() {
            if s.tick >= tick {
                return s;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    panic!("the servo never reached tick {tick}");
}

#[test]
fn a_session_takes_valid_commands_and_refuses_bad_ones_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let session = session(None);
    let api = session.api();
    wait_for_tick(&*api, 50);

    let reply = api
        .control(ControlCommand::SetStiffness { k: 350.0 })
        .unwrap();
    let snapshot = api.snapshot().unwrap();
    assert_eq!(
        snapshot.stiffness_n_per_m, 350.0,
        "applied before the reply"
    );
    assert_eq!(snapshot.scene_generation, reply.scene_generation);

    let before = (api.scene(), api.snapshot().unwrap().scene_generation);
    let refused: Vec<RefusedCase> = vec![
        (ControlCommand::SetStiffness { k: -1.0 }, |e| {
            matches!(e, ControlError::Invalid(_))
        }),
        (ControlCommand::SetStiffness { k: f64::INFINITY }, |e| {
            matches!(e, ControlError::Invalid(_))
        }),
        (ControlCommand::SetStiffness { k: 1e9 }, |e| {
            matches!(e, ControlError::Invalid(_))
        }),
        (ControlCommand::SetDamping { damping: -0.1 }, |e| {
            matches!(e, ControlError::Invalid(_))
        }),
        (
            ControlCommand::SetDamping { damping: 1e6 },
            |e| matches!(e, ControlError::Invalid(m) if m.contains("damping must be at most")),
        ),
        (
            ControlCommand::RemoveMode {
                name: "nope".into(),
            },
            |e| matches!(e, ControlError::NotFound(_)),
        ),
        (
            ControlCommand::LoadVolume {
                path: dir.path().join("missing.nii"),
                name: None,
            },
            |e| matches!(e, ControlError::NotFound(_)),
        ),
        (
            ControlCommand::LoadVolume {
                path: "builtin:nope".into(),
                name: None,
            },
            |e| matches!(e, ControlError::Invalid(_)),
        ),
        (
            ControlCommand::LoadVolume {
                path: "builtin:sphere".into(),
                name: Some("nope".into()),
            },
            |e| matches!(e, ControlError::NotFound(m) if m.contains("no volume named \"nope\"")),
        ),
        (
            ControlCommand::AddMode {
                mode: ModeConfig {
                    volume: Some("nope".into()),
                    ..ModeConfig::new(ModeKind::Surface)
                },
            },
            |e| matches!(e, ControlError::Invalid(_)),
        ),
        (ControlCommand::StopRecording, |e| {
            matches!(e, ControlError::Conflict(_))
        }),
        (
            ControlCommand::SetHandTarget {
                position_m: Some([f64::NAN, 0.0, 0.0]),
            },
            |e| matches!(e, ControlError::Invalid(_)),
        ),
    ];
    for (command, expected) in refused {
        let error = api
            .control(command.clone())
            .expect_err(&format!("{command:?} accepted"));
        assert!(expected(&error), "{command:?}: {error}");
        assert!(!error.to_string().is_empty());
    }
    assert_eq!(api.scene(), before.0, "a refused command changed the scene");
    assert_eq!(api.snapshot().unwrap().scene_generation, before.1);

    // Remove a mode, change a transfer function, move the hand, record a while.
    api.control(ControlCommand::RemoveMode {
        name: "viscosity".into(),
    })
    .unwrap();
    assert_eq!(api.scene().modes.len(), 2);
    let transfer = TransferFunction::new(vec![[0.45, 0.0], [0.5, 1.0]]).unwrap();
    api.control(ControlCommand::SetTransfer {
        mode: "surface".into(),
        transfer: transfer.clone(),
    })
    .unwrap();
    assert_eq!(api.scene().modes[0].transfer, Some(transfer));
    api.control(ControlCommand::SetHandTarget {
        position_m: Some([0.0, 0.0, 0.05]),
    })
    .unwrap();
    let trace = dir.path().join("session.csv");
    api.control(ControlCommand::StartRecording {
        path: trace.clone(),
        format: None,
    })
    .unwrap();
    let conflict = api.control(ControlCommand::AddMode {
        mode: ModeConfig::new(ModeKind::Surface),
    });
    assert!(
        matches!(conflict, Err(ControlError::Conflict(_))),
        "{conflict:?}"
    );
    let start = api.snapshot().unwrap().tick;
    wait_for_tick(&*api, start + 300);
    let reply = api.control(ControlCommand::StopRecording).unwrap();
    assert!(reply.message.contains("samples"), "{}", reply.message);
    // A built-in volume loads like a file (as `--volume builtin:NAME` does).
    api.control(ControlCommand::LoadVolume {
        path: "builtin:shells".into(),
        name: Some("density".into()),
    })
    .unwrap();
    let density = api
        .scene()
        .volumes
        .into_iter()
        .find(|v| v.name == "density");
    assert_eq!(density.map(|v| v.source), Some("builtin:shells".to_owned()));
    let summary = session.stop();
    let trace = read_trace(&trace).unwrap();
    assert!(
        trace.samples.len() >= 250,
        "{} samples",
        trace.samples.len()
    );
    assert!(trace.samples.windows(2).all(|w| w[0].tick < w[1].tick));
    assert_eq!(trace.mode_names, vec!["surface", "vector_follow"]);
    // The hand holds the arm 5 cm up, above the ball: no contact force at the end.
    let last = trace.samples.last().unwrap();
    assert!(
        (last.probe_m - DVec3::new(0.0, 0.0, 0.05)).length() < 0.01,
        "{:?}",
        last.probe_m
    );
    assert!(summary.stats.ticks > 300);
    assert_eq!(summary.stats.recorder_drops, 0);
}

#[test]
fn stopping_a_session_finishes_its_recording() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.csv");
    let session = session(Some(path.clone()));
    wait_for_tick(&*session.api(), 200);
    let summary = session.stop();
    let trace = summary.trace.expect("the trace was finished on stop");
    assert_eq!(trace.trace_path, path);
    let read = read_trace(&path).unwrap();
    assert_eq!(read.samples.len() as u64, trace.sample_count);
    assert_eq!(read.samples[0].tick, 0);
    assert!(summary.stats.ticks >= trace.sample_count);
    assert!(read
        .samples
        .iter()
        .all(|s| s.sent_force_n.is_finite() && s.sent_force_n.length() <= 10.0));
}

#[test]
fn the_hand_of_a_real_device_cannot_be_moved() {
    // A replay device stands in for hardware: record a short session, then replay it.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.csv");
    let recorded = session(Some(path.clone()));
    wait_for_tick(&*recorded.api(), 100);
    recorded.stop();
    let mut config = SessionConfig::new(
        DeviceSpec::Replay {
            path,
            options: Default::default(),
        },
        SceneSetup::builtin().unwrap(),
    );
    config.rt = voxhap::servo::rt::RtMode::Off;
    let replay = Session::start(config).unwrap();
    let api = replay.api();
    assert!(!api.scene().simulated);
    let error = api
        .control(ControlCommand::SetHandTarget {
            position_m: Some([0.0, 0.0, 0.05]),
        })
        .expect_err("a hand target for a replayed device");
    assert!(matches!(error, ControlError::Conflict(_)), "{error}");
    assert_eq!(error.http_status(), 409, "what /api/hand answers");
    replay.stop();
}

/// The largest strength (N) among the primitives the servo emitted this tick.
fn strongest_primitive_n(snapshot: &Snapshot) -> f64 {
    snapshot.primitive_slots[..usize::from(snapshot.primitive_count)]
        .iter()
        .flatten()
        .map(|p| p.strength_n)
        .fold(0.0, f64::max)
}

#[test]
fn switching_modes_off_renders_nothing_and_keeps_their_breakpoints() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("switched.csv");
    let session = session(Some(trace.clone()));
    let api = session.api();
    // Hold the simulated hand 2 mm inside the density ball's surface (radius 3 cm), where the surface mode's
    // plane holds the proxy (viscosity emits no primitive: it is a damper on the proxy's motion).
    api.control(ControlCommand::SetHandTarget {
        position_m: Some([0.028, 0.0, 0.0]),
    })
    .unwrap();
    let start = api.snapshot().map_or(0, |s| s.tick);
    let on = wait_for_tick(&*api, start + 500);
    assert!(
        strongest_primitive_n(&on) > 0.1,
        "nothing pushes inside the surface: {on:?}"
    );
    let scene_before = api.scene();

    // Allowed while recording: the trace keeps its columns.
    let names: Vec<String> = scene_before
        .modes
        .iter()
        .map(|m| m.display_name().to_owned())
        .collect();
    for name in &names {
        let reply = api
            .control(ControlCommand::SetModeEnabled {
                mode: name.clone(),
                enabled: false,
            })
            .unwrap();
        assert!(reply.message.contains("off"), "{}", reply.message);
    }
    let off = wait_for_tick(&*api, api.snapshot().unwrap().tick + 300);
    assert_eq!(strongest_primitive_n(&off), 0.0, "{off:?}");
    assert!(
        off.rendered_force_n.length() < 0.05,
        "switched-off modes still push: {} N",
        off.rendered_force_n
    );
    let scene_off = api.scene();
    for (before, now) in scene_before.modes.iter().zip(&scene_off.modes) {
        assert!(!now.is_enabled());
        assert_eq!(before.transfer, now.transfer, "breakpoints lost");
    }

    for name in &names {
        api.control(ControlCommand::SetModeEnabled {
            mode: name.clone(),
            enabled: true,
        })
        .unwrap();
    }
    assert_eq!(
        api.scene().modes,
        scene_before.modes,
        "not restored as it was"
    );
    let again = wait_for_tick(&*api, api.snapshot().unwrap().tick + 300);
    assert!(strongest_primitive_n(&again) > 0.1, "{again:?}");

    let error = api
        .control(ControlCommand::SetModeEnabled {
            mode: "nonesuch".into(),
            enabled: false,
        })
        .expect_err("an unknown mode");
    assert!(matches!(error, ControlError::NotFound(_)), "{error}");
    let summary = session.stop();
    assert!(summary.trace.is_some(), "the recording did not survive");
    assert_eq!(summary.recorder_error, None);
    assert!(std::fs::metadata(&trace).unwrap().len() > 0);
}
