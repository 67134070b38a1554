//! Hand targets from the control API are validated: a real HTTP client sends targets
//! that are huge (1e308, which would overflow the simulated arm's hand spring into NaN for the rest of the
//! session), outside the arm's workspace (for the unbounded built-in arm: more than 10 m from the origin),
//! out of JSON's range or malformed. Each is refused with 400 and a
//! message naming the problem, and the session goes on: ticks keep coming, the arm's probe, proxy and
//! force stay finite, and a valid target is still obeyed afterwards. Targets are scene positions: under a
//! workspace mapping (docs/workspace.md) the hand is moved to the device point that maps there.

use crate::util::server::TestServer;
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use voxhap::device::mapping::WorkspaceMapping;
use voxhap::device::profile::{DeviceProfile, MappingChoice};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::SessionConfig;

fn finite_vector(state: &Value, key: &str) -> bool {
    state[key]
        .as_array()
        .is_some_and(|v| v.len() == 3 && v.iter().all(|x| x.as_f64().is_some_and(f64::is_finite)))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_hand_targets_are_refused_and_the_arm_stays_finite() {
    let server = TestServer::start(8).await;
    let (_, before) = server.get("/api/state").await;
    let tick_before = before["tick"].as_u64().expect("tick");
    for (body, expected) in [
        (
            json!({"position_m": [1e308, 0.0, 0.0]}).to_string(),
            "outside the simulated arm's workspace",
        ),
        // The built-in scene's arm has an unbounded workspace; targets are still kept within 10 m.
        (
            json!({"position_m": [0.0, 0.0, 50.0]}).to_string(),
            "outside the simulated arm's workspace",
        ),
        (
            json!({"position_m": [-1e300, 1e300, 0.0]}).to_string(),
            "outside the simulated arm's workspace",
        ),
        // Beyond f64: JSON parsing refuses it before it can become infinity.
        (r#"{"position_m": [1e999, 0, 0]}"#.to_owned(), ""),
        (r#"{"position_m": [0.01, 0.02]}"#.to_owned(), ""),
        (r#"{"position_m": "here"}"#.to_owned(), ""),
    ] {
        let (status, reply) = server.post("/api/hand", &body).await;
        assert!(
            (400..500).contains(&status),
            "{body}: answered {status} {reply}"
        );
        assert!(
            reply.to_string().contains(expected),
            "{body}: {reply} does not say {expected:?}"
        );
        let (_, state) = server.get("/api/state").await;
        assert_eq!(state["hand_target_m"], Value::Null, "{body} was applied");
    }

    // The session goes on with finite numbers.
    let started = Instant::now();
    let state = loop {
        let (_, state) = server.get("/api/state").await;
        if state["tick"].as_u64().unwrap_or(0) > tick_before + 200 {
            break state;
        }
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "the servo stopped ticking: {state}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    for key in ["probe_m", "proxy_m", "force_n"] {
        assert!(finite_vector(&state, key), "{key} is not finite: {state}");
    }

    // A valid target is still obeyed.
    let target = [0.04, 0.04, 0.0];
    let (status, reply) = server
        .post("/api/hand", &json!({"position_m": target}).to_string())
        .await;
    assert_eq!(status, 200, "{reply}");
    let distance = probe_distance_after_settling(&server, target, 0.005).await;
    assert!(
        distance < 0.005,
        "the probe is still {distance} m from a valid hand target"
    );
}

/// Waits (up to 5 s) until the probe (scene frame, as `/api/state` reports it, finite) is within `within_m` of
/// `target`; returns the last distance.
async fn probe_distance_after_settling(
    server: &TestServer,
    target: [f64; 3],
    within_m: f64,
) -> f64 {
    let started = Instant::now();
    loop {
        let (_, state) = server.get("/api/state").await;
        assert!(finite_vector(&state, "probe_m"), "{state}");
        let probe: Vec<f64> = serde_json::from_value(state["probe_m"].clone()).unwrap();
        let distance = probe
            .iter()
            .zip(target)
            .map(|(p, t)| (p - t).powi(2))
            .sum::<f64>()
            .sqrt();
        if distance < within_m || started.elapsed() > Duration::from_secs(5) {
            return distance;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Issue 13: `/api/hand` takes a scene position. Under a mapping with scale 2 and a translation of
/// (0.1, -0.05, 0.02) m, a target of (0.14, -0.05, 0.02) m in the scene is the device point (0.02, 0, 0) m;
/// the probe, which the session reports in the scene frame, must come to the target. Were the target taken
/// as a device point, the probe would settle at s p + t = (0.38, -0.15, 0.06) m instead.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hand_target_in_scene_coordinates_puts_the_probe_there_under_a_workspace_mapping() {
    let mapping = WorkspaceMapping::new(
        glam::DMat3::IDENTITY,
        2.0,
        glam::DVec3::new(0.1, -0.05, 0.02),
    )
    .unwrap();
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
    config.profile = DeviceProfile {
        mapping: MappingChoice::Fixed(mapping),
        ..DeviceProfile::default()
    };
    // No modes: nothing but the hand moves the arm.
    config.setup.modes.clear();
    let server = TestServer::start_session(8, |_| {}, None, config).await;
    for target in [[0.14, -0.05, 0.02], [0.08, -0.03, 0.04]] {
        let (status, reply) = server
            .post("/api/hand", &json!({"position_m": target}).to_string())
            .await;
        assert_eq!(status, 200, "{reply}");
        let (_, state) = server.get("/api/state").await;
        assert_eq!(
            state["hand_target_m"],
            json!(target),
            "reported in the scene frame"
        );
        let distance = probe_distance_after_settling(&server, target, 0.003).await;
        assert!(
            distance < 0.003,
            "the probe settled {distance} m from the scene target {target:?}"
        );
    }
    // The workspace check is made in the device frame, and the error says both: the built-in arm's 10 m
    // limit is 20 m in this scene, so a scene target 12 m out is accepted, and one 25 m out is not.
    let (status, reply) = server
        .post(
            "/api/hand",
            &json!({"position_m": [12.0, 0.0, 0.0]}).to_string(),
        )
        .await;
    assert_eq!(status, 200, "{reply}");
    let (status, reply) = server
        .post(
            "/api/hand",
            &json!({"position_m": [25.0, 0.0, 0.0]}).to_string(),
        )
        .await;
    assert_eq!(status, 400, "{reply}");
    assert!(reply.to_string().contains("in the device frame"), "{reply}");
}
