//! Hand targets from the control API are validated (issue 15, item 1): a real HTTP client sends targets
//! that are huge (1e308, which once overflowed the simulated arm's hand spring into NaN for the rest of the
//! session), outside the arm's workspace (for the unbounded built-in arm: more than 10 m from the origin),
//! out of JSON's range or malformed. Each is refused with 400 and a
//! message naming the problem, and the session goes on: ticks keep coming, the arm's probe, proxy and
//! force stay finite, and a valid target is still obeyed afterwards.

use crate::util::server::TestServer;
use serde_json::{json, Value};
use std::time::{Duration, Instant};

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
        if distance < 0.005 {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "the probe is still {distance} m from a valid hand target"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}
