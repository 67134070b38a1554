//! Connection limits below HTTP: the connection cap, idle and trickling connections, duplicate Host or Origin
//! headers, and request heads larger than the parser buffer.

use crate::util::server::{next_json, rss_kb, TestServer, TOKEN};
use std::time::{Duration, Instant};

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

/// A request without a Host header is refused with 400 naming it (RFC 9112 section 3.2: "A server MUST respond
/// with a 400 (Bad Request) status code to any HTTP/1.1 request message that lacks a Host header field"), for
/// HTTP/1.1 and HTTP/1.0 alike, and changes nothing; with one it is answered. Before the fix it was answered
/// 200.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_without_a_host_header_is_refused() {
    use voxhap::servo::SessionApi as _;
    let server = TestServer::start(4).await;
    let addr = server.addr;
    for version in ["HTTP/1.1", "HTTP/1.0"] {
        let request = format!("GET /api/state {version}\r\nConnection: close\r\n\r\n");
        let (status, body) = raw_request(addr, request.as_bytes()).await;
        assert_eq!(status, 400, "{version}: {body}");
        assert!(body.contains("no Host header"), "{body}");
    }
    let k_before = server.api.snapshot().unwrap().stiffness_n_per_m;
    let post = format!(
        "POST /api/stiffness HTTP/1.1\r\nAuthorization: Bearer {TOKEN}\r\n\
         Content-Type: application/json\r\nContent-Length: 10\r\nConnection: close\r\n\r\n{{\"k\": 321}}"
    );
    let (status, body) = raw_request(addr, post.as_bytes()).await;
    assert_eq!(status, 400, "{body}");
    assert_eq!(server.api.snapshot().unwrap().stiffness_n_per_m, k_before);
    let (status, body) = raw_request(
        addr,
        format!("GET /api/state HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .await;
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
