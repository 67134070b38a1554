//! The state stream and its clients: hello first and the asked rate, a rate out of range, the client cap, a
//! client that never reads, clean shutdown with 1001, and an oversized message closing with 1009.

use crate::util::server::{close_code, next_answer, next_json, rss_kb, send_json, TestServer, Ws};
use futures_util::SinkExt;
use serde_json::json;
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
    // Frames for clients that do not read are dropped, not queued: the count grows past what every
    // client's bounded queue could hold. No rate is assumed (a busy machine makes fewer frames): the test
    // waits for the drops, up to a minute.
    let deadline = Instant::now() + Duration::from_secs(60);
    let dropped_after = loop {
        let (_, stats) = server.get("/api/stats").await;
        assert_eq!(stats["server"]["clients"], 16);
        let dropped = stats["server"]["frames_dropped"].as_u64().unwrap();
        if dropped >= dropped_before + 16 * 100 || Instant::now() > deadline {
            break dropped;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(
        dropped_after >= dropped_before + 16 * 100,
        "frames dropped went only from {dropped_before} to {dropped_after} in a minute"
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
async fn an_oversized_message_closes_the_socket_with_1009() {
    let server = TestServer::start(8).await;
    let mut ws = server.ws("rate=5").await;
    let huge = json!({"type": "rate", "rate_hz": 10, "pad": "x".repeat(70 * 1024)});
    ws.send(Message::Text(huge.to_string().into()))
        .await
        .unwrap();
    assert_eq!(close_code(&mut ws).await, Some(1009));
}
