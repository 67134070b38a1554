//! A test double of the Haply Inverse Service's simulation channel, written from Haply's published service
//! documentation (docs.haply.co/inverseSDK/service: "Simulation Channel", "WebSocket Protocol", "Control
//! Commands"), not from voxhap's driver. A real WebSocket server on 127.0.0.1 (port 0, or a given port to come
//! back on after a "restart").
//!
//! Behaviour: on connect it sends the initial inventory (`session_id` and, per Inverse3, `device_id`, `config`,
//! `state`, `status`); then exactly one state update (`state` and `status` of every device) per client message,
//! whatever the message. Every `set_cursor_force` vector it receives is logged with its device id, and so are
//! messages it cannot parse. A test can move the handle, make the next replies malformed, hold the next reply
//! back for a while (a busy service: the state is the one at the message's arrival, sent late), or stop the
//! service (every connection dropped, the port closed) and start it again on the same port.
//!
//! Misbehaviours outside Haply's documentation, for the driver's robustness: more than one reply per message
//! (`replies_per_message`), an unsolicited state update every `unsolicited_every_ms`, no replies at all
//! (`mute`: messages are still read and logged), dropping each connection after a number of replies
//! (`close_after_replies`), dropping each connection at once without a handshake (`refuse`), and a
//! slow-loris handshake (`slow_handshake_from`: from that connection on, the HTTP answer is sent one byte per
//! 100 ms and never ends). With `stamp`, the position of every state message carries its index (1, 2, ...
//! over the double's life): x = [`STAMP_BASE_M`] + index · [`STAMP_STEP_M`]; `written` is the index of the
//! last state message whose write has returned.

use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tungstenite::Message;

/// What the double received.
#[derive(Debug, Clone, PartialEq)]
pub enum ServiceEvent {
    /// A client connected (the inventory was sent).
    Connected,
    /// A `set_cursor_force` for this device id with this vector (N).
    Force { device_id: String, vector: [f64; 3] },
    /// The session configuration of a message.
    Session(Value),
    /// A message that is not JSON.
    Unparsable(String),
}

/// State shared with the server threads.
#[derive(Debug)]
pub struct ServiceShared {
    pub log: Mutex<Vec<ServiceEvent>>,
    pub position_m: Mutex<[f64; 3]>,
    /// The next this-many replies are malformed (alternately not JSON, a binary frame, and JSON without state).
    pub malformed_replies: AtomicU32,
    /// The next reply is sent this many milliseconds late (then back to 0).
    pub delay_next_reply_ms: AtomicU64,
    /// State updates sent per message received (documented: 1).
    pub replies_per_message: AtomicU32,
    /// An unsolicited state update this often (ms; 0: never, as documented).
    pub unsolicited_every_ms: AtomicU64,
    /// Positions carry the message index (module docs).
    pub stamp: AtomicBool,
    /// Index of the last state message whose write returned (with `stamp`; 0 before the first).
    pub written: AtomicU64,
    next_index: AtomicU64,
    /// Read and log messages, answer none.
    pub mute: AtomicBool,
    /// Drop each connection after this many replies (0: never).
    pub close_after_replies: AtomicU32,
    /// Drop each connection as soon as it is accepted.
    pub refuse: AtomicBool,
    /// Connections numbered from this one on (1 is the first) get the slow-loris handshake (0: none).
    pub slow_handshake_from: AtomicU32,
    /// TCP connections accepted.
    pub accepted: AtomicU32,
    stop: AtomicBool,
}

/// Where stamped positions start (m).
pub const STAMP_BASE_M: f64 = -0.05;
/// Stamped positions advance by this per message (m): 1 µm, a plausible drift of about 1-2 mm/s.
pub const STAMP_STEP_M: f64 = 1e-6;

/// The message index a stamped position carries.
pub fn stamp_of(x_m: f64) -> u64 {
    ((x_m - STAMP_BASE_M) / STAMP_STEP_M).round() as u64
}

/// The running double.
pub struct InverseService {
    pub shared: Arc<ServiceShared>,
    address: SocketAddr,
    thread: Option<JoinHandle<()>>,
}

pub const DEVICE_ID: &str = "049D";

fn inventory(position: [f64; 3]) -> Value {
    // The documented inventory example ("WebSocket Protocol", step 1), trimmed to the fields it lists.
    json!({
        "session_id": 7,
        "inverse3": [{
            "device_id": DEVICE_ID,
            "config": {
                "type": "inverse3",
                "port": "COM12",
                "device_info": {"major_version": 7, "minor_version": 4, "id": DEVICE_ID, "device_type": 4, "uuid": "…"},
                "handedness": "right",
                "basis": {"permutation": "XYZ"}
            },
            "state": state(position),
            "status": {}
        }]
    })
}

fn state(position: [f64; 3]) -> Value {
    json!({
        "cursor_position": {"x": position[0], "y": position[1], "z": position[2]},
        "cursor_velocity": {"x": 0.0, "y": 0.0, "z": 0.0},
        "control_mode": "idle"
    })
}

impl InverseService {
    /// Starts on 127.0.0.1, port 0.
    pub fn start() -> InverseService {
        let shared = Arc::new(ServiceShared {
            log: Mutex::new(Vec::new()),
            position_m: Mutex::new([0.0, -0.12, 0.15]),
            malformed_replies: AtomicU32::new(0),
            delay_next_reply_ms: AtomicU64::new(0),
            replies_per_message: AtomicU32::new(1),
            unsolicited_every_ms: AtomicU64::new(0),
            stamp: AtomicBool::new(false),
            written: AtomicU64::new(0),
            next_index: AtomicU64::new(0),
            mute: AtomicBool::new(false),
            close_after_replies: AtomicU32::new(0),
            refuse: AtomicBool::new(false),
            slow_handshake_from: AtomicU32::new(0),
            accepted: AtomicU32::new(0),
            stop: AtomicBool::new(false),
        });
        Self::start_on("127.0.0.1:0".parse().unwrap(), shared)
    }

    fn start_on(address: SocketAddr, shared: Arc<ServiceShared>) -> InverseService {
        let (address, thread) = spawn(address, &shared);
        InverseService {
            shared,
            address,
            thread: Some(thread),
        }
    }

    /// `ws://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("ws://{}", self.address)
    }

    /// Stops the service: every connection and the listening socket close.
    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }

    /// Starts again (after [`InverseService::stop`]) on the same port, keeping the log.
    pub fn start_again(&mut self) {
        self.stop();
        let (_, thread) = spawn(self.address, &self.shared);
        self.thread = Some(thread);
    }

    /// Every event so far.
    pub fn events(&self) -> Vec<ServiceEvent> {
        self.shared.log.lock().unwrap().clone()
    }

    /// Every force vector received, in order.
    pub fn forces(&self) -> Vec<[f64; 3]> {
        self.events()
            .into_iter()
            .filter_map(|e| match e {
                ServiceEvent::Force { vector, .. } => Some(vector),
                _ => None,
            })
            .collect()
    }

    /// Moves the handle.
    pub fn set_position(&self, position_m: [f64; 3]) {
        *self.shared.position_m.lock().unwrap() = position_m;
    }
}

impl Drop for InverseService {
    fn drop(&mut self) {
        self.stop();
    }
}

fn spawn(address: SocketAddr, shared: &Arc<ServiceShared>) -> (SocketAddr, JoinHandle<()>) {
    // std sets SO_REUSEADDR on Unix, so a restart can bind the same port at once.
    let listener = TcpListener::bind(address).expect("bind the Inverse Service double");
    listener.set_nonblocking(true).unwrap();
    let address = listener.local_addr().unwrap();
    shared.stop.store(false, Ordering::Release);
    let shared = shared.clone();
    (
        address,
        std::thread::spawn(move || accept_loop(listener, &shared)),
    )
}

fn accept_loop(listener: TcpListener, shared: &Arc<ServiceShared>) {
    let mut connections = Vec::new();
    while !shared.stop.load(Ordering::Acquire) {
        match listener.accept() {
            Ok((stream, _)) => {
                let shared = shared.clone();
                connections.push(std::thread::spawn(move || serve(stream, &shared)));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
    }
    for connection in connections {
        let _ = connection.join();
    }
}

fn vec3(value: &Value) -> [f64; 3] {
    let get = |axis: &str| value.get(axis).and_then(Value::as_f64).unwrap_or(0.0);
    [get("x"), get("y"), get("z")]
}

/// A state message for the handle where the double has it, stamped when asked: returns it and its index.
fn state_message(shared: &ServiceShared) -> (Message, u64) {
    let mut position = *shared.position_m.lock().unwrap();
    let index = shared.next_index.fetch_add(1, Ordering::AcqRel) + 1;
    if shared.stamp.load(Ordering::Acquire) {
        position[0] = STAMP_BASE_M + index as f64 * STAMP_STEP_M;
    }
    let message = Message::text(
        json!({"inverse3": [{"device_id": DEVICE_ID, "state": state(position), "status": {}}]})
            .to_string(),
    );
    (message, index)
}

/// The slow-loris handshake: reads the HTTP request, then answers one byte per 100 ms, a header line after
/// another, until the client goes or the double stops.
fn slow_handshake(mut stream: TcpStream, shared: &ServiceShared) {
    let mut request = Vec::new();
    let mut buffer = [0u8; 1024];
    while !request.windows(4).any(|w| w == b"\r\n\r\n") {
        if shared.stop.load(Ordering::Acquire) {
            return;
        }
        match stream.read(&mut buffer) {
            Ok(0) => return,
            Ok(n) => request.extend_from_slice(&buffer[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => return,
        }
    }
    let text = String::from_utf8_lossy(&request).into_owned();
    let key = text
        .lines()
        .find_map(|line| {
            let (name, value) = line.split_once(':')?;
            name.eq_ignore_ascii_case("sec-websocket-key")
                .then(|| value.trim().to_owned())
        })
        .unwrap_or_default();
    let accept = tungstenite::handshake::derive_accept_key(key.as_bytes());
    let head = format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n"
    );
    let bytes = head.bytes().chain(b"X-Slow: 1\r\n".iter().copied().cycle());
    for byte in bytes {
        if shared.stop.load(Ordering::Acquire) || stream.write_all(&[byte]).is_err() {
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn serve(stream: TcpStream, shared: &ServiceShared) {
    let number = shared.accepted.fetch_add(1, Ordering::AcqRel) + 1;
    if shared.refuse.load(Ordering::Acquire) {
        return;
    }
    stream.set_nodelay(true).unwrap();
    stream.set_nonblocking(false).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_millis(5)))
        .unwrap();
    let slow_from = shared.slow_handshake_from.load(Ordering::Acquire);
    if slow_from != 0 && number >= slow_from {
        slow_handshake(stream, shared);
        return;
    }
    let Ok(mut socket) = tungstenite::accept(stream) else {
        return;
    };
    let position = *shared.position_m.lock().unwrap();
    if socket
        .send(Message::text(inventory(position).to_string()))
        .is_err()
    {
        return;
    }
    shared.log.lock().unwrap().push(ServiceEvent::Connected);
    let mut malformed_turn = 0u32;
    let mut replies = 0u32;
    let mut last_unsolicited = std::time::Instant::now();
    while !shared.stop.load(Ordering::Acquire) {
        let every_ms = shared.unsolicited_every_ms.load(Ordering::Acquire);
        if every_ms > 0 && last_unsolicited.elapsed() >= Duration::from_millis(every_ms) {
            last_unsolicited = std::time::Instant::now();
            let (update, index) = state_message(shared);
            if socket.send(update).is_err() {
                return;
            }
            shared.written.store(index, Ordering::Release);
        }
        let message = match socket.read() {
            Ok(Message::Text(text)) => text.to_string(),
            Ok(Message::Binary(bytes)) => String::from_utf8_lossy(&bytes).into_owned(),
            Ok(Message::Close(_)) => return,
            Ok(_) => continue,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(_) => return,
        };
        match serde_json::from_str::<Value>(&message) {
            Ok(value) => {
                let mut log = shared.log.lock().unwrap();
                if let Some(session) = value.get("session") {
                    log.push(ServiceEvent::Session(session.clone()));
                }
                for device in value["inverse3"].as_array().into_iter().flatten() {
                    if let Some(force) = device["commands"].get("set_cursor_force") {
                        log.push(ServiceEvent::Force {
                            device_id: device["device_id"].as_str().unwrap_or("").to_owned(),
                            vector: vec3(&force["vector"]),
                        });
                    }
                }
            }
            Err(_) => shared
                .log
                .lock()
                .unwrap()
                .push(ServiceEvent::Unparsable(message)),
        }
        if shared.mute.load(Ordering::Acquire) {
            continue;
        }
        // One state update per message (or as many as asked).
        let delay_ms = shared.delay_next_reply_ms.swap(0, Ordering::AcqRel);
        let count = shared.replies_per_message.load(Ordering::Acquire).max(1);
        for _ in 0..count {
            let (reply, index) = if shared
                .malformed_replies
                .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
                .is_ok()
            {
                malformed_turn += 1;
                let reply = match malformed_turn % 3 {
                    0 => Message::text("{\"inverse3\": [ {\"device_id\": "),
                    1 => Message::binary(vec![0xff, 0x00, 0x13]),
                    _ => Message::text(json!({"inverse3": [{"device_id": DEVICE_ID}]}).to_string()),
                };
                (reply, None)
            } else {
                let (reply, index) = state_message(shared);
                (reply, Some(index))
            };
            if delay_ms > 0 {
                std::thread::sleep(Duration::from_millis(delay_ms));
            }
            if socket.send(reply).is_err() {
                return;
            }
            if let Some(index) = index {
                shared.written.store(index, Ordering::Release);
            }
        }
        replies += 1;
        let close_after = shared.close_after_replies.load(Ordering::Acquire);
        if close_after != 0 && replies >= close_after {
            return;
        }
    }
    // Stopped: drop the connection without a close handshake, as a killed service would.
}
