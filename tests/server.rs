//! The visualiser server against a real session (simulated arm, built-in scene, 1 kHz) on 127.0.0.1:0: the
//! state stream's rate, the control API's token and validation, the client cap, a client that never reads,
//! clean shutdown, slices and the page. Contract: protocol/VISUALISER.md.

use crate::util::server::{
    close_code, http, next_answer, next_json, rss_kb, TestServer, Ws, TOKEN,
};
use futures_util::SinkExt;
use serde_json::{json, Value};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

/// State messages received in `window` (other messages are ignored).
async fn count_states(ws: &mut Ws, window: Duration) -> usize {
    let end = Instant::now() + window;
    let mut count = 0;
    while Instant::now() < end {
        let left = end.saturating_duration_since(Instant::now());
        let Ok(value) = tokio::time::timeout(left, next_json(ws)).await else {
            break;
        };
        if value["type"] == "state" {
            count += 1;
        }
    }
    count
}

async fn send_json(ws: &mut Ws, value: Value) {
    ws.send(Message::Text(value.to_string().into()))
        .await
        .unwrap();
}

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
async fn the_stream_starts_with_hello_and_arrives_at_the_asked_rate() {
    let server = TestServer::start(8).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{}/ws?rate=50", server.addr))
        .await
        .unwrap();
    let hello = next_json(&mut ws).await;
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["schema"], "voxhap.visualiser.v1");
    assert_eq!(hello["rate_hz"], 50.0);
    assert_eq!(hello["servo_rate_hz"], 1000.0);
    assert_eq!(hello["scene"]["modes"].as_array().unwrap().len(), 3);
    assert_eq!(hello["scene"]["simulated"], true);

    let state = next_json(&mut ws).await;
    assert_eq!(state["type"], "state");
    for key in [
        "tick",
        "t_s",
        "probe_m",
        "proxy_m",
        "force_n",
        "rendered_force_n",
        "primitives",
        "error_bound_m",
        "status",
        "sweeps",
        "stiffness_n_per_m",
        "damping_n_s_per_m",
        "connected",
        "engaged",
        "scene_generation",
        "hand_target_m",
        "frames_dropped",
    ] {
        assert!(state.get(key).is_some(), "state lacks {key}: {state}");
    }
    assert_eq!(state["probe_m"].as_array().unwrap().len(), 3);

    let count = count_states(&mut ws, Duration::from_secs(2)).await;
    assert!(
        (80..=120).contains(&count),
        "{count} states in 2 s at 50 Hz"
    );

    send_json(&mut ws, json!({"type": "rate", "id": 1, "rate_hz": 200})).await;
    let reply = next_answer(&mut ws).await;
    assert_eq!(reply["type"], "reply", "{reply}");
    assert_eq!(reply["id"], 1);
    let count = count_states(&mut ws, Duration::from_secs(1)).await;
    assert!(
        (160..=240).contains(&count),
        "{count} states in 1 s at 200 Hz"
    );

    send_json(&mut ws, json!({"type": "rate", "id": 2, "rate_hz": 5000})).await;
    let error = next_answer(&mut ws).await;
    assert_eq!(error["type"], "error");
    assert!(
        error["error"]
            .as_str()
            .unwrap()
            .contains("rate must be 1 ..= 1000 Hz"),
        "{error}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rate_out_of_range_is_refused_before_the_upgrade() {
    let server = TestServer::start(8).await;
    for (query, why) in [
        ("rate=0", "rate must be 1 ..= 1000 Hz"),
        ("rate=fast", "rate must be a number"),
    ] {
        let error = tokio_tungstenite::connect_async(format!("ws://{}/ws?{query}", server.addr))
            .await
            .unwrap_err();
        let tokio_tungstenite::tungstenite::Error::Http(response) = error else {
            panic!("expected an HTTP refusal, got {error}");
        };
        assert_eq!(response.status().as_u16(), 400);
        let body = String::from_utf8(response.body().clone().unwrap_or_default()).unwrap();
        assert!(body.contains(why), "{body}");
    }
    assert_eq!(server.get("/api/stats").await.1["server"]["clients"], 0);
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_over_the_cap_are_refused_with_503() {
    let server = TestServer::start(2).await;
    let first = server.ws("rate=5").await;
    let _second = server.ws("rate=5").await;
    let error = tokio_tungstenite::connect_async(format!("ws://{}/ws", server.addr))
        .await
        .unwrap_err();
    let tokio_tungstenite::tungstenite::Error::Http(response) = error else {
        panic!("expected 503, got {error}");
    };
    assert_eq!(response.status().as_u16(), 503);
    let (_, stats) = server.get("/api/stats").await;
    assert_eq!(stats["server"]["clients"], 2);
    assert_eq!(stats["server"]["max_clients"], 2);
    assert_eq!(stats["server"]["clients_refused"], 1);
    assert!(stats["servo"]["ticks"].as_u64().unwrap() > 0);

    // A client that leaves frees its slot.
    drop(first);
    let started = Instant::now();
    while server.get("/api/stats").await.1["server"]["clients"] != 1 {
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "the slot was never freed"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let _third = server.ws("rate=5").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_that_never_read_lose_frames_not_memory() {
    let server = TestServer::start(32).await;
    // Sixteen clients at 1 kHz that read nothing after the handshake: unbounded queues would hold about
    // 16 x 1000 x 1.2 kB = 19 MB more every second.
    let mut clients = Vec::new();
    for _ in 0..16 {
        let (ws, _) =
            tokio_tungstenite::connect_async(format!("ws://{}/ws?rate=1000", server.addr))
                .await
                .unwrap();
        clients.push(ws);
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    let (_, stats) = server.get("/api/stats").await;
    let dropped_before = stats["server"]["frames_dropped"].as_u64().unwrap();
    // Other tests run in this process at the same time and allocate (sessions, volumes), so the RSS is
    // watched over three 1 s windows: a leak grows it in every window, a neighbour only now and then.
    let mut growth_kb = Vec::new();
    for _ in 0..3 {
        let before = rss_kb();
        tokio::time::sleep(Duration::from_secs(1)).await;
        growth_kb.push(rss_kb().saturating_sub(before));
    }
    let (_, stats) = server.get("/api/stats").await;
    let dropped_after = stats["server"]["frames_dropped"].as_u64().unwrap();
    assert_eq!(stats["server"]["clients"], 16);
    assert!(
        dropped_after >= dropped_before + 16 * 1000,
        "frames dropped went from {dropped_before} to {dropped_after} in 3 s"
    );
    let least = growth_kb.iter().copied().min().unwrap();
    assert!(
        least < 4 * 1024,
        "the RSS grew in every 1 s window (kB: {growth_kb:?})"
    );
    drop(clients);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_closes_every_client_with_1001_and_run_returns() {
    let mut server = TestServer::start(8).await;
    let mut a = server.ws("rate=30").await;
    let mut b = server.ws("rate=1000").await;
    // One that never reads: run() must still return (its close frame may not fit).
    let (_stuck, _) =
        tokio_tungstenite::connect_async(format!("ws://{}/ws?rate=1000", server.addr))
            .await
            .unwrap();
    // The two reading clients read on until their close frame.
    let a = tokio::spawn(async move { close_code(&mut a).await });
    let b = tokio::spawn(async move { close_code(&mut b).await });
    tokio::time::sleep(Duration::from_millis(300)).await;
    let started = Instant::now();
    server.shutdown().await;
    assert!(
        started.elapsed() < Duration::from_secs(4),
        "run() took {:?}",
        started.elapsed()
    );
    assert_eq!(a.await.unwrap(), Some(1001));
    assert_eq!(b.await.unwrap(), Some(1001));
    // Nothing listens any more.
    assert!(tokio::net::TcpStream::connect(server.addr).await.is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slices_over_rest_and_websocket() {
    let server = TestServer::start(8).await;
    // Through the ball's centre; then through the proxy (the default), wherever it is.
    let (status, slice) = server.get("/api/slice?axis=z&size=64&at=0,0,0").await;
    assert_eq!(status, 200, "{slice}");
    assert_eq!(
        (slice["width"].as_u64(), slice["height"].as_u64()),
        (Some(64), Some(64))
    );
    assert_eq!(slice["axis"], "z");
    let values = slice["values"].as_array().unwrap();
    assert_eq!(values.len(), 64 * 64);
    assert!(values
        .iter()
        .all(|v| v.as_f64().is_some_and(f64::is_finite)));
    let (min, max) = (
        slice["min"].as_f64().unwrap(),
        slice["max"].as_f64().unwrap(),
    );
    assert!(
        min < max,
        "the slice through the centre crosses the density ball"
    );
    let (status, slice) = server.get("/api/slice?axis=z&size=16").await;
    assert_eq!(status, 200, "{slice}");
    let proxy_z = server.get("/api/state").await.1["proxy_m"][2]
        .as_f64()
        .unwrap();
    let slice_z = slice["origin_m"][2].as_f64().unwrap();
    assert!(
        (slice_z - proxy_z).abs() < 0.01,
        "slice at z = {slice_z}, proxy at {proxy_z}"
    );

    // 8-bit levels (what the page asks for): the same picture in a fraction of the bytes.
    let (_, _, full_text) = http(
        server.addr,
        "GET",
        "/api/slice?axis=z&size=128&at=0,0,0",
        None,
        "",
    )
    .await;
    let (status, _, u8_text) = http(
        server.addr,
        "GET",
        "/api/slice?axis=z&size=128&at=0,0,0&encoding=u8",
        None,
        "",
    )
    .await;
    assert_eq!(status, 200, "{u8_text}");
    let compact: Value = serde_json::from_str(&u8_text).unwrap();
    assert!(compact.get("values").is_none());
    let levels = base64::Engine::decode(
        &base64::engine::general_purpose::STANDARD,
        compact["values_u8"].as_str().unwrap(),
    )
    .unwrap();
    assert_eq!(levels.len(), 128 * 128);
    assert_eq!(levels.iter().copied().max(), Some(255), "max maps to 255");
    assert_eq!(levels.iter().copied().min(), Some(0), "min maps to 0");
    assert!(
        u8_text.len() * 3 < full_text.len(),
        "u8 {} bytes vs f32 {} bytes",
        u8_text.len(),
        full_text.len()
    );
    eprintln!(
        "slice 128x128: f32 JSON {} bytes, u8 JSON {} bytes",
        full_text.len(),
        u8_text.len()
    );

    let (status, slice) = server
        .get("/api/slice?axis=x&size=16&at=0,0,0.01&volume=flow")
        .await;
    assert_eq!(status, 200, "{slice}");
    assert_eq!(slice["origin_m"][0], 0.0);
    assert_eq!(slice["volume"], "flow");

    for (query, status, why) in [
        ("size=8", 400, "size must be 16 ..= 512"),
        ("axis=w", 400, "axis must be x, y or z"),
        ("at=1,2", 400, "at must be three finite numbers"),
        ("volume=nope", 404, "no volume named"),
        ("encoding=png", 400, "encoding must be f32 or u8"),
    ] {
        let (got, body) = server.get(&format!("/api/slice?{query}")).await;
        assert_eq!(got, status, "{query}: {body}");
        assert!(
            body["error"].as_str().unwrap().contains(why),
            "{query}: {body}"
        );
    }

    let mut ws = server.ws("rate=10").await;
    send_json(
        &mut ws,
        json!({"type": "slice", "id": 9, "axis": "y", "size": 32}),
    )
    .await;
    let slice = next_answer(&mut ws).await;
    assert_eq!(slice["type"], "slice", "{slice}");
    assert_eq!(slice["id"], 9);
    assert_eq!(slice["values"].as_array().unwrap().len(), 32 * 32);
    send_json(&mut ws, json!({"type": "slice", "id": 10, "size": 4096})).await;
    let error = next_answer(&mut ws).await;
    assert_eq!(
        (error["type"].as_str(), error["id"].as_u64()),
        (Some("error"), Some(10))
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_message_closes_the_socket_with_1009() {
    let server = TestServer::start(8).await;
    let mut ws = server.ws("rate=5").await;
    let huge = json!({"type": "rate", "rate_hz": 10, "pad": "x".repeat(70 * 1024)});
    ws.send(Message::Text(huge.to_string().into()))
        .await
        .unwrap();
    assert_eq!(close_code(&mut ws).await, Some(1009));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_and_the_read_endpoints() {
    let server = TestServer::start(8).await;
    for (path, content_type) in [
        ("/", "text/html"),
        ("/app.js", "text/javascript"),
        ("/style.css", "text/css"),
    ] {
        let (status, head, _) = http(server.addr, "GET", path, None, "").await;
        assert_eq!(status, 200, "{path}");
        assert!(
            head.contains(&format!("content-type: {content_type}")),
            "{path}: {head}"
        );
    }
    let (status, state) = server.get("/api/state").await;
    assert_eq!(status, 200);
    assert_eq!(state["type"], "state");
    assert_eq!(state["frames_dropped"], 0);
    let (status, stats) = server.get("/api/stats").await;
    assert_eq!(status, 200);
    assert_eq!(stats["servo"]["rate_hz"], 1000.0);
    for key in [
        "clients",
        "max_clients",
        "frames_sent",
        "frames_dropped",
        "clients_refused",
    ] {
        assert!(
            stats["server"].get(key).is_some(),
            "server stats lack {key}"
        );
    }
    let (status, scene) = server.get("/api/scene").await;
    assert_eq!(status, 200);
    assert_eq!(scene["volumes"][0]["name"], "density");
    let (status, body) = server.get("/api/nothing").await;
    assert_eq!(status, 404);
    assert!(body["error"].as_str().unwrap().contains("/api/nothing"));
}

/// Reads from `stream` until the server closes it (EOF or a reset) or `within` passes; true if it closed.
async fn closed_by_server(stream: &mut tokio::net::TcpStream, within: Duration) -> bool {
    use tokio::io::AsyncReadExt;
    let mut buf = [0u8; 256];
    let deadline = Instant::now() + within;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, stream.read(&mut buf)).await {
            Err(_) => return false,
            Ok(Ok(0)) | Ok(Err(_)) => return true,
            Ok(Ok(_)) => continue,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_over_the_cap_are_closed_at_once_and_counted() {
    // max_clients 2: at most 2 + EXTRA_CONNECTIONS connections. Here every slot carries a request in
    // progress (a complete head whose body never comes), which half-open newcomers cannot take over: a
    // flood beyond the cap is refused.
    use tokio::io::AsyncWriteExt;
    let server = TestServer::start(2).await;
    let cap = 2 + voxhap::server::EXTRA_CONNECTIONS;
    let mut idle = Vec::new();
    for _ in 0..cap {
        let mut stream = tokio::net::TcpStream::connect(server.addr).await.unwrap();
        let head = format!(
            "POST /api/control HTTP/1.1\r\nHost: {}\r\nContent-Length: 10\r\n\r\n",
            server.addr
        );
        stream.write_all(head.as_bytes()).await.unwrap();
        idle.push(stream);
    }
    // Let the server accept all of them before the extra ones arrive.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let mut extra = Vec::new();
    for _ in 0..5 {
        extra.push(tokio::net::TcpStream::connect(server.addr).await.unwrap());
    }
    for stream in &mut extra {
        assert!(
            closed_by_server(stream, Duration::from_secs(2)).await,
            "a connection over the cap was kept open"
        );
    }
    // The ones inside the cap are still open.
    assert!(!closed_by_server(&mut idle[0], Duration::from_millis(200)).await);
    drop(idle);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (status, stats) = server.get("/api/stats").await;
    assert_eq!(status, 200, "{stats}");
    assert_eq!(stats["server"]["connections_refused"], 5, "{stats}");
    assert_eq!(stats["server"]["max_connections"], cap, "{stats}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_are_closed_but_a_reading_websocket_client_stays() {
    let server = TestServer::start_with(4, Duration::from_millis(400)).await;
    // A connection that never sends a request (half a request, here) is closed after the idle timeout.
    let mut silent = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    {
        use tokio::io::AsyncWriteExt;
        silent
            .write_all(b"GET /api/state HTTP/1.1\r\nHo")
            .await
            .unwrap();
    }
    let started = Instant::now();
    assert!(closed_by_server(&mut silent, Duration::from_secs(3)).await);
    assert!(
        started.elapsed() >= Duration::from_millis(300),
        "closed before the idle timeout: {:?}",
        started.elapsed()
    );
    // A WebSocket client that sends nothing but reads its states keeps its connection well past the
    // timeout: the writes are progress.
    let mut ws = server.ws("rate=60").await;
    let until = Instant::now() + Duration::from_millis(1500);
    let mut states = 0;
    while Instant::now() < until {
        let message = next_json(&mut ws).await;
        if message["type"] == "state" {
            states += 1;
        }
    }
    assert!(states > 60, "only {states} states in 1.5 s");
    let (_, stats) = server.get("/api/stats").await;
    assert!(
        stats["server"]["idle_closed"].as_u64() >= Some(1),
        "{stats}"
    );
    assert_eq!(stats["server"]["clients"], 1, "{stats}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_trickled_a_byte_at_a_time_is_closed_after_the_timeout() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let server = TestServer::start_with(4, Duration::from_millis(400)).await;
    let mut stream = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    stream
        .write_all(b"GET /api/state HTTP/1.1\r\nX-Slow: ")
        .await
        .unwrap();
    let started = Instant::now();
    let mut buf = [0u8; 256];
    // A byte every 50 ms, well inside the 400 ms timeout each time: only the server's writes count.
    let closed_after = loop {
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "a client trickling its request kept the connection for 5 s"
        );
        tokio::select! {
            read = stream.read(&mut buf) => match read {
                Ok(0) | Err(_) => break started.elapsed(),
                Ok(n) => panic!(
                    "the server answered a request that never finished: {:?}",
                    String::from_utf8_lossy(&buf[..n])
                ),
            },
            () = tokio::time::sleep(Duration::from_millis(50)) => {
                if stream.write_all(b"a").await.is_err() {
                    break started.elapsed();
                }
            }
        }
    };
    assert!(
        closed_after >= Duration::from_millis(300),
        "closed before the timeout: {closed_after:?}"
    );
    let (_, stats) = server.get("/api/stats").await;
    assert!(
        stats["server"]["idle_closed"].as_u64() >= Some(1),
        "{stats}"
    );
}

/// Sends `request` on a fresh connection and reads the answer until the server closes it (5 s at most):
/// (status, body).
async fn raw_request(addr: std::net::SocketAddr, request: &[u8]) -> (u16, String) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    // The server may answer and close before reading all of a large request: a failed write is fine.
    let _ = stream.write_all(request).await;
    let mut response = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut response)).await;
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
        .unwrap_or_default();
    (status, body)
}

/// A request with two Host headers, or two Origin headers, is refused with 400 naming the header, whichever
/// comes first (RFC 9112 section 3.2 allows one Host line; RFC 6454 section 7.3 one Origin), and changes
/// nothing; the same requests with one of each are answered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_with_two_host_or_two_origin_headers_is_refused() {
    use voxhap::servo::SessionApi as _;
    let server = TestServer::start(4).await;
    let addr = server.addr;
    let good_host = format!("Host: {addr}\r\n");
    let evil_host = format!("Host: rebind.example:{}\r\n", addr.port());
    let good_origin = format!("Origin: http://{addr}\r\n");
    let evil_origin = "Origin: https://evil.example\r\n";
    let get =
        |headers: String| format!("GET /api/state HTTP/1.1\r\n{headers}Connection: close\r\n\r\n");
    let (status, body) = raw_request(addr, get(good_host.clone()).as_bytes()).await;
    assert_eq!(status, 200, "{body}");
    for hosts in [
        format!("{good_host}{evil_host}"),
        format!("{evil_host}{good_host}"),
        format!("{good_host}{good_host}"),
    ] {
        let (status, body) = raw_request(addr, get(hosts.clone()).as_bytes()).await;
        assert_eq!(status, 400, "{hosts}: {body}");
        assert!(body.contains("2 Host headers"), "{body}");
    }
    // A control request: two Origins, the page's own first.
    let k_before = server.api.snapshot().unwrap().stiffness_n_per_m;
    let post = |origins: &str| {
        format!(
            "POST /api/stiffness HTTP/1.1\r\n{good_host}{origins}Authorization: Bearer {TOKEN}\r\n\
             Content-Type: application/json\r\nContent-Length: 10\r\nConnection: close\r\n\r\n{{\"k\": 321}}"
        )
    };
    let (status, body) = raw_request(
        addr,
        post(&format!("{good_origin}{evil_origin}")).as_bytes(),
    )
    .await;
    assert_eq!(status, 400, "{body}");
    assert!(body.contains("2 Origin headers"), "{body}");
    let (status, body) = raw_request(
        addr,
        post(&format!("{evil_origin}{good_origin}")).as_bytes(),
    )
    .await;
    assert_eq!(status, 400, "{body}");
    assert_eq!(server.api.snapshot().unwrap().stiffness_n_per_m, k_before);
    // A WebSocket upgrade with two Origins is not upgraded.
    let upgrade = format!(
        "GET /ws HTTP/1.1\r\n{good_host}{good_origin}{evil_origin}Connection: Upgrade\r\nUpgrade: websocket\r\n\
         Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
    );
    let (status, body) = raw_request(addr, upgrade.as_bytes()).await;
    assert_eq!(status, 400, "{body}");
    // One of each: answered.
    let (status, body) = raw_request(addr, post(&good_origin).as_bytes()).await;
    assert_eq!(status, 200, "{body}");
}

/// What a client can make the server buffer before a request is even routed: a request head is bounded by
/// the HTTP parser's buffer (about 400 KiB; hyper's default of 8 KiB + 100 x 4 KiB): 20 clients each sending
/// 8 MiB of header lines are answered 431 (or closed) long before the 160 MiB arrive, and this process (the
/// server runs in it) grows by far less.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_heads_larger_than_the_parser_buffer_are_refused_without_growing_memory() {
    let server = TestServer::start(4).await;
    let addr = server.addr;
    let line = format!("X-Pad: {}\r\n", "a".repeat(1000));
    let padding: std::sync::Arc<Vec<u8>> = std::sync::Arc::new(line.repeat(8 << 10).into_bytes());
    let before_kb = rss_kb();
    let clients: Vec<_> = (0..20)
        .map(|_| {
            let padding = padding.clone();
            tokio::spawn(async move {
                use tokio::io::{AsyncReadExt, AsyncWriteExt};
                let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
                let head = format!("GET /api/state HTTP/1.1\r\nHost: {addr}\r\n");
                stream.write_all(head.as_bytes()).await.unwrap();
                let sent =
                    tokio::time::timeout(Duration::from_secs(10), stream.write_all(&padding)).await;
                let mut response = Vec::new();
                let _ =
                    tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut response))
                        .await;
                (
                    matches!(sent, Ok(Ok(()))),
                    String::from_utf8_lossy(&response).into_owned(),
                )
            })
        })
        .collect();
    for client in clients {
        let (sent_all, response) = client.await.unwrap();
        assert!(!sent_all, "the server read an 8 MiB request head");
        assert!(
            response.is_empty() || response.starts_with("HTTP/1.1 431"),
            "{response}"
        );
    }
    let growth_mib = rss_kb().saturating_sub(before_kb) as f64 / 1024.0;
    eprintln!("RSS grew by {growth_mib:.1} MiB");
    assert!(growth_mib < 64.0, "RSS grew by {growth_mib:.1} MiB");
    // The server still answers.
    assert_eq!(server.get("/api/state").await.0, 200);
}
