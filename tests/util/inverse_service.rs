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

use serde_json::{json, Value};
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
    stop: AtomicBool,
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

fn serve(stream: TcpStream, shared: &ServiceShared) {
    stream.set_nodelay(true).unwrap();
    stream.set_nonblocking(false).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_millis(5)))
        .unwrap();
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
    while !shared.stop.load(Ordering::Acquire) {
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
        // One state update per message.
        let reply = if shared
            .malformed_replies
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
            .is_ok()
        {
            malformed_turn += 1;
            match malformed_turn % 3 {
                0 => Message::text("{\"inverse3\": [ {\"device_id\": "),
                1 => Message::binary(vec![0xff, 0x00, 0x13]),
                _ => Message::text(json!({"inverse3": [{"device_id": DEVICE_ID}]}).to_string()),
            }
        } else {
            let position = *shared.position_m.lock().unwrap();
            Message::text(
                json!({"inverse3": [{"device_id": DEVICE_ID, "state": state(position), "status": {}}]})
                    .to_string(),
            )
        };
        let delay_ms = shared.delay_next_reply_ms.swap(0, Ordering::AcqRel);
        if delay_ms > 0 {
            std::thread::sleep(Duration::from_millis(delay_ms));
        }
        if socket.send(reply).is_err() {
            return;
        }
    }
    // Stopped: drop the connection without a close handshake, as a killed service would.
}
