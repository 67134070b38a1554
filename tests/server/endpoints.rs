//! Slices over REST and WebSocket, the page and the read endpoints.

use crate::util::server::{http, next_answer, send_json, TestServer};
use serde_json::{json, Value};

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
    // The tick's truth, over the socket: why the force is off (a name from the documented list), the device's
    // fault bits, the rendered sample's age and the energy ledger's totals.
    let causes = voxhap::record::ForceOffCause::ALL.map(|c| c.name());
    assert!(
        causes.contains(&state["force_off_cause"].as_str().unwrap()),
        "{state}"
    );
    assert!(state["device_fault_bits"].is_u64(), "{state}");
    assert!(state["sample_age_ticks"].is_u64(), "{state}");
    let (status, stats) = server.get("/api/stats").await;
    assert_eq!(status, 200);
    assert_eq!(stats["servo"]["rate_hz"], 1000.0);
    let energy = &stats["servo"]["energy"];
    for key in [
        "work_on_probe_j",
        "coupling_energy_j",
        "generated_j",
        "active_work_j",
        "device_dissipation_j",
        "net_generated_j",
        "passivity_dissipated_j",
        "largest_rise_j",
    ] {
        assert!(energy[key].as_f64().unwrap().is_finite(), "{key}: {energy}");
        assert!(
            state["energy"][key].is_f64() || key == "largest_rise_j",
            "{key}: {state}"
        );
    }
    assert!(
        energy["contacts"].is_u64() && energy["longest_cycle_run"].is_u64(),
        "{energy}"
    );
    assert!(
        energy["active"].is_boolean() && energy["oscillating"].is_boolean(),
        "{energy}"
    );
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
