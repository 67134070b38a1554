//! The Foxglove live view and the Foxglove topics of MCAP traces: a real session on the simulated arm, the
//! SDK's WebSocket server on a free port, and a tokio-tungstenite client speaking `foxglove.sdk.v1` (the
//! client side of the protocol is parsed by hand here, so the test does not trust the SDK to check itself).

use ::foxglove::messages::{FrameTransform, SceneUpdate, Vector3};
use ::foxglove::Decode;
use futures_util::{SinkExt, StreamExt};
use glam::DVec3;
use std::collections::HashMap;
use std::net::{SocketAddr, TcpListener};
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;
use voxhap::record::{read_trace, TraceFormat};
use voxhap::server::foxglove::{
    start_for_serve, FoxgloveConfig, FoxgloveServer, LiveViewError, TOPICS,
};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{
    ControlCommand, ControlError, ControlReply, SceneReport, Session, SessionApi, SessionConfig,
    Slice, SliceRequest, Snapshot, StatsReport,
};

const SUBPROTOCOL: &str = "foxglove.sdk.v1";

fn sim_session(record: Option<(std::path::PathBuf, TraceFormat)>) -> Session {
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
    config.rt = voxhap::servo::rt::RtMode::Off;
    config.record = record;
    Session::start(config).unwrap()
}

fn loopback(port: u16) -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], port))
}

type Client =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(addr: SocketAddr) -> Client {
    let mut request = format!("ws://{addr}/").into_client_request().unwrap();
    request.headers_mut().insert(
        "sec-websocket-protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    let (client, response) = tokio_tungstenite::connect_async(request)
        .await
        .expect("connect to the live view");
    assert_eq!(
        response.headers().get("sec-websocket-protocol").unwrap(),
        SUBPROTOCOL
    );
    client
}

/// The next message within `timeout`, or `None`.
async fn next(client: &mut Client, timeout: Duration) -> Option<Message> {
    match tokio::time::timeout(timeout, client.next()).await {
        Ok(Some(Ok(message))) => Some(message),
        _ => None,
    }
}

/// One `messageData` frame as received: arrival, log time (ns), payload.
type Received = (Instant, u64, Vec<u8>);

/// A `messageData` frame: opcode 1, subscription id (u32 LE), log time (u64 LE ns), payload.
fn message_data(bytes: &[u8]) -> (u32, u64, &[u8]) {
    assert!(bytes.len() >= 13, "binary frame of {} bytes", bytes.len());
    assert_eq!(bytes[0], 1, "opcode of a messageData frame");
    let id = u32::from_le_bytes(bytes[1..5].try_into().unwrap());
    let log_time = u64::from_le_bytes(bytes[5..13].try_into().unwrap());
    (id, log_time, &bytes[13..])
}

/// Reads the serverInfo and the advertisements; returns the channels as topic -> (id, schema name,
/// encoding).
async fn handshake(client: &mut Client) -> HashMap<String, (u64, String, String)> {
    let mut server_info = None;
    let mut channels = HashMap::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    while (server_info.is_none() || channels.len() < TOPICS.len()) && Instant::now() < deadline {
        let Some(Message::Text(text)) = next(client, Duration::from_secs(5)).await else {
            continue;
        };
        let value: serde_json::Value = serde_json::from_str(text.as_str()).unwrap();
        match value["op"].as_str() {
            Some("serverInfo") => server_info = Some(value),
            Some("advertise") => {
                for channel in value["channels"].as_array().unwrap() {
                    channels.insert(
                        channel["topic"].as_str().unwrap().to_owned(),
                        (
                            channel["id"].as_u64().unwrap(),
                            channel["schemaName"].as_str().unwrap().to_owned(),
                            channel["encoding"].as_str().unwrap().to_owned(),
                        ),
                    );
                }
            }
            _ => {}
        }
    }
    let server_info = server_info.expect("a serverInfo message");
    assert!(
        server_info["name"].as_str().unwrap().starts_with("voxhap"),
        "{server_info}"
    );
    channels
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_view_advertises_the_topics_and_streams_the_force_at_the_asked_rate() {
    let session = sim_session(None);
    let api: Arc<dyn SessionApi> = session.api();
    const RATE_HZ: u32 = 100;
    let server = FoxgloveServer::start(api, &FoxgloveConfig::at(loopback(0), RATE_HZ))
        .await
        .unwrap();
    let addr = server.local_addr();
    assert_ne!(addr.port(), 0);
    let mut client = connect(addr).await;

    let channels = handshake(&mut client).await;
    let expected = [
        ("/voxhap/measured_cp", "foxglove.FrameTransform", "protobuf"),
        ("/voxhap/setpoint_cp", "foxglove.FrameTransform", "protobuf"),
        ("/voxhap/measured_cv", "foxglove.Vector3", "protobuf"),
        ("/voxhap/servo_cf", "foxglove.Vector3", "protobuf"),
        ("/voxhap/operating_state", "voxhap.OperatingState", "json"),
        ("/voxhap/primitives", "foxglove.SceneUpdate", "protobuf"),
        ("/voxhap/bound", "voxhap.Bound", "json"),
        ("/voxhap/stats", "voxhap.Stats", "json"),
        ("/voxhap/volume", "foxglove.SceneUpdate", "protobuf"),
        (
            "/voxhap/volume_frame",
            "foxglove.FrameTransform",
            "protobuf",
        ),
        ("/voxhap/volume/slice_x", "foxglove.Grid", "protobuf"),
        ("/voxhap/volume/slice_y", "foxglove.Grid", "protobuf"),
        ("/voxhap/volume/slice_z", "foxglove.Grid", "protobuf"),
        // The old names, kept for one release.
        ("/voxhap/probe", "foxglove.FrameTransform", "protobuf"),
        ("/voxhap/proxy", "foxglove.FrameTransform", "protobuf"),
        ("/voxhap/force", "foxglove.Vector3", "protobuf"),
    ];
    assert_eq!(channels.len(), expected.len(), "{:?}", channels.keys());
    for (topic, schema, encoding) in expected {
        let (_, found_schema, found_encoding) = channels
            .get(topic)
            .unwrap_or_else(|| panic!("{topic} not advertised: {channels:?}"));
        assert_eq!(
            (found_schema.as_str(), found_encoding.as_str()),
            (schema, encoding),
            "{topic}"
        );
    }

    // Subscribe to everything; subscription id i + 1 is TOPICS[i].
    let subscriptions: Vec<serde_json::Value> = TOPICS
        .iter()
        .enumerate()
        .map(|(i, topic)| serde_json::json!({"id": i + 1, "channelId": channels[*topic].0}))
        .collect();
    let subscribe = serde_json::json!({"op": "subscribe", "subscriptions": subscriptions});
    client
        .send(Message::Text(subscribe.to_string().into()))
        .await
        .unwrap();

    let mut received: HashMap<&str, Vec<Received>> = HashMap::new();
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(3000) {
        let Some(Message::Binary(bytes)) = next(&mut client, Duration::from_secs(2)).await else {
            continue;
        };
        let (id, log_time, payload) = message_data(&bytes);
        let topic = TOPICS[id as usize - 1];
        received
            .entry(topic)
            .or_default()
            .push((Instant::now(), log_time, payload.to_vec()));
    }

    // The force: about RATE_HZ messages a second (a loaded machine may lose some, never burst), counted
    // by their log times (the sampled ticks' times) and by when they arrived.
    let forces = &received["/voxhap/servo_cf"];
    // The old name carries the same messages for one more release.
    assert!(received["/voxhap/force"].len() >= forces.len() / 2);
    let (first_arrival, first_log_time) = (forces[0].0, forces[0].1);
    let in_one_second = forces
        .iter()
        .filter(|(_, log_time, _)| log_time - first_log_time < 1_000_000_000)
        .count();
    let arrived_in_one_second = forces
        .iter()
        .filter(|(at, _, _)| at.duration_since(first_arrival) < Duration::from_secs(1))
        .count();
    assert!(
        (RATE_HZ as usize / 2..=RATE_HZ as usize * 3 / 2).contains(&arrived_in_one_second),
        "{arrived_in_one_second} force messages arrived in one second at {RATE_HZ} Hz"
    );
    assert!(
        (RATE_HZ as usize / 2..=RATE_HZ as usize * 6 / 5).contains(&in_one_second),
        "{in_one_second} force messages in one second at {RATE_HZ} Hz"
    );
    eprintln!("{in_one_second} force messages logged and {arrived_in_one_second} arrived in one second at {RATE_HZ} Hz");
    let mut moved = false;
    for (_, _, payload) in forces {
        let force = Vector3::decode(&payload[..]).unwrap();
        let force = DVec3::new(force.x, force.y, force.z);
        assert!(force.is_finite() && force.length() < 50.0, "{force}");
        moved |= force.length() > 0.0;
    }
    assert!(moved, "every force sample was zero");
    // Log times are wall-clock and increase.
    let now_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    assert!(forces.windows(2).all(|w| w[0].1 < w[1].1));
    assert!(forces[0].1.abs_diff(now_ns) < 60_000_000_000);

    let probe = FrameTransform::decode(&received["/voxhap/measured_cp"][0].2[..]).unwrap();
    assert_eq!(
        (
            probe.parent_frame_id.as_str(),
            probe.child_frame_id.as_str()
        ),
        ("world", "probe")
    );
    let translation = probe.translation.unwrap();
    // The simulated hand circles 2 cm around (0, 0, 2 cm).
    assert!(DVec3::new(translation.x, translation.y, translation.z).length() < 0.2);
    let proxy = FrameTransform::decode(&received["/voxhap/setpoint_cp"][0].2[..]).unwrap();
    assert_eq!(proxy.child_frame_id, "proxy");
    let state: serde_json::Value =
        serde_json::from_slice(&received["/voxhap/operating_state"][0].2).unwrap();
    assert_eq!(state["state"], "ENABLED", "{state}");
    assert_eq!(state["is_homed"], true);
    Vector3::decode(&received["/voxhap/measured_cv"][0].2[..]).unwrap();

    // The volume: sent once (the scene did not change), its box and the surface mode's iso-surface.
    let volumes = &received["/voxhap/volume"];
    assert_eq!(
        volumes.len(),
        1,
        "the volume picture is sent once per scene"
    );
    let volume = SceneUpdate::decode(&volumes[0].2[..]).unwrap();
    let bounds = volume
        .entities
        .iter()
        .find(|e| e.id == "volume/bounds")
        .unwrap();
    assert_eq!(bounds.lines[0].points.len(), 24, "12 box edges");
    let surface = volume
        .entities
        .iter()
        .find(|e| e.id == "volume/surface")
        .unwrap();
    let mesh = &surface.triangles[0];
    assert!(
        mesh.indices.len() >= 300 && mesh.indices.len() % 3 == 0,
        "{} indices",
        mesh.indices.len()
    );
    assert!(mesh.indices.len() / 3 <= voxhap::server::foxglove::volume::MAX_TRIANGLES);
    assert!(mesh
        .indices
        .iter()
        .all(|&i| (i as usize) < mesh.points.len()));
    let frame = FrameTransform::decode(&received["/voxhap/volume_frame"][0].2[..]).unwrap();
    assert_eq!(frame.child_frame_id, "volume");
    // The slices through the proxy: 128 x 128 cells of value + RGBA.
    for topic in [
        "/voxhap/volume/slice_x",
        "/voxhap/volume/slice_y",
        "/voxhap/volume/slice_z",
    ] {
        let grids = received.get(topic).unwrap_or_else(|| panic!("no {topic}"));
        let grid = ::foxglove::messages::Grid::decode(&grids[0].2[..]).unwrap();
        assert_eq!(grid.column_count, 128, "{topic}");
        assert_eq!(grid.data.len(), 128 * 128 * 8, "{topic}");
        assert_eq!(grid.fields.len(), 5);
    }

    let scene = SceneUpdate::decode(&received["/voxhap/primitives"][0].2[..]).unwrap();
    let ids: Vec<&str> = scene.entities.iter().map(|e| e.id.as_str()).collect();
    for id in ["probe", "proxy", "force"] {
        assert!(ids.contains(&id), "{ids:?}");
    }

    let bound: serde_json::Value = serde_json::from_slice(&received["/voxhap/bound"][0].2).unwrap();
    for key in ["tick", "t_s", "error_bound_m", "sweeps", "status"] {
        assert!(bound.get(key).is_some(), "{key} missing from {bound}");
    }
    let stats = &received
        .get("/voxhap/stats")
        .expect("statistics within 3 s (they come once a second)");
    assert!(
        stats.len() <= 4,
        "{} statistics messages in 3 s",
        stats.len()
    );
    let stats: serde_json::Value = serde_json::from_slice(&stats[0].2).unwrap();
    // The first statistics may be sampled before the servo's first tick on a loaded machine.
    let stats_ticks = stats["ticks"].as_u64().expect("ticks");
    assert_eq!(stats["rate_hz"], 1000.0);
    assert!(stats["lateness"]["p99_us"].is_number(), "{stats}");

    // Stopping the view closes the client's connection.
    assert_eq!(server.client_count(), 1);
    server.stop().await;
    let closed = async {
        loop {
            match client.next().await {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => break,
                Some(Ok(_)) => {}
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(5), closed)
        .await
        .expect("the connection was not closed on stop");
    let summary = session.stop();
    assert!(summary.stats.ticks > 1000);
    assert!(stats_ticks <= summary.stats.ticks);
}

/// A session that never ticks, for the tests that only need the server to start or not.
struct IdleSession;

impl SessionApi for IdleSession {
    fn snapshot(&self) -> Option<Snapshot> {
        None
    }
    fn stats(&self) -> StatsReport {
        StatsReport::default()
    }
    fn scene(&self) -> SceneReport {
        unimplemented!("not used by the live view")
    }
    fn control(&self, _: ControlCommand) -> Result<ControlReply, ControlError> {
        Err(ControlError::Unavailable("idle test session".into()))
    }
    fn slice(&self, _: SliceRequest) -> Result<Slice, ControlError> {
        Err(ControlError::Unavailable("idle test session".into()))
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_busy_default_address_is_skipped_with_a_warning_but_an_explicit_one_is_an_error() {
    let taken = TcpListener::bind(loopback(0)).unwrap();
    let addr = taken.local_addr().unwrap();
    let default = FoxgloveConfig {
        addr,
        explicit: false,
        rate_hz: 60,
    };
    let started = start_for_serve(Arc::new(IdleSession), Some(default))
        .await
        .unwrap();
    assert!(started.is_none(), "started on a busy port");
    let explicit = FoxgloveConfig {
        explicit: true,
        ..default
    };
    let error = start_for_serve(Arc::new(IdleSession), Some(explicit))
        .await
        .err()
        .expect("an explicit busy address must be an error");
    assert!(
        matches!(error, LiveViewError::AddressInUse { addr: a } if a == addr),
        "{error}"
    );
    assert!(error.to_string().contains("--no-foxglove"), "{error}");
    assert!(start_for_serve(Arc::new(IdleSession), None)
        .await
        .unwrap()
        .is_none());
    // Once the port is free the same explicit configuration starts.
    drop(taken);
    let server = start_for_serve(Arc::new(IdleSession), Some(explicit))
        .await
        .unwrap()
        .expect("started");
    assert_eq!(server.local_addr(), addr);
    server.stop().await;
}

fn voxhap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .expect("run voxhap")
}

#[test]
fn serve_refuses_a_remote_address_without_the_flag_before_starting() {
    let out = voxhap(&[
        "serve",
        "--rt",
        "off",
        "--foxglove",
        "0.0.0.0:0",
        "--duration",
        "1",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stdout}");
    assert!(stderr.contains("--foxglove-allow-remote"), "{stderr}");
    assert!(
        !stdout.contains("serving:"),
        "the session started: {stdout}"
    );
}

#[test]
fn serve_prints_the_live_view_address_and_fails_on_an_explicit_busy_one() {
    let out = voxhap(&[
        "serve",
        "--rt",
        "off",
        "--foxglove",
        "127.0.0.1:0",
        "--duration",
        "0.5",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout
        .lines()
        .find(|l| l.starts_with("foxglove: listening on ws://127.0.0.1:"))
        .unwrap_or_else(|| panic!("no foxglove line in {stdout}"));
    let port: u16 = line.rsplit(':').next().unwrap().parse().unwrap();
    assert_ne!(port, 0, "{line}");

    let taken = TcpListener::bind(loopback(0)).unwrap();
    let busy = taken.local_addr().unwrap().to_string();
    let out = voxhap(&[
        "serve",
        "--rt",
        "off",
        "--foxglove",
        &busy,
        "--duration",
        "5",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("already in use"), "{stderr}");
}

#[test]
fn a_recorded_session_carries_the_foxglove_topics_in_its_mcap() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("session.mcap");
    let session = sim_session(Some((path.clone(), TraceFormat::Mcap)));
    std::thread::sleep(Duration::from_millis(400));
    let summary = session.stop();
    let trace = summary.trace.expect("a finished trace");
    assert!(trace.sample_count > 100, "{} samples", trace.sample_count);

    let bytes = std::fs::read(&path).unwrap();
    let mcap_summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("the trace has a summary section");
    let stats = mcap_summary.stats.as_ref().expect("statistics record");
    let mut by_topic = HashMap::new();
    for (id, channel) in &mcap_summary.channels {
        let schema = channel
            .schema
            .as_ref()
            .map(|s| (s.name.clone(), s.encoding.clone()));
        let count = stats.channel_message_counts.get(id).copied().unwrap_or(0);
        by_topic.insert(
            channel.topic.clone(),
            (schema, channel.message_encoding.clone(), count),
        );
    }
    let n = trace.sample_count;
    let protobuf = |name: &str| Some((name.to_owned(), "protobuf".to_owned()));
    let json = |name: &str| Some((name.to_owned(), "jsonschema".to_owned()));
    assert_eq!(
        by_topic["/voxhap/measured_cp"],
        (protobuf("foxglove.FrameTransform"), "protobuf".into(), n)
    );
    assert_eq!(
        by_topic["/voxhap/setpoint_cp"],
        (protobuf("foxglove.FrameTransform"), "protobuf".into(), n)
    );
    assert_eq!(
        by_topic["/voxhap/servo_cf"],
        (protobuf("foxglove.Vector3"), "protobuf".into(), n)
    );
    // The scene: the volume once, markers and bound at up to 60 Hz of tick time, statistics once a second.
    assert_eq!(
        by_topic["/voxhap/volume"],
        (protobuf("foxglove.SceneUpdate"), "protobuf".into(), 1)
    );
    assert_eq!(by_topic["/voxhap/volume_frame"].2, 1);
    let markers = by_topic["/voxhap/primitives"].2;
    assert!(
        markers > 10 && markers < n / 10,
        "{markers} scene updates for {n} ticks"
    );
    assert_eq!(by_topic["/voxhap/bound"].2, markers);
    assert_eq!(by_topic["/voxhap/bound"].0, json("voxhap.Bound"));
    assert_eq!(by_topic["/voxhap/stats"].0, json("voxhap.TraceStats"));
    // The trace's own channels are still there, and voxhap reads the trace back.
    assert_eq!(
        by_topic["/voxhap/state"],
        (json("voxhap.State"), "json".into(), n)
    );
    assert_eq!(
        by_topic["/voxhap/solver"],
        (json("voxhap.Solver"), "json".into(), n)
    );
    assert_eq!(by_topic.len(), 10, "{:?}", by_topic.keys());
    let read = read_trace(&path).unwrap();
    assert_eq!(read.samples.len() as u64, n);

    // The last force message is the last sample's force.
    let last_force = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .filter(|m| m.channel.topic == "/voxhap/servo_cf")
        .last()
        .unwrap();
    let force = Vector3::decode(&last_force.data[..]).unwrap();
    let sample = read.samples.last().unwrap();
    assert_eq!([force.x, force.y, force.z], sample.force_n.to_array());
    // Log times are wall-clock UTC: the first sample at about the time the recording started.
    let first = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .find(|m| m.channel.topic == "/voxhap/servo_cf")
        .unwrap();
    let since_first_ns = ((sample.t_s - read.samples[0].t_s) * 1e9).round() as u64;
    assert_eq!(last_force.log_time - first.log_time, since_first_ns);
    let now_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    assert!(
        now_ns.abs_diff(first.log_time) < 60_000_000_000,
        "first log time {}",
        first.log_time
    );
}

/// The scene topics of a recording, read by the `mcap` Python package (an independent MCAP reader; .ci/run
/// installs it): the volume picture once, markers and bounds, statistics, wall-clock log times.
#[test]
fn python_mcap_reads_the_scene_topics_of_a_recorded_session() {
    let has_mcap = Command::new("python3")
        .args(["-c", "import mcap"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !has_mcap {
        eprintln!(
            "SKIPPED python_mcap_reads_the_scene_topics_of_a_recorded_session: python3 with the `mcap` \
             package is not available (pip install mcap)"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.mcap");
    let session = sim_session(Some((path.clone(), TraceFormat::Mcap)));
    std::thread::sleep(Duration::from_millis(1500));
    session.stop();
    let script = r#"
import json, sys, time
from mcap.reader import make_reader
report = {"counts": {}, "schemas": {}, "sizes": {}, "first_log_time": None, "json": {}}
with open(sys.argv[1], "rb") as f:
    for schema, channel, message in make_reader(f).iter_messages():
        topic = channel.topic
        report["counts"][topic] = report["counts"].get(topic, 0) + 1
        report["schemas"][topic] = [schema.name, schema.encoding, channel.message_encoding]
        report["sizes"][topic] = max(report["sizes"].get(topic, 0), len(message.data))
        if report["first_log_time"] is None:
            report["first_log_time"] = message.log_time
        if channel.message_encoding == "json":
            report["json"].setdefault(topic, json.loads(message.data))
report["now_ns"] = time.time_ns()
print(json.dumps(report))
"#;
    let output = Command::new("python3")
        .args(["-c", script])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let schema = |topic: &str| report["schemas"][topic].clone();
    assert_eq!(
        schema("/voxhap/volume"),
        serde_json::json!(["foxglove.SceneUpdate", "protobuf", "protobuf"])
    );
    assert_eq!(report["counts"]["/voxhap/volume"], 1);
    assert_eq!(report["counts"]["/voxhap/volume_frame"], 1);
    // The built-in scene's density ball, meshed: tens of kilobytes of triangles.
    let volume_bytes = report["sizes"]["/voxhap/volume"].as_u64().unwrap();
    assert!(
        volume_bytes > 20_000,
        "volume message of {volume_bytes} bytes"
    );
    let markers = report["counts"]["/voxhap/primitives"].as_u64().unwrap();
    assert!(
        (30..=120).contains(&markers),
        "{markers} marker updates in ~1.5 s"
    );
    assert_eq!(
        schema("/voxhap/primitives"),
        serde_json::json!(["foxglove.SceneUpdate", "protobuf", "protobuf"])
    );
    let bound = &report["json"]["/voxhap/bound"];
    for key in ["tick", "t_s", "error_bound_m", "sweeps", "status"] {
        assert!(bound.get(key).is_some(), "{key} missing from {bound}");
    }
    let stats = &report["json"]["/voxhap/stats"];
    assert!(stats["ticks"].as_u64().unwrap() >= 900, "{stats}");
    let first = report["first_log_time"].as_u64().unwrap();
    let now = report["now_ns"].as_u64().unwrap();
    assert!(
        now > first && now - first < 120_000_000_000,
        "first log time {first}, now {now}"
    );
}
