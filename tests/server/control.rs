//! The control API: the token, commands rejected naming the problem and changing nothing, a valid change in the
//! next state, and the hand target moving the simulated probe.

use crate::util::server::{next_answer, next_json, send_json, TestServer, Ws, TOKEN};
use futures_util::SinkExt;
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

/// The first state whose `scene_generation` is at least `generation` (panics after 5 s).
async fn state_with_generation(ws: &mut Ws, generation: u64) -> Value {
    loop {
        let value = next_json(ws).await;
        if value["type"] == "state" && value["scene_generation"].as_u64().unwrap() >= generation {
            return value;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn control_without_the_token_is_refused_and_changes_nothing() {
    let server = TestServer::start(8).await;
    let before = server.generation();
    let (_, scene_before) = server.get("/api/scene").await;
    for token in [None, Some("wrong-token-000000000")] {
        let (status, body) = server
            .send("POST", "/api/stiffness", token, r#"{"k": 123}"#)
            .await;
        assert_eq!(status, 401, "{body}");
        assert!(
            body["error"].as_str().unwrap().starts_with("unauthorized"),
            "{body}"
        );
    }
    let (status, _) = server.send("DELETE", "/api/modes/surface", None, "").await;
    assert_eq!(status, 401);
    let (status, _) = server
        .send(
            "POST",
            "/api/control",
            Some("Basic abc"),
            r#"{"command":"stop_recording"}"#,
        )
        .await;
    assert_eq!(status, 401);

    let mut ws = server.ws("rate=10").await;
    let command = json!({"command": "set_stiffness", "k": 123});
    send_json(
        &mut ws,
        json!({"type": "control", "id": 5, "command": command}),
    )
    .await;
    let error = next_answer(&mut ws).await;
    assert_eq!(
        (error["type"].as_str(), error["id"].as_u64()),
        (Some("error"), Some(5))
    );
    assert!(
        error["error"].as_str().unwrap().contains("token"),
        "{error}"
    );
    send_json(
        &mut ws,
        json!({"type": "control", "id": 6, "token": "nope", "command": command}),
    )
    .await;
    let error = next_answer(&mut ws).await;
    assert_eq!(error["error"], "unauthorized: wrong token");

    assert_eq!(server.generation(), before);
    assert_eq!(server.get("/api/scene").await.1, scene_before);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invalid_commands_are_rejected_naming_the_problem_and_change_nothing() {
    let server = TestServer::start(8).await;
    let before = server.generation();
    let (_, scene_before) = server.get("/api/scene").await;
    let big = format!(r#"{{"k": 400, "pad": "{}"}}"#, "x".repeat(70 * 1024));
    let cases: &[(&str, &str, &str, u16, &str)] = &[
        (
            "POST",
            "/api/stiffness",
            r#"{"k": -5}"#,
            400,
            "k must be > 0",
        ),
        (
            "POST",
            "/api/stiffness",
            r#"{"k": "NaN"}"#,
            400,
            "k: invalid type: string \"NaN\"",
        ),
        (
            "POST",
            "/api/stiffness",
            r#"{"k": 400, "damping": -1}"#,
            400,
            "damping must be",
        ),
        (
            "POST",
            "/api/stiffness",
            r#"{"k": 400, "spring": 1}"#,
            400,
            "unknown field `spring`",
        ),
        (
            "POST",
            "/api/stiffness",
            r#"{"k": 4"#,
            400,
            "malformed JSON",
        ),
        ("POST", "/api/stiffness", "", 400, "empty"),
        ("POST", "/api/stiffness", r#"{}"#, 400, "give \"k\""),
        ("POST", "/api/stiffness", &big, 413, "length limit"),
        (
            "POST",
            "/api/modes/nonesuch/transfer",
            r#"{"transfer": [[0, 0], [1, 1]]}"#,
            404,
            "no mode named \"nonesuch\"",
        ),
        (
            "POST",
            "/api/modes/surface/transfer",
            r#"{"transfer": [[1, 0], [0, 1]]}"#,
            400,
            "transfer",
        ),
        (
            "POST",
            "/api/modes/nonesuch/enabled",
            r#"{"enabled": false}"#,
            404,
            "no mode named \"nonesuch\"",
        ),
        (
            "POST",
            "/api/modes/surface/enabled",
            r#"{"enabled": "no"}"#,
            400,
            "enabled",
        ),
        ("DELETE", "/api/modes/nonesuch", "", 404, "no mode named"),
        (
            "POST",
            "/api/modes",
            r#"{"mode": {"kind": "surface", "volume": "density", "bogus": 1}}"#,
            400,
            "unknown field `bogus`",
        ),
        (
            "POST",
            "/api/modes",
            r#"{"mode": {"kind": "surface", "name": "extra", "volume": "nope", "transfer": [[0, 0], [1, 1]]}}"#,
            400,
            "nope",
        ),
        (
            "POST",
            "/api/volume",
            r#"{"path": "/nonexistent/volume.nrrd"}"#,
            404,
            "does not exist",
        ),
        (
            "POST",
            "/api/record/start",
            r#"{"path": "/nonexistent/dir/trace.csv"}"#,
            404,
            "does not exist",
        ),
        ("POST", "/api/record/stop", "", 409, "not recording"),
        (
            "POST",
            "/api/hand",
            r#"{"position_m": [0, 0, "x"]}"#,
            400,
            "position_m",
        ),
        (
            "POST",
            "/api/control",
            r#"{"command": "set_stiffness", "k": "NaN"}"#,
            400,
            "k: invalid type",
        ),
        (
            "POST",
            "/api/control",
            r#"{"command": "fly"}"#,
            400,
            "unknown variant `fly`",
        ),
        (
            "POST",
            "/api/control",
            r#"{"k": 5}"#,
            400,
            "missing field `command`",
        ),
    ];
    for (method, path, body, status, why) in cases {
        let (got, answer) = server.send(method, path, Some(TOKEN), body).await;
        let error = answer["error"].as_str().unwrap_or_default();
        assert_eq!(got, *status, "{method} {path} {:.80}: {answer}", body);
        assert!(
            error.contains(why),
            "{method} {path}: {error:?} lacks {why:?}"
        );
        assert_eq!(answer["ok"], false);
        assert_eq!(
            server.generation(),
            before,
            "{method} {path} changed the scene"
        );
    }
    assert_eq!(server.get("/api/scene").await.1, scene_before);

    // Over the WebSocket: a bad command and invalid JSON get an error; the connection stays.
    let mut ws = server.ws("rate=10").await;
    let command = json!({"command": "set_stiffness", "k": -1});
    send_json(
        &mut ws,
        json!({"type": "control", "id": 1, "token": TOKEN, "command": command}),
    )
    .await;
    let error = next_answer(&mut ws).await;
    assert!(
        error["error"].as_str().unwrap().contains("k must be > 0"),
        "{error}"
    );
    ws.send(Message::Text("{not json".into())).await.unwrap();
    let error = next_answer(&mut ws).await;
    assert!(
        error["error"].as_str().unwrap().contains("malformed JSON"),
        "{error}"
    );
    let command = json!({"command": "remove_mode", "name": "nonesuch", "extra": true});
    send_json(
        &mut ws,
        json!({"type": "control", "id": 2, "token": TOKEN, "command": command}),
    )
    .await;
    let error = next_answer(&mut ws).await;
    assert!(
        error["error"]
            .as_str()
            .unwrap()
            .contains("unknown field `extra`"),
        "{error}"
    );
    send_json(&mut ws, json!({"type": "rate", "rate_hz": 20})).await;
    assert_eq!(
        next_answer(&mut ws).await["type"],
        "reply",
        "the connection still works"
    );
    assert_eq!(server.generation(), before);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_valid_change_takes_effect_in_the_next_state() {
    let server = TestServer::start(8).await;
    let mut ws = server.ws("rate=100").await;
    let (status, reply) = server
        .post("/api/stiffness", r#"{"k": 321, "damping": 0.5}"#)
        .await;
    assert_eq!(status, 200, "{reply}");
    assert_eq!(reply["ok"], true);
    assert!(
        reply["message"]
            .as_str()
            .unwrap()
            .contains("stiffness set to 321"),
        "{reply}"
    );
    let generation = reply["scene_generation"].as_u64().unwrap();
    let state = state_with_generation(&mut ws, generation).await;
    assert_eq!(state["stiffness_n_per_m"], 321.0);
    assert_eq!(state["damping_n_s_per_m"], 0.5);

    // The same over the WebSocket, with the token.
    let command = json!({"command": "set_stiffness", "k": 250});
    send_json(
        &mut ws,
        json!({"type": "control", "id": "s", "token": TOKEN, "command": command}),
    )
    .await;
    let reply = next_answer(&mut ws).await;
    assert_eq!(
        (reply["type"].as_str(), reply["ok"].as_bool()),
        (Some("reply"), Some(true)),
        "{reply}"
    );
    assert_eq!(reply["id"], "s");
    let state = state_with_generation(&mut ws, reply["scene_generation"].as_u64().unwrap()).await;
    assert_eq!(state["stiffness_n_per_m"], 250.0);

    // A mode's transfer function, then removing and re-adding a mode.
    let (status, reply) = server
        .post(
            "/api/modes/viscosity/transfer",
            r#"{"transfer": [[0, 0], [1, 0.1]]}"#,
        )
        .await;
    assert_eq!(status, 200, "{reply}");
    // Switched off and on again: the breakpoints survive (a strength of 0 and back must not flatten them),
    // and the scene says which modes are off.
    let mode_named = |scene: &Value, name: &str| {
        scene["modes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["name"] == name || (m["name"].is_null() && m["kind"] == name))
            .cloned()
            .unwrap()
    };
    let (status, reply) = server
        .post("/api/modes/viscosity/enabled", r#"{"enabled": false}"#)
        .await;
    assert_eq!(status, 200, "{reply}");
    assert!(
        reply["message"].as_str().unwrap().contains("off"),
        "{reply}"
    );
    let off = mode_named(&server.get("/api/scene").await.1, "viscosity");
    assert_eq!(off["enabled"], false, "{off}");
    assert_eq!(off["transfer"], json!([[0.0, 0.0], [1.0, 0.1]]), "{off}");
    let (status, reply) = server
        .post("/api/modes/viscosity/enabled", r#"{"enabled": true}"#)
        .await;
    assert_eq!(status, 200, "{reply}");
    let on = mode_named(&server.get("/api/scene").await.1, "viscosity");
    assert!(on.get("enabled").is_none(), "{on}");
    assert_eq!(on["transfer"], json!([[0.0, 0.0], [1.0, 0.1]]), "{on}");

    let (status, reply) = server
        .send("DELETE", "/api/modes/viscosity", Some(TOKEN), "")
        .await;
    assert_eq!(status, 200, "{reply}");
    let (status, reply) = server
        .post("/api/modes", r#"{"mode": {"kind": "viscosity", "volume": "density", "transfer": [[0, 0], [1, 0.2]]}}"#)
        .await;
    assert_eq!(status, 200, "{reply}");
    assert_eq!(
        server.get("/api/scene").await.1["modes"]
            .as_array()
            .unwrap()
            .len(),
        3
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_hand_target_moves_the_simulated_probe() {
    let server = TestServer::start(8).await;
    // Outside the density ball (radius 3 cm), where nothing pushes back.
    let target = [0.04, 0.04, 0.0];
    let (status, reply) = server
        .post("/api/hand", &json!({"position_m": target}).to_string())
        .await;
    assert_eq!(status, 200, "{reply}");
    let mut ws = server.ws("rate=50").await;
    let started = Instant::now();
    let distance = loop {
        let state = next_json(&mut ws).await;
        if state["type"] != "state" {
            continue;
        }
        assert_eq!(state["hand_target_m"], json!(target));
        let probe: Vec<f64> = serde_json::from_value(state["probe_m"].clone()).unwrap();
        let distance = probe
            .iter()
            .zip(target)
            .map(|(p, t)| (p - t).powi(2))
            .sum::<f64>()
            .sqrt();
        if distance < 0.005 || started.elapsed() > Duration::from_secs(3) {
            break distance;
        }
    };
    assert!(
        distance < 0.005,
        "the probe is still {distance} m from the hand target"
    );
    let (status, _) = server.post("/api/hand", r#"{"position_m": null}"#).await;
    assert_eq!(status, 200);
    assert_eq!(
        server.get("/api/state").await.1["hand_target_m"],
        Value::Null
    );
}

/// `POST /api/stiffness` with both k and damping is checked whole before anything is applied. The simulated
/// arm's default `[arm]` damping is b = 1 N s/m at T = 1 ms (docs/safety.md), so the passivity bound leaves
/// `b - k T/2 = 1 - 1500 * 0.0005 = 0.25 N s/m` of coupling damping at k = 1500 N/m: 0.5 N s/m is refused
/// there, and the stiffness must stay as it was; at k = 1000 N/m the bound is exactly 0.5 and both apply.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_damping_leaves_the_stiffness_of_the_same_request_unapplied() {
    let server = TestServer::start(8).await;
    let before = server.generation();
    let (_, scene_before) = server.get("/api/scene").await;
    let (status, answer) = server
        .post("/api/stiffness", r#"{"k": 1500, "damping": 0.5}"#)
        .await;
    assert_eq!(status, 400, "{answer}");
    let error = answer["error"].as_str().unwrap();
    assert!(
        error.contains("damping must be at most 0.25 N s/m") && error.contains("(1500 N/m)"),
        "{error}"
    );
    assert_eq!(
        server.generation(),
        before,
        "the refused request changed the scene"
    );
    assert_eq!(server.get("/api/scene").await.1, scene_before);

    let mut ws = server.ws("rate=100").await;
    let (status, reply) = server
        .post("/api/stiffness", r#"{"k": 1000, "damping": 0.5}"#)
        .await;
    assert_eq!(status, 200, "{reply}");
    let message = reply["message"].as_str().unwrap();
    assert!(
        message.contains("stiffness set to 1000 N/m")
            && message.contains("damping set to 0.5 N s/m"),
        "{message}"
    );
    let state = state_with_generation(&mut ws, reply["scene_generation"].as_u64().unwrap()).await;
    assert_eq!(state["stiffness_n_per_m"], 1000.0);
    assert_eq!(state["damping_n_s_per_m"], 0.5);
}
