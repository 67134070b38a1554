//! The Foxglove view follows the scene: a volume loaded through the control API while a client watches is
//! redrawn (new mesh, bounds, camera framing and slices, and no stale picture after it), and a volume loaded
//! while recording is redrawn in the MCAP file at the change. Real parts throughout: a session on the
//! simulated arm, the SDK's WebSocket server on 127.0.0.1 port 0 with the hand-written client of
//! `super::foxglove`, a MetaImage file on disk, the `mcap` crate reading the recording back.

use super::foxglove::{
    connect, handshake, loopback, message_data, next, python_mcap_scene_check, sim_session,
    subscribe,
};
use ::foxglove::messages::{FrameTransform, Grid, SceneUpdate};
use ::foxglove::Decode;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;
use voxhap::record::TraceFormat;
use voxhap::server::foxglove::{FoxgloveConfig, FoxgloveServer};
use voxhap::servo::{ControlCommand, SessionApi};
use voxhap::view::topics::{CameraFraming, VIEW_FRAME, VOLUME_FRAME};

/// Samples per side of the loaded ball volume, and their spacing (mm): 31 cm from the first to the last.
const BALL_SAMPLES: usize = 32;
const BALL_SPACING_MM: f64 = 10.0;
/// The ball's radius (m) about the volume's centre; density 1 inside, 0 outside, a 1 cm ramp between.
const BALL_RADIUS_M: f64 = 0.1;

/// Writes a MetaImage (`.mha`, float32, RAS origin (100, 50, -20) mm: LPS offset (-100, -50, -20)) of a
/// ball: a volume three times the built-in scene's size, off its centre.
fn write_ball(dir: &Path) -> PathBuf {
    let n = BALL_SAMPLES;
    let half_m = 0.5 * (n - 1) as f64 * BALL_SPACING_MM * 1e-3;
    let mut data = Vec::with_capacity(n * n * n * 4);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let offset_m = DVec3::new(i as f64, j as f64, k as f64) * BALL_SPACING_MM * 1e-3
                    - DVec3::splat(half_m);
                let value = ((BALL_RADIUS_M - offset_m.length()) / 0.01 + 0.5).clamp(0.0, 1.0);
                data.extend_from_slice(&(value as f32).to_le_bytes());
            }
        }
    }
    let header = format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nElementByteOrderMSB = False\n\
         CompressedData = False\nTransformMatrix = -1 0 0 0 -1 0 0 0 1\nOffset = -100 -50 -20\n\
         ElementSpacing = {BALL_SPACING_MM} {BALL_SPACING_MM} {BALL_SPACING_MM}\nDimSize = {n} {n} {n}\n\
         ElementType = MET_FLOAT\nElementDataFile = LOCAL\n"
    );
    let path = dir.join("ball.mha");
    let mut bytes = header.into_bytes();
    bytes.extend_from_slice(&data);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// The bounds voxhap reports for the volume named `density` (the built-in scene's scalar volume).
fn density_bounds(api: &dyn SessionApi) -> (DVec3, DVec3) {
    let scene = api.scene();
    let volume = scene
        .volumes
        .iter()
        .find(|v| v.name == "density")
        .expect("the built-in scene has a volume named density");
    (volume.min_m, volume.max_m)
}

/// A `volume/bounds` entity's metadata value.
fn bounds_meta(update: &SceneUpdate, key: &str) -> String {
    let bounds = update
        .entities
        .iter()
        .find(|e| e.id == "volume/bounds")
        .expect("a volume/bounds entity");
    bounds
        .metadata
        .iter()
        .find(|kv| kv.key == key)
        .unwrap_or_else(|| panic!("no {key} in the bounds' metadata"))
        .value
        .clone()
}

fn vec3_meta(update: &SceneUpdate, key: &str) -> DVec3 {
    let values: Vec<f64> = serde_json::from_str(&bounds_meta(update, key)).unwrap();
    DVec3::from_slice(&values)
}

/// The picture's box as its metadata gives it.
fn picture_bounds(update: &SceneUpdate) -> (DVec3, DVec3) {
    (vec3_meta(update, "min_m"), vec3_meta(update, "max_m"))
}

fn close(a: DVec3, b: DVec3) -> bool {
    (a - b).length() < 1e-9
}

/// Checks the picture shows the loaded ball: its box, the camera framing of that box, and a mesh of the
/// ball's half-density shell inside it.
fn assert_shows_ball(update: &SceneUpdate, min_m: DVec3, max_m: DVec3) {
    let (shown_min, shown_max) = picture_bounds(update);
    assert!(
        close(shown_min, min_m) && close(shown_max, max_m),
        "shown {shown_min}..{shown_max}"
    );
    // 31 samples of 10 mm: a 31 cm cube from RAS (100, 50, -20) mm, its centre at (255, 205, 135) mm.
    assert!(
        ((max_m - min_m) - DVec3::splat(0.31)).length() < 1e-9,
        "{min_m}..{max_m}"
    );
    let centre = (min_m + max_m) * 0.5;
    assert!(
        (centre - DVec3::new(0.255, 0.205, 0.135)).length() < 1e-9,
        "{centre}"
    );
    // The framing: target at the centre, distance 1.1 x (0.31 sqrt(3) / 2) / sin(22.5 degrees).
    assert!(close(vec3_meta(update, "camera_target_m"), centre));
    let distance: f64 = bounds_meta(update, "camera_distance_m").parse().unwrap();
    assert!(
        (distance - 0.771_694_4).abs() < 1e-6,
        "camera distance {distance} m"
    );
    let surface = update
        .entities
        .iter()
        .find(|e| e.id == "volume/surface")
        .expect("the ball's iso-surface");
    let mesh = &surface.triangles[0];
    assert!(mesh.indices.len() >= 300, "{} indices", mesh.indices.len());
    for p in &mesh.points {
        let r = (DVec3::new(p.x, p.y, p.z) - centre).length();
        assert!(
            (r - BALL_RADIUS_M).abs() < 0.015,
            "vertex {r} m from the centre"
        );
    }
}

/// A live client subscribed to the volume and its frames sees the built-in scene's picture, then, after a
/// volume is loaded through the control API, the new volume's picture within a bounded time, its frames
/// (the camera framed on it) and slices, and no picture of the old volume after it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_loaded_volume_is_redrawn_for_a_subscribed_client_and_nothing_stale_follows() {
    let dir = tempfile::tempdir().unwrap();
    let ball = write_ball(dir.path());
    let session = sim_session(None);
    let api: Arc<dyn SessionApi> = session.api();
    let server = FoxgloveServer::start(api.clone(), &FoxgloveConfig::at(loopback(0), 30))
        .await
        .unwrap();
    let mut client = connect(server.local_addr()).await;
    let channels = handshake(&mut client).await;
    let topics = [
        "/voxhap/volume",
        "/voxhap/volume_frame",
        "/voxhap/volume/slice_z",
    ];
    subscribe(&mut client, &channels, &topics).await;

    // Every message from now on: (arrival, topic index, payload).
    let mut received: Vec<(Instant, usize, Vec<u8>)> = Vec::new();
    let (old_min, old_max) = density_bounds(api.as_ref());
    let deadline = Instant::now() + Duration::from_secs(30);
    while Instant::now() < deadline && !received.iter().any(|m| m.1 == 0) {
        if let Some(Message::Binary(bytes)) = next(&mut client, Duration::from_secs(1)).await {
            let (id, _, payload) = message_data(&bytes);
            received.push((Instant::now(), id as usize - 1, payload.to_vec()));
        }
    }
    let first = received
        .iter()
        .find(|m| m.1 == 0)
        .expect("the built-in volume's picture within 30 s");
    let first = SceneUpdate::decode(&first.2[..]).unwrap();
    let (min_m, max_m) = picture_bounds(&first);
    assert!(close(min_m, old_min) && close(max_m, old_max));

    // Load the ball in place of the built-in scene's density volume (a blocking control call).
    let control = api.clone();
    let path = ball.clone();
    let reply = tokio::task::spawn_blocking(move || {
        control.control(ControlCommand::LoadVolume {
            path,
            name: Some("density".to_owned()),
        })
    })
    .await
    .unwrap()
    .expect("the ball loads");
    let loaded_at = Instant::now();
    assert!(reply.scene_generation > 1, "{reply:?}");
    let (new_min, new_max) = density_bounds(api.as_ref());
    assert!(!close(new_min, old_min));

    // The new picture within 20 s (meshing a 64-cube of samples on a loaded 2-core machine), then 1.5 s
    // more of messages.
    received.clear();
    let mut new_picture_at = None;
    let deadline = loaded_at + Duration::from_secs(20);
    loop {
        let now = Instant::now();
        let done = new_picture_at.is_some_and(|at: Instant| now > at + Duration::from_millis(1500));
        if done || (new_picture_at.is_none() && now > deadline) {
            break;
        }
        let Some(Message::Binary(bytes)) = next(&mut client, Duration::from_millis(500)).await
        else {
            continue;
        };
        let (id, _, payload) = message_data(&bytes);
        let topic = id as usize - 1;
        if topic == 0 && new_picture_at.is_none() {
            let update = SceneUpdate::decode(payload).unwrap();
            let (min_m, max_m) = picture_bounds(&update);
            if close(min_m, new_min) && close(max_m, new_max) {
                new_picture_at = Some(Instant::now());
            }
        }
        received.push((Instant::now(), topic, payload.to_vec()));
    }
    let new_picture_at =
        new_picture_at.expect("no picture of the loaded volume within 20 s of the load");
    eprintln!(
        "the loaded volume's picture arrived {:.2} s after the load",
        new_picture_at.duration_since(loaded_at).as_secs_f64()
    );
    let after: Vec<_> = received.iter().filter(|m| m.0 >= new_picture_at).collect();
    let pictures: Vec<SceneUpdate> = after
        .iter()
        .filter(|m| m.1 == 0)
        .map(|m| SceneUpdate::decode(&m.2[..]).unwrap())
        .collect();
    assert!(!pictures.is_empty());
    for picture in &pictures {
        // Every picture from then on shows the ball: no stale mesh of the old volume follows.
        assert_shows_ball(picture, new_min, new_max);
    }
    // The frames of the new picture: `volume` at the ball's centre, `volume_view` where the framing puts it.
    let framing = CameraFraming::of_bounds(new_min, new_max);
    let frames: Vec<FrameTransform> = received
        .iter()
        .filter(|m| m.1 == 1)
        .map(|m| FrameTransform::decode(&m.2[..]).unwrap())
        .collect();
    let frame_at = |child: &str| {
        let t = frames
            .iter()
            .rev()
            .find(|f| f.child_frame_id == child)
            .unwrap_or_else(|| panic!("no {child} frame after the load"));
        let v = t.translation.as_ref().unwrap();
        DVec3::new(v.x, v.y, v.z)
    };
    assert!(close(frame_at(VOLUME_FRAME), framing.target_m));
    assert!(close(frame_at(VIEW_FRAME), framing.view_frame_m));
    // Slices after the new picture sample the ball's volume: 128 cells over its 31 cm.
    let slice = after
        .iter()
        .find(|m| m.1 == 2)
        .expect("a z slice within 1.5 s of the new picture");
    let grid = Grid::decode(&slice.2[..]).unwrap();
    let width_m = grid.cell_size.unwrap().x * f64::from(grid.column_count);
    assert!((width_m - 0.31).abs() < 0.01, "slice {width_m} m wide");

    server.stop().await;
    session.stop();
}

/// A volume loaded while recording is redrawn in the MCAP file: two pictures, in log-time order, the
/// second with the loaded volume's bounds, framing and mesh, written within a few scene intervals of the
/// ticks that render it; frames and slices follow the new volume.
#[test]
fn a_volume_loaded_while_recording_is_redrawn_in_the_mcap() {
    let dir = tempfile::tempdir().unwrap();
    let ball = write_ball(dir.path());
    let path = dir.path().join("change.mcap");
    let session = sim_session(Some((path.clone(), TraceFormat::Mcap)));
    let api = session.api();
    std::thread::sleep(Duration::from_millis(600));
    let (old_min, old_max) = density_bounds(api.as_ref());
    let asked = Instant::now();
    let reply = api
        .control(ControlCommand::LoadVolume {
            path: ball,
            name: Some("density".to_owned()),
        })
        .expect("the ball loads while recording");
    eprintln!(
        "load_volume while recording (meshing the recording's picture) took {:.3} s",
        asked.elapsed().as_secs_f64()
    );
    let (new_min, new_max) = density_bounds(api.as_ref());
    // Long enough for the recorder to mesh the ball on a loaded machine and record past it.
    std::thread::sleep(Duration::from_millis(2500));
    let summary = session.stop();
    assert!(summary.trace.is_some(), "a finished trace");

    let bytes = std::fs::read(&path).unwrap();
    let mut pictures = Vec::new();
    let mut frames = Vec::new();
    let mut slices = Vec::new();
    let mut states = Vec::new();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let data = message.data.to_vec();
        match message.channel.topic.as_str() {
            "/voxhap/volume" => {
                pictures.push((message.log_time, SceneUpdate::decode(&data[..]).unwrap()))
            }
            "/voxhap/volume_frame" => {
                frames.push((message.log_time, FrameTransform::decode(&data[..]).unwrap()))
            }
            "/voxhap/volume/slice_z" => {
                slices.push((message.log_time, Grid::decode(&data[..]).unwrap()))
            }
            "/voxhap/state" => states.push(message.log_time),
            _ => {}
        }
    }
    assert_eq!(
        pictures.len(),
        2,
        "the start's picture and the loaded volume's"
    );
    let (first_ns, first) = &pictures[0];
    let (second_ns, second) = &pictures[1];
    assert!(
        first_ns < second_ns,
        "log times {first_ns} then {second_ns}"
    );
    let (min_m, max_m) = picture_bounds(first);
    assert!(close(min_m, old_min) && close(max_m, old_max));
    assert_shows_ball(second, new_min, new_max);
    // Written at the change: after the first recorded tick and before the last (the picture is meshed by
    // load_volume before it returns, and the recorder writes it with the next tick). No bound on when: on a
    // busy machine the session's first tick and the recorder run late.
    assert!(states[0] <= *first_ns && *second_ns < *states.last().unwrap());
    let elapsed_s = (*second_ns - states[0]) as f64 * 1e-9;
    eprintln!(
        "scene generation {} drawn at {elapsed_s:.3} s into the recording",
        reply.scene_generation
    );
    // Its frames, with the same log time: `volume` at the ball's centre, `volume_view` per the framing.
    let framing = CameraFraming::of_bounds(new_min, new_max);
    let at_change: Vec<_> = frames.iter().filter(|(t, _)| t == second_ns).collect();
    assert_eq!(at_change.len(), 2);
    let position = |f: &FrameTransform| {
        let v = f.translation.as_ref().unwrap();
        DVec3::new(v.x, v.y, v.z)
    };
    assert_eq!(at_change[0].1.child_frame_id, VOLUME_FRAME);
    assert!(close(position(&at_change[0].1), framing.target_m));
    assert_eq!(at_change[1].1.child_frame_id, VIEW_FRAME);
    assert!(close(position(&at_change[1].1), framing.view_frame_m));
    // Slices before the change cover the 10 cm built-in volume, from the change on the 31 cm ball's.
    let width = |grid: &Grid| grid.cell_size.unwrap().x * f64::from(grid.column_count);
    let (before, after): (Vec<_>, Vec<_>) = slices.iter().partition(|(t, _)| t < second_ns);
    assert!(!before.is_empty() && !after.is_empty());
    assert_eq!(
        after[0].0, *second_ns,
        "slices of the new volume with its picture"
    );
    for (_, grid) in &before {
        assert!((width(grid) - (old_max - old_min).x).abs() < 0.01);
    }
    for (_, grid) in &after {
        assert!((width(grid) - 0.31).abs() < 0.01, "{} m", width(grid));
    }
    // An independent reader (the `mcap` Python package) sees the two pictures in order, each with its
    // two frames, and every topic at its rate.
    if let Some(report) = python_mcap_scene_check(
        "a_volume_loaded_while_recording_is_redrawn_in_the_mcap (Python part)",
        &path,
        2,
    ) {
        let times = report["picture_log_times"].as_array().unwrap();
        assert_eq!(times[1].as_u64(), Some(*second_ns), "{report}");
    }
}
