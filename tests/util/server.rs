//! Helpers for the visualiser server tests: a real session on the simulated arm with the server on
//! 127.0.0.1:0, a minimal HTTP/1.1 client over a TcpStream, and WebSocket helpers (tokio-tungstenite).

use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};
use voxhap::server::{self, ServerConfig};
use voxhap::servo::api::folders::{ConfinedVolumes, VolumeDirs};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::rt::RtMode;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{Session, SessionApi, SessionConfig, SessionShared};

pub const TOKEN: &str = "test-token-0123456789";

pub type Ws = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// A running session with the visualiser server in front of it. Dropping it stops both (call
/// [`TestServer::shutdown`] to watch the server go).
pub struct TestServer {
    pub addr: SocketAddr,
    pub api: Arc<SessionShared>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    pub task: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
    // Dropped last: the session outlives the server.
    _session: Session,
}

impl TestServer {
    /// Starts the built-in scene on the simulated arm at 1 kHz and the server on an ephemeral port; returns
    /// once the servo has ticked.
    pub async fn start(max_clients: usize) -> TestServer {
        Self::start_with(max_clients, server::config::DEFAULT_IDLE_TIMEOUT).await
    }

    /// As [`TestServer::start`], closing connections idle for `idle_timeout`.
    pub async fn start_with(max_clients: usize, idle_timeout: Duration) -> TestServer {
        Self::start_configured(max_clients, |config| config.idle_timeout = idle_timeout).await
    }

    /// As [`TestServer::start`], with the server settings changed by `edit`.
    pub async fn start_configured(
        max_clients: usize,
        edit: impl FnOnce(&mut ServerConfig),
    ) -> TestServer {
        Self::start_full(max_clients, edit, None).await
    }

    /// As [`TestServer::start_configured`]; with `volume_dirs`, the server sees the session through
    /// [`ConfinedVolumes`] as `voxhap serve --volume-dir` does.
    pub async fn start_full(
        max_clients: usize,
        edit: impl FnOnce(&mut ServerConfig),
        volume_dirs: Option<VolumeDirs>,
    ) -> TestServer {
        Self::start_session(
            max_clients,
            edit,
            volume_dirs,
            SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap()),
        )
        .await
    }

    /// As [`TestServer::start_full`], on a session started from `config` (real-time settings off).
    pub async fn start_session(
        max_clients: usize,
        edit: impl FnOnce(&mut ServerConfig),
        volume_dirs: Option<VolumeDirs>,
        mut config: SessionConfig,
    ) -> TestServer {
        config.rt = RtMode::Off;
        // Less spinning: several sessions may run at once on a small CI machine.
        config.spin_ns = 20_000;
        let session = Session::start(config).unwrap();
        let api = session.api();
        for _ in 0..400 {
            if api.snapshot().is_some() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        assert!(api.snapshot().is_some(), "the servo never ticked");
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let mut config = ServerConfig {
            token: TOKEN.to_owned(),
            max_clients,
            idle_timeout: server::config::DEFAULT_IDLE_TIMEOUT,
            header_timeout: voxhap::server::config::DEFAULT_HEADER_TIMEOUT,
            allowed_hosts: Vec::new(),
            allowed_origins: Vec::new(),
        };
        edit(&mut config);
        let shared: Arc<dyn SessionApi> = match volume_dirs {
            Some(dirs) => Arc::new(ConfinedVolumes::new(api.clone(), dirs)),
            None => api.clone(),
        };
        let task = tokio::spawn(server::run(listener, shared, config, async move {
            let _ = stopped.await;
        }));
        TestServer {
            addr,
            api,
            stop: Some(stop),
            task: Some(task),
            _session: session,
        }
    }

    /// Signals shutdown and waits for `run` to return (panics after 5 s).
    pub async fn shutdown(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(task) = self.task.take() {
            tokio::time::timeout(Duration::from_secs(5), task)
                .await
                .expect("run() returned after the shutdown signal")
                .unwrap()
                .unwrap();
        }
    }

    /// `GET path` → (status, JSON body).
    pub async fn get(&self, path: &str) -> (u16, Value) {
        let (status, _, body) = http(self.addr, "GET", path, None, "").await;
        (status, json(&body))
    }

    /// `method path` with `body` and the test token (or `token`) → (status, JSON body).
    pub async fn send(
        &self,
        method: &str,
        path: &str,
        token: Option<&str>,
        body: &str,
    ) -> (u16, Value) {
        let (status, _, text) = http(self.addr, method, path, token, body).await;
        (status, json(&text))
    }

    /// `POST path` with the right token.
    pub async fn post(&self, path: &str, body: &str) -> (u16, Value) {
        self.send("POST", path, Some(TOKEN), body).await
    }

    /// The scene generation the servo reports now.
    pub fn generation(&self) -> u64 {
        self.api.snapshot().unwrap().scene_generation
    }

    /// A WebSocket client (`query`: e.g. `rate=50`), with its hello message already read and checked.
    pub async fn ws(&self, query: &str) -> Ws {
        let (mut ws, _) =
            tokio_tungstenite::connect_async(format!("ws://{}/ws?{query}", self.addr))
                .await
                .expect("WebSocket connect");
        let hello = next_json(&mut ws).await;
        assert_eq!(hello["type"], "hello", "{hello}");
        ws
    }
}

fn json(text: &str) -> Value {
    serde_json::from_str(text).unwrap_or_else(|e| panic!("not JSON ({e}): {text:?}"))
}

/// One HTTP/1.1 request on a fresh connection → (status, headers in lower case, body).
pub async fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: &str,
) -> (u16, String, String) {
    let mut stream = TcpStream::connect(addr).await.unwrap();
    let auth = token
        .map(|t| format!("Authorization: Bearer {t}\r\n"))
        .unwrap_or_default();
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.unwrap();
    // A server may answer (413) before reading a large body and close: ignore a failed body write.
    let _ = stream.write_all(body.as_bytes()).await;
    let mut response = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut response))
        .await
        .expect("the server answered within 10 s");
    let text = String::from_utf8_lossy(&response).into_owned();
    let (head, body) = text
        .split_once("\r\n\r\n")
        .unwrap_or_else(|| panic!("no HTTP head in {text:?}"));
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no status in {head:?}"));
    let head = head.to_ascii_lowercase();
    let body = if head.contains("transfer-encoding: chunked") {
        dechunk(body)
    } else {
        body.to_owned()
    };
    (status, head, body)
}

fn dechunk(mut body: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = body.split_once("\r\n") {
        let size = usize::from_str_radix(size.trim(), 16).unwrap_or(0);
        if size == 0 {
            break;
        }
        out.push_str(&rest[..size]);
        body = &rest[size + 2..];
    }
    out
}

/// Sends `value` as one JSON text message.
pub async fn send_json(ws: &mut Ws, value: Value) {
    ws.send(Message::Text(value.to_string().into()))
        .await
        .unwrap();
}

/// The next text message as JSON (panics after 5 s, or on a close).
pub async fn next_json(ws: &mut Ws) -> Value {
    loop {
        let message = tokio::time::timeout(Duration::from_secs(5), ws.next())
            .await
            .expect("a message within 5 s")
            .expect("the stream is open")
            .expect("no WebSocket error");
        match message {
            Message::Text(text) => return json(text.as_str()),
            Message::Close(frame) => panic!("closed: {frame:?}"),
            _ => continue,
        }
    }
}

/// The next message that is not a state (a reply, an error, a slice).
pub async fn next_answer(ws: &mut Ws) -> Value {
    loop {
        let value = next_json(ws).await;
        if value["type"] != "state" {
            return value;
        }
    }
}

/// Reads until a close frame and returns its code (panics after 5 s).
pub async fn close_code(ws: &mut Ws) -> Option<u16> {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    loop {
        let message = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("a close frame within 5 s");
        match message {
            Some(Ok(Message::Close(frame))) => return frame.map(|f| u16::from(f.code)),
            Some(Ok(_)) => continue,
            Some(Err(error)) => panic!("WebSocket error before the close frame: {error}"),
            None => return None,
        }
    }
}

/// This process's resident set size (kB), from /proc/self/status.
pub fn rss_kb() -> u64 {
    proc_status_kb("self", "VmRSS")
}

/// A memory field (kB) of /proc/`pid`/status: `VmRSS` (resident now), `VmHWM` (the peak resident size).
pub fn proc_status_kb(pid: &str, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|line| line.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or_else(|| panic!("{field} in /proc/{pid}/status"))
}
