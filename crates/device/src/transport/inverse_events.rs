//! The Haply Inverse Service's events channel: a read-only WebSocket (default ws://localhost:10020) on which
//! the service reports safety triggers, device connections and control-rate anomalies, one message per event
//! (docs.haply.co/inverseSDK/service/api/events "Events Channel"; docs.haply.co/inverseSDK/service/events
//! "Events & Monitoring").
//!
//! Where it sits: its own thread beside the simulation channel's I/O thread ([`super::io`]); it never touches
//! the servo thread. Safety events for the driven device go through a lock-free ring ([`EventChannel::pop`],
//! called by the driver on the servo thread) and become device faults (the driver's `take_event`), so the
//! supervisor zeroes the force on the tick it reads them. Everything else worth telling is a notice: printed
//! on stderr and kept ([`EventChannel::notices`]).
//!
//! Event shape (Haply, "Events & Monitoring"): `{"name": "device-safety-triggered", "category": "device",
//! "level": "error", "data": {"device_family": "inverse", "device_id": "049D", "safety_type":
//! "ebrake_triggered"}, "message": "…"}`. `safety_type` is one of `ebrake_triggered` (error: emergency brake
//! engaged, device locked), `ebrake_released` (notice), `fod_stage_changed` (warning/info), `stall_detected`
//! (warning: motor stall), `stability_ceiling` (warning: stability ceiling reached). Rate reports: Haply's
//! client names `system-rate-report` with `min_frequency`, `max_frequency`, `mean_frequency`,
//! `median_frequency` (crate `haply` 1.3.1, src/interfaces/events.rs:64-69).
//!
//! The channel is optional: a service without one (before 3.5) or a refused connection is said once as a
//! notice, and the thread tries again every [`RETRY_INTERVAL`]. Its stop is bounded by [`READ_TIMEOUT`] and
//! the connect timeout, whatever the service does.

use serde_json::Value;
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tungstenite::Message;

/// Safety events queued for the servo thread (it takes them every tick; a few per session are usual).
pub const EVENT_RING_CAPACITY: usize = 64;
/// Longest the thread blocks on a read before it looks at its stop flag.
pub const READ_TIMEOUT: Duration = Duration::from_millis(50);
/// Time allowed for the TCP connect and the WebSocket handshake.
pub const CONNECT_TIMEOUT: Duration = Duration::from_millis(500);
/// Wait between attempts to reach the channel.
pub const RETRY_INTERVAL: Duration = Duration::from_secs(1);
/// Notices kept for [`EventChannel::notices`] (the oldest are dropped; all were printed).
pub const MAX_NOTICES: usize = 256;

/// A safety event of the driven device, as Haply names it (`safety_type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafetyEvent {
    /// `ebrake_triggered`: the emergency brake engaged; the device is locked.
    EbrakeTriggered,
    /// `stall_detected`: a motor stalled.
    StallDetected,
    /// `stability_ceiling`: the stability ceiling was reached.
    StabilityCeiling,
}

/// What one event message means for voxhap.
#[derive(Debug, Clone, PartialEq)]
pub enum Classified {
    /// A safety event of the driven device: a device fault.
    Fault(SafetyEvent, String),
    /// Worth telling the user (rate warnings, e-brake released, other warnings).
    Notice(String),
    /// Nothing for this session (another device, an informational event).
    Ignore,
}

/// The simulation channel's host on the events port: `ws://HOST:PORT/…` gives `ws://HOST:10020`.
pub fn default_events_url(simulation_url: &str) -> String {
    let rest = simulation_url
        .strip_prefix("ws://")
        .unwrap_or(simulation_url);
    let authority = rest.split('/').next().unwrap_or(rest);
    let host = authority
        .rsplit_once(':')
        .map_or(authority, |(host, _)| host);
    format!("ws://{host}:{}", super::DEFAULT_EVENTS_PORT)
}

fn text_of(value: &Value) -> Option<String> {
    match value {
        Value::String(s) => Some(s.clone()),
        Value::Number(n) => Some(n.to_string()),
        _ => None,
    }
}

/// What an event message means for a session driving `device_id` (module docs for the shapes).
pub fn classify(text: &str, device_id: &str) -> Classified {
    let Ok(value) = serde_json::from_str::<Value>(text) else {
        return Classified::Notice(format!(
            "an events-channel message that is not JSON: {:?}",
            text.chars().take(120).collect::<String>()
        ));
    };
    let name = value.get("name").and_then(text_of).unwrap_or_default();
    let level = value.get("level").and_then(text_of).unwrap_or_default();
    let data = value.get("data").cloned().unwrap_or(Value::Null);
    let message = value.get("message").and_then(text_of).unwrap_or_default();
    let said = |what: &str| {
        if message.is_empty() {
            format!("{what} ({name}, level {level})")
        } else {
            format!("{what} ({name}, level {level}): {message}")
        }
    };
    // An event naming another device is not ours; one naming none concerns every device.
    if let Some(id) = data.get("device_id").and_then(text_of) {
        if id != device_id {
            return Classified::Ignore;
        }
    }
    if let Some(safety) = data.get("safety_type").and_then(text_of) {
        let event = match safety.as_str() {
            "ebrake_triggered" => SafetyEvent::EbrakeTriggered,
            "stall_detected" => SafetyEvent::StallDetected,
            "stability_ceiling" => SafetyEvent::StabilityCeiling,
            "ebrake_released" => {
                return Classified::Notice(said(
                    "the emergency brake was released (voxhap stays faulted until the operator clears it)",
                ))
            }
            other => return Classified::Notice(said(&format!("safety notice {other:?}"))),
        };
        return Classified::Fault(event, said(&format!("safety event {safety:?}")));
    }
    if name.contains("rate") {
        let frequencies = [
            "min_frequency",
            "mean_frequency",
            "median_frequency",
            "max_frequency",
        ]
        .iter()
        .filter_map(|key| Some(format!("{key} {}", data.get(*key).and_then(text_of)?)))
        .collect::<Vec<_>>()
        .join(", ");
        return Classified::Notice(said(&format!("control rate report [{frequencies}]")));
    }
    match level.as_str() {
        "warning" | "error" | "critical" | "panic" => Classified::Notice(said("event")),
        _ => Classified::Ignore,
    }
}

/// Counters and notices shared with the events thread.
#[derive(Debug, Default)]
pub struct EventsShared {
    stop: AtomicBool,
    /// The channel is connected now.
    pub connected: AtomicBool,
    /// Messages received.
    pub received: AtomicU64,
    /// Safety events that found the ring full (never expected: the servo thread empties it every tick).
    pub dropped: AtomicU64,
    notices: Mutex<Vec<String>>,
}

impl EventsShared {
    fn notice(&self, text: String) {
        eprintln!("voxhap: Haply Inverse Service: {text}");
        let mut notices = self.notices.lock().unwrap_or_else(|e| e.into_inner());
        if notices.len() >= MAX_NOTICES {
            notices.remove(0);
        }
        notices.push(text);
    }
}

/// The servo thread's end of the events channel.
#[derive(Debug)]
pub struct EventChannel {
    events: rtrb::Consumer<SafetyEvent>,
    /// Counters and notices.
    pub shared: Arc<EventsShared>,
    thread: Option<JoinHandle<()>>,
}

impl EventChannel {
    /// Starts the events thread for `url`, keeping safety events about `device_id`.
    pub fn start(url: String, device_id: String) -> EventChannel {
        let (tx, events) = rtrb::RingBuffer::new(EVENT_RING_CAPACITY);
        let shared = Arc::new(EventsShared::default());
        let thread_shared = shared.clone();
        let thread = std::thread::Builder::new()
            .name("voxhap-inverse-events".to_owned())
            .spawn(move || run(&url, &device_id, tx, &thread_shared))
            .ok();
        if thread.is_none() {
            shared.notice(
                "could not start the events thread: e-brake and stall events will not reach voxhap"
                    .to_owned(),
            );
        }
        EventChannel {
            events,
            shared,
            thread,
        }
    }

    /// The next safety event, if any (lock-free, allocation-free: for the servo thread).
    pub fn pop(&mut self) -> Option<SafetyEvent> {
        self.events.pop().ok()
    }

    /// Every notice so far (at most [`MAX_NOTICES`], oldest first).
    pub fn notices(&self) -> Vec<String> {
        self.shared
            .notices
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Stops the thread and waits for it (bounded by [`READ_TIMEOUT`] and [`CONNECT_TIMEOUT`]).
    pub fn shut_down(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for EventChannel {
    fn drop(&mut self) {
        self.shut_down();
    }
}

type EventSocket = tungstenite::WebSocket<TcpStream>;

/// Why the events channel could not be opened: each names the URL (or the address it gave) and what failed.
#[derive(Debug, thiserror::Error)]
pub enum EventsOpenError {
    /// The URL does not start with `ws://` (the service listens on plain WebSocket on localhost).
    #[error("{url:?} is not a ws:// URL")]
    NotWebSocket {
        /// The URL given.
        url: String,
    },
    /// The URL's host and port could not be resolved.
    #[error("the host and port {authority:?} of {url} cannot be resolved: {source}")]
    Resolve {
        /// The URL given.
        url: String,
        /// Its `HOST:PORT`.
        authority: String,
        /// What the resolver said.
        source: std::io::Error,
    },
    /// The host resolved to no address.
    #[error("the host and port {authority:?} of {url} resolve to no address")]
    NoAddress {
        /// The URL given.
        url: String,
        /// Its `HOST:PORT`.
        authority: String,
    },
    /// The TCP connection (or setting its timeouts) failed.
    #[error("{during} {address} (from {url}): {source}")]
    Socket {
        /// The URL given.
        url: String,
        /// The address it resolved to.
        address: SocketAddr,
        /// What was being done.
        during: &'static str,
        /// What the socket said.
        source: std::io::Error,
    },
    /// The WebSocket upgrade failed.
    #[error("the WebSocket handshake with {url} failed: {source}")]
    Handshake {
        /// The URL given.
        url: String,
        /// What tungstenite said.
        source: Box<tungstenite::Error>,
    },
    /// The WebSocket upgrade did not finish within [`CONNECT_TIMEOUT`].
    #[error("the WebSocket handshake with {url} did not finish within {} ms", CONNECT_TIMEOUT.as_millis())]
    HandshakeTimeout {
        /// The URL given.
        url: String,
    },
}

fn open(url: &str) -> Result<EventSocket, EventsOpenError> {
    let authority = url
        .strip_prefix("ws://")
        .ok_or_else(|| EventsOpenError::NotWebSocket {
            url: url.to_owned(),
        })?
        .split('/')
        .next()
        .unwrap_or_default();
    let address = authority
        .to_socket_addrs()
        .map_err(|source| EventsOpenError::Resolve {
            url: url.to_owned(),
            authority: authority.to_owned(),
            source,
        })?
        .next()
        .ok_or_else(|| EventsOpenError::NoAddress {
            url: url.to_owned(),
            authority: authority.to_owned(),
        })?;
    let socket_error = |during: &'static str| {
        move |source| EventsOpenError::Socket {
            url: url.to_owned(),
            address,
            during,
            source,
        }
    };
    let stream = TcpStream::connect_timeout(&address, CONNECT_TIMEOUT)
        .map_err(socket_error("cannot connect to"))?;
    stream
        .set_read_timeout(Some(CONNECT_TIMEOUT))
        .and_then(|()| stream.set_write_timeout(Some(CONNECT_TIMEOUT)))
        .map_err(socket_error("cannot set the timeouts of the socket to"))?;
    let (socket, _) = tungstenite::client(url, stream).map_err(|error| match error {
        tungstenite::HandshakeError::Failure(source) => EventsOpenError::Handshake {
            url: url.to_owned(),
            source: Box::new(source),
        },
        tungstenite::HandshakeError::Interrupted(_) => EventsOpenError::HandshakeTimeout {
            url: url.to_owned(),
        },
    })?;
    socket
        .get_ref()
        .set_read_timeout(Some(READ_TIMEOUT))
        .map_err(socket_error("cannot set the read timeout of the socket to"))?;
    Ok(socket)
}

fn sleep_unless_stopped(shared: &EventsShared, total: Duration) {
    let step = Duration::from_millis(20);
    let mut slept = Duration::ZERO;
    while slept < total && !shared.stop.load(Ordering::Acquire) {
        std::thread::sleep(step);
        slept += step;
    }
}

fn run(url: &str, device_id: &str, mut tx: rtrb::Producer<SafetyEvent>, shared: &EventsShared) {
    let mut said_unreachable = false;
    while !shared.stop.load(Ordering::Acquire) {
        let mut socket = match open(url) {
            Ok(socket) => socket,
            Err(reason) => {
                if !said_unreachable {
                    said_unreachable = true;
                    shared.notice(format!(
                        "its events channel cannot be reached ({reason}); e-brake, stall and stability \
                         events will not reach voxhap until it can (retrying every {} s)",
                        RETRY_INTERVAL.as_secs()
                    ));
                }
                sleep_unless_stopped(shared, RETRY_INTERVAL);
                continue;
            }
        };
        shared.connected.store(true, Ordering::Release);
        if said_unreachable {
            shared.notice(format!("its events channel {url} is connected"));
            said_unreachable = false;
        }
        while !shared.stop.load(Ordering::Acquire) {
            let text = match socket.read() {
                Ok(Message::Text(text)) => text.to_string(),
                Ok(Message::Binary(bytes)) => String::from_utf8_lossy(&bytes).into_owned(),
                Ok(Message::Close(_)) => break,
                Ok(_) => continue,
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    continue
                }
                Err(_) => break,
            };
            shared.received.fetch_add(1, Ordering::Relaxed);
            match classify(&text, device_id) {
                Classified::Fault(event, said) => {
                    if tx.push(event).is_err() {
                        shared.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    shared.notice(said);
                }
                Classified::Notice(said) => shared.notice(said),
                Classified::Ignore => {}
            }
        }
        shared.connected.store(false, Ordering::Release);
        if !shared.stop.load(Ordering::Acquire) {
            shared.notice(format!("its events channel {url} closed; reconnecting"));
            said_unreachable = true;
            sleep_unless_stopped(shared, RETRY_INTERVAL);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each reason the channel cannot be opened names what was given and what failed: a URL of another scheme,
    /// a port nobody listens on (a listener on 127.0.0.1 port 0, closed before the connect), a listener that is
    /// not a WebSocket server (it answers the upgrade with plain text).
    #[test]
    fn an_unreachable_events_channel_says_what_was_given_and_what_failed() {
        let error = open("http://127.0.0.1:10020").unwrap_err();
        assert!(
            matches!(error, EventsOpenError::NotWebSocket { .. }),
            "{error:?}"
        );
        assert!(
            error
                .to_string()
                .contains("\"http://127.0.0.1:10020\" is not a ws:// URL"),
            "{error}"
        );

        let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = closed.local_addr().unwrap();
        drop(closed);
        let url = format!("ws://{address}");
        let error = open(&url).unwrap_err();
        assert!(
            matches!(&error, EventsOpenError::Socket { address: a, .. } if *a == address),
            "{error:?}"
        );
        let said = error.to_string();
        assert!(
            said.contains(&address.to_string()) && said.contains("cannot connect"),
            "{said}"
        );

        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("ws://{}/", listener.local_addr().unwrap());
        let server = std::thread::spawn(move || {
            use std::io::{Read, Write};
            let (mut stream, _) = listener.accept().unwrap();
            let mut request = [0u8; 1024];
            let _ = stream.read(&mut request);
            let _ = stream.write_all(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nno");
        });
        let error = open(&url).unwrap_err();
        server.join().unwrap();
        assert!(
            matches!(error, EventsOpenError::Handshake { .. }),
            "{error:?}"
        );
        assert!(error.to_string().contains(&url), "{error}");
    }

    #[test]
    fn the_events_url_is_the_simulation_host_on_port_10020() {
        assert_eq!(
            default_events_url("ws://127.0.0.1:10001"),
            "ws://127.0.0.1:10020"
        );
        assert_eq!(
            default_events_url("ws://localhost:9/x"),
            "ws://localhost:10020"
        );
    }

    #[test]
    fn documented_safety_events_of_our_device_are_faults() {
        // The event shape of docs.haply.co "Events & Monitoring", with each documented safety_type.
        let event = |safety: &str, id: &str| {
            format!(
                r#"{{"name":"device-safety-triggered","category":"device","level":"error",
                   "data":{{"device_family":"inverse","device_id":"{id}","safety_type":"{safety}"}},"message":"m"}}"#
            )
        };
        for (safety, expected) in [
            ("ebrake_triggered", SafetyEvent::EbrakeTriggered),
            ("stall_detected", SafetyEvent::StallDetected),
            ("stability_ceiling", SafetyEvent::StabilityCeiling),
        ] {
            assert!(
                matches!(classify(&event(safety, "049D"), "049D"), Classified::Fault(e, _) if e == expected),
                "{safety}"
            );
            assert_eq!(classify(&event(safety, "0A11"), "049D"), Classified::Ignore);
        }
        for notice in ["ebrake_released", "fod_stage_changed"] {
            assert!(matches!(
                classify(&event(notice, "049D"), "049D"),
                Classified::Notice(_)
            ));
        }
    }

    #[test]
    fn rate_reports_and_warnings_are_notices_and_info_is_ignored() {
        // Haply's client's rate report (crate haply 1.3.1, src/interfaces/events.rs:64-69).
        let rate = r#"{"name":"system-rate-report","category":"system","level":"warning",
            "data":{"min_frequency":310,"max_frequency":1020,"mean_frequency":900,"median_frequency":950}}"#;
        match classify(rate, "049D") {
            Classified::Notice(text) => assert!(text.contains("min_frequency 310"), "{text}"),
            other => panic!("{other:?}"),
        }
        let busy = r#"{"name":"device-busy","category":"device","level":"warning","data":{"device_id":"049D"}}"#;
        assert!(matches!(classify(busy, "049D"), Classified::Notice(_)));
        let connected = r#"{"name":"device-connected","category":"device","level":"info","data":{"device_id":"049D"}}"#;
        assert_eq!(classify(connected, "049D"), Classified::Ignore);
    }
}
