//! Tests of [`super`].

use super::*;
use ::foxglove::Decode;

#[test]
fn a_recording_of_a_builtin_sphere_gets_its_bounds_and_a_mesh_at_the_surface_threshold() {
    let mut meta = crate::test_support::meta(&["surface"]);
    meta.volume = "builtin:sphere".to_owned();
    meta.scenario = serde_json::json!({
        "modes": [{"kind": "surface", "volume": "v", "transfer": [[0.45, 0.0], [0.55, 2.0]]}]
    });
    let picture = RecordedVolume::from_meta(&meta).expect("a picture");
    assert!(
        picture.min_m.x < -0.03 && picture.max_m.x > 0.03,
        "{picture:?}"
    );
    let (mesh, colour, iso) = picture.surface.expect("a surface mesh");
    assert!((iso - 0.5).abs() < 1e-12);
    assert_eq!(colour, palette().mode(0));
    assert!(!mesh.triangles.is_empty() && mesh.triangles.len() <= RECORDED_MAX_TRIANGLES);
    // The half-density shell of the radius-3 cm ball.
    for v in &mesh.vertices {
        assert!(
            (v.length() - 0.03).abs() < 0.003,
            "vertex at {} m",
            v.length()
        );
    }
    meta.volume = "procedural:sphere, /no/such/file.nii".to_owned();
    assert_eq!(RecordedVolume::from_meta(&meta), None);
}

/// A one-mode sample of tick `tick` at 1 kHz.
fn sample_at(tick: u64) -> crate::TraceSample {
    let mut sample = crate::TraceSample::zeroed(1);
    sample.tick = tick;
    sample.t_s = tick as f64 * 1e-3;
    sample
}

/// Writes 3 s of 1 kHz samples through a [`RecordedScene`], with the servo's snapshots every 17th tick
/// for the first second only; returns how many messages each channel got and the last statistics.
fn record_with_frames_for_one_second() -> (RecordedScene, Vec<u16>, serde_json::Value) {
    let mut meta = crate::test_support::meta(&["surface"]);
    meta.volume = "builtin:sphere".to_owned();
    let mut writer = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
    let mut scene = RecordedScene::add(&mut writer, &meta).unwrap();
    let mut channels = Vec::new();
    let mut last_stats = serde_json::Value::Null;
    let every = scene_frame_interval_ticks(1_000_000);
    for tick in 0..3000u64 {
        let sample = sample_at(tick);
        let frame = Snapshot {
            tick,
            t_s: sample.t_s,
            connected: true,
            engaged: true,
            ..Snapshot::example()
        };
        let frame = (tick < 1000 && tick % every == 0).then_some(&frame);
        let stats_channel = scene.stats;
        scene
            .write(&sample, frame, tick * 1_000_000, &mut |channel, encode| {
                let mut bytes = Vec::new();
                encode(&mut bytes).unwrap();
                if channel == stats_channel {
                    last_stats = serde_json::from_slice(&bytes).unwrap();
                }
                channels.push(channel);
                Ok(())
            })
            .unwrap();
    }
    (scene, channels, last_stats)
}

#[test]
fn snapshots_drive_the_scene_updates_and_missing_ones_are_drawn_from_samples_and_counted() {
    let (scene, channels, stats) = record_with_frames_for_one_second();
    let count = |channel: u16| channels.iter().filter(|&&c| c == channel).count();
    // 59 snapshots in the first second (ticks 0, 17, ..., 986); then none: one update per 3 intervals
    // (50 ms) from the samples, 40 in the last two seconds.
    assert_eq!(count(scene.primitives), 59 + 40);
    assert_eq!(count(scene.bound), count(scene.primitives));
    assert_eq!(count(scene.operating_state), count(scene.primitives));
    // The last statistics (at 2 s) count the 20 updates drawn from samples by then (ticks 1036 ..= 1986).
    assert_eq!(stats["t_s"], 2.0);
    assert_eq!(stats["scene_frames_missing"], 20, "{stats}");
    // Slices every 0.25 s, the volume picture once, statistics once a second (at 1 s and 2 s).
    for channel in scene.slices {
        assert_eq!(count(channel), 12);
    }
    assert_eq!(count(scene.volume), 1);
    assert_eq!(
        count(scene.volume_frame),
        2,
        "frames volume and volume_view"
    );
    assert_eq!(count(scene.stats), 2);
}

/// A scene change while recording: the new volume's picture and frames are written with the first
/// snapshot of the new generation, slices switch to it, and an unchanged scene draws nothing.
#[test]
fn a_scene_change_redraws_the_volume_with_the_first_snapshot_of_its_generation() {
    use voxhap_core::haptics::modes::ModeConfig;
    let mut meta = crate::test_support::meta(&["surface"]);
    meta.volume = "builtin:sphere".to_owned();
    let modes: Vec<ModeConfig> = serde_json::from_value(serde_json::json!([
        {"kind": "surface", "volume": "v", "transfer": [[0.45, 0.0], [0.55, 2.0]]}
    ]))
    .unwrap();
    meta.scenario = serde_json::json!({ "modes": modes });
    let mut writer = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
    let mut scene = RecordedScene::add(&mut writer, &meta).unwrap();
    // A 10 cm ball in a 40 cm cube.
    let big = voxhap_core::volume::procedural::sphere(
        0.1,
        voxhap_core::volume::Grid::centred_cube([24; 3], 0.2).unwrap(),
    )
    .unwrap();
    let (big_min_m, big_max_m) = big.grid().bounds_world();
    assert!((big_max_m - big_min_m - DVec3::splat(0.4)).length() < 0.05);
    let sphere = NamedVolume {
        name: "v".to_owned(),
        source: "builtin:sphere".to_owned(),
        volume: voxhap_core::volume::AnyVolume::Scalar(
            voxhap_core::volume::procedural::builtin("sphere")
                .unwrap()
                .scalar
                .unwrap(),
        ),
    };
    let ball = NamedVolume {
        name: "v".to_owned(),
        source: "big.mha".to_owned(),
        volume: voxhap_core::volume::AnyVolume::Scalar(big),
    };
    let before = (std::slice::from_ref(&sphere), &modes[..]);
    // The same scene draws nothing new.
    assert!(SceneChange::between(before, before, 2).is_none());
    let change =
        SceneChange::between(before, (std::slice::from_ref(&ball), &modes[..]), 2).unwrap();
    // A new iso-value redraws the same volume.
    let mut steeper = modes.clone();
    steeper[0].transfer =
        Some(voxhap_core::haptics::modes::TransferFunction::ramp(0.2, 0.3, 2.0).unwrap());
    let redrawn = SceneChange::between(before, (std::slice::from_ref(&sphere), &steeper[..]), 3);
    assert!((redrawn.unwrap().picture.surface.unwrap().2 - 0.25).abs() < 1e-12);
    let every = scene_frame_interval_ticks(1_000_000);
    let mut written: Vec<(u16, u64, Vec<u8>)> = Vec::new();
    for tick in 0..1000u64 {
        if tick == 400 {
            scene.scene_changed(&change);
        }
        let sample = sample_at(tick);
        // The servo took the change at tick 410.
        let frame = Snapshot {
            tick,
            t_s: sample.t_s,
            scene_generation: if tick >= 410 { 2 } else { 1 },
            ..Snapshot::example()
        };
        let frame = (tick % every == 0).then_some(&frame);
        let time_ns = tick * 1_000_000;
        scene
            .write(&sample, frame, time_ns, &mut |channel, encode| {
                let mut bytes = Vec::new();
                encode(&mut bytes).unwrap();
                written.push((channel, time_ns, bytes));
                Ok(())
            })
            .unwrap();
    }
    let pictures: Vec<_> = written.iter().filter(|m| m.0 == scene.volume).collect();
    assert_eq!(pictures.len(), 2);
    // The first snapshot of generation 2 is tick 425 (every 17th tick).
    assert_eq!((pictures[0].1, pictures[1].1), (0, 425_000_000));
    let second = SceneUpdate::decode(&pictures[1].2[..]).unwrap();
    let meta_of = |key: &str| {
        second.entities[0]
            .metadata
            .iter()
            .find(|kv| kv.key == key)
            .unwrap()
            .value
            .clone()
    };
    assert_eq!(meta_of("volume"), "big.mha");
    let expected = CameraFraming::of_bounds(big_min_m, big_max_m);
    let max_m: Vec<f64> = serde_json::from_str(&meta_of("max_m")).unwrap();
    assert_eq!(max_m, big_max_m.to_array());
    assert!(
        (meta_of("camera_distance_m").parse::<f64>().unwrap() - expected.distance_m).abs() < 1e-9
    );
    let mesh = &second.entities[1].triangles[0];
    let reach = mesh
        .points
        .iter()
        .map(|p| DVec3::new(p.x, p.y, p.z).length())
        .fold(0.0, f64::max);
    assert!(
        (reach - 0.1).abs() < 0.02,
        "the new ball's surface reaches {reach} m"
    );
    // Two frames per picture; the slices after the change sample the new 40 cm volume.
    assert_eq!(
        written.iter().filter(|m| m.0 == scene.volume_frame).count(),
        4
    );
    let slice = written
        .iter()
        .find(|m| m.0 == scene.slices[2] && m.1 >= 425_000_000)
        .unwrap();
    assert_eq!(slice.1, 425_000_000, "slices of the new volume at once");
    let grid = Grid::decode(&slice.2[..]).unwrap();
    let cell = grid.cell_size.unwrap().x;
    assert!(
        (cell * RECORDED_SLICE_SAMPLES as f64 - 0.4).abs() < 0.05,
        "cell {cell} m"
    );
}
