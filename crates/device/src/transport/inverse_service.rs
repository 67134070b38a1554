//! The Haply Inverse Service's simulation channel (JSON over WebSocket), run on a dedicated I/O thread so the
//! servo thread never touches a socket.
//!
//! Where it sits: under the Haply Inverse3 driver (crates/device/src/drivers/haply_inverse.rs). The servo thread pushes
//! one force command per tick into a lock-free ring (rtrb) and reads the newest device state from a triple buffer,
//! as the recorder hands trace rows to its writer thread (crates/servo/src/recorder.rs); this thread does the WebSocket
//! exchange, parses JSON and allocates as it needs.
//!
//! Protocol (Haply's published service documentation, docs.haply.co/inverseSDK/service: "Simulation Channel",
//! "WebSocket Protocol", "Control Commands", "Basis Permutation"): the service listens on ws://localhost:10001;
//! on connect it sends one inventory message (`{"session_id":…, "inverse3":[{"device_id":"049D", "config":{…},
//! "state":{…}, "status":{…}}]}`); after that it sends exactly one state update (device `state` and `status`) for
//! every message the client sends. A force is the per-tick, non-persistent command
//! `{"inverse3":[{"device_id":ID,"commands":{"set_cursor_force":{"vector":{"x":…,"y":…,"z":…}}}}]}` in newtons;
//! when commands stop the device returns to idle. The first message ([`setup_message`]) sets the session's
//! profile and basis, the device's preset `defaults` and basis `XYZ` (replacing any mount another program left)
//! and asks for the full state; [`handshake`] reads back preset, basis, mount and workspace transform from the
//! answer ([`check_configuration`]) and fails on any difference, so positions (m), velocities (m/s) and forces
//! (N) are in Haply's own right-handed frame (+X right, +Y forward, +Z up, origin on the mounting plate)
//! whatever an earlier application configured; the device profile maps that frame onto the scene. State fields
//! that are absent keep their previous value (the service's partial-update semantics). The events channel
//! (port 10020) runs on its own thread ([`events`]). [`handshake`] leaves the set-up, non-blocking socket
//! ([`io::ServicePort`]); the driver's I/O thread (`drivers/haply_inverse_io.rs`) drives it, and its protocol
//! core (`drivers/haply_inverse_link.rs`) keeps the invariants below.
//!
//! The thread sends a force as soon as one is queued (coalescing to the newest if several are: it never falls
//! behind) and reads the reply. Its socket is non-blocking: it waits with poll(2), and before every send,
//! right after it and while waiting for the reply it **drains** the socket, reading every complete message
//! already there, so a service that sends more than one message per command (a second reply, unsolicited
//! updates) builds no backlog: the state published is always the newest received. Invariants:
//!
//! - Replies are counted against the messages sent, in order. A message that arrives when every message
//!   sent has had its reply is an **extra**: it updates the position, is counted (`extra`; the driver reports
//!   it as [`crate::DeviceEvent::Surplus`]) and never advances the label below.
//! - Each published state is labelled with the sequence of the force it answers at the latest: its reply's
//!   message, but never a force sent after the socket was last found empty (`floor`). A reply that came after
//!   `reply_timeout` (a busy service) is read later and labelled with its own, older sequence; a message
//!   counted against the wrong force because of extras is at most as new as the newest force sent before the
//!   drain that preceded it, since TCP keeps the order. So the age the driver reports is never younger than
//!   the message is, whatever the service sends.
//! - More than [`MAX_DRAIN_MESSAGES`] in one drain (a flood), a send that cannot leave within
//!   [`WRITE_TIMEOUT`] (a service that reads nothing) or a socket error ends the thread and raises
//!   `link_down`; the driver then reports a disconnect and the supervisor reconnects with a new driver (with
//!   back-off, `servo::device::reconnect`). The stop therefore never waits on the service for more than a few
//!   write timeouts.
//! - The connect (TCP, WebSocket handshake, inventory, the answer to the session configuration) has one
//!   overall deadline, `connect_timeout`: every read and write of it gets only the time left
//!   ([`ServiceStream`]), so a service that sends its handshake one byte at a time fails the open at the
//!   deadline.
//!
//! With no force for 100 ms the thread sends a zero-force keepalive (Haply's own tutorials do the same).
//! Malformed frames (not JSON, binary, no state for our device) are counted and skipped. On stop the thread
//! sends a zero force, then a WebSocket close.

pub use super::inverse_wire::{
    force_message, parse_frame_text, setup_message, WireConfig, WireError, WireFrame, WireInverse3,
    WireState, WireTransform, SESSION_BASIS, SESSION_PRESET,
};
use crate::DeviceError;
use glam::DVec3;
use std::io::{Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

#[path = "inverse_events.rs"]
pub mod events;
#[path = "inverse_io.rs"]
pub mod io;
#[cfg(test)]
#[path = "inverse_service_tests.rs"]
mod tests;

/// The service's default events channel port (docs.haply.co "Events Channel": ws://localhost:10020).
pub const DEFAULT_EVENTS_PORT: u16 = 10020;

/// The service's default simulation channel.
pub const DEFAULT_URL: &str = "ws://127.0.0.1:10001";
/// Largest message accepted from the service (bytes); an inventory of a few devices is a few kilobytes.
pub const MAX_MESSAGE_BYTES: usize = 1 << 20;
/// With no force queued for this long the thread sends a zero-force keepalive.
pub const KEEPALIVE_INTERVAL: Duration = Duration::from_millis(100);
/// Capacity of the force ring (ticks): a full ring means the I/O thread has stalled this long.
pub const FORCE_RING_CAPACITY: usize = 64;
/// Longest a message to the service may take to leave (the socket's send buffer full because the service
/// stopped reading): past it the link is dropped, so no stop waits on a service that reads nothing.
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(100);
/// Most messages read in one drain: a service that always has more than this many waiting floods the link,
/// which is then dropped (a message per command and a few unsolicited updates are a handful).
pub const MAX_DRAIN_MESSAGES: usize = 1024;

/// The identity of the driven device, from the inventory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceDevice {
    /// The device id.
    pub device_id: String,
    /// "inverse3", "inverse3x", "minverse" (as the service says).
    pub device_type: String,
    /// Firmware version "major.minor", when reported.
    pub firmware: Option<String>,
    /// "left" / "right", when reported.
    pub handedness: Option<String>,
    /// The session the service assigned (a string whatever its JSON type).
    pub session_id: Option<String>,
    /// What the session's configuration read-back showed.
    pub configuration: Configuration,
    /// The service's filters (force gate, damping) as it reported them in the read-back, when it did.
    pub filters: Option<String>,
}

/// What the read-back of the session's configuration showed (`connect` fails on a mismatch instead).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Configuration {
    /// The service reported the preset, basis and an identity mount and workspace transform: positions and
    /// forces are in Haply's documented frame, unscaled.
    Confirmed,
    /// The service's answer did not carry its configuration (an older service): the frame is as asked for
    /// but not confirmed; what was missing.
    Unconfirmed(String),
}

/// One force command from the servo thread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceCommand {
    /// Tick sequence (starts at 1).
    pub sequence: u64,
    /// Force (N, Haply frame).
    pub force_n: DVec3,
}

/// The newest state, published by the I/O thread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServiceSnapshot {
    /// Sequence of the command this state answers (0 before the first).
    pub answers_sequence: u64,
    /// Handle position (m).
    pub position_m: DVec3,
    /// Handle velocity (m/s).
    pub velocity_m_per_s: DVec3,
    /// The force that reached the arm after the service's filters (`current_cursor_force`, N), once reported.
    pub arm_force_n: Option<DVec3>,
}

impl ServiceSnapshot {
    /// Applies a state object (absent fields keep their value, the service's partial updates); false when
    /// there is none or it holds a non-finite position.
    pub fn apply(&mut self, state: Option<&WireState>) -> bool {
        let Some(state) = state else {
            return false;
        };
        if let Some(p) = state.cursor_position {
            if !p.is_finite() {
                return false;
            }
            self.position_m = p;
        }
        if let Some(v) = state.cursor_velocity.filter(|v| v.is_finite()) {
            self.velocity_m_per_s = v;
        }
        if let Some(f) = state.current_cursor_force.filter(|f| f.is_finite()) {
            self.arm_force_n = Some(f);
        }
        true
    }
}

/// Counters and flags shared by both threads.
#[derive(Debug, Default)]
pub struct ServiceShared {
    /// Set by the driver to end the thread.
    pub stop: AtomicBool,
    /// Raised by the thread when the connection is gone.
    pub link_down: AtomicBool,
    /// Messages sent (forces and keepalives).
    pub sent: AtomicU64,
    /// State updates received and used.
    pub states: AtomicU64,
    /// Frames that could not be used (not JSON, binary, no state for our device).
    pub malformed: AtomicU64,
    /// Commands dropped because a newer one was queued behind them.
    pub coalesced: AtomicU64,
    /// Messages beyond the one reply per message sent (duplicates, unsolicited updates): read, used for the
    /// position (the newest wins) and counted, never taken for the answer to a newer command.
    pub extra: AtomicU64,
    /// Raised with `link_down` when the link was dropped because the service flooded it
    /// ([`MAX_DRAIN_MESSAGES`]).
    pub flooded: AtomicBool,
    /// Messages with a field voxhap uses in another JSON type than Haply documents (counted in `malformed`
    /// too); the first one's description is kept in `first_drift`.
    pub drifted: AtomicU64,
    /// What the first type drift was (written by the I/O thread only).
    pub first_drift: Mutex<Option<String>>,
}

/// The servo thread's end of the channel.
pub struct ServiceLink {
    /// Force commands to the I/O thread.
    pub forces: rtrb::Producer<ForceCommand>,
    /// Newest state from the I/O thread.
    pub states: triple_buffer::Output<ServiceSnapshot>,
    /// Flags and counters.
    pub shared: Arc<ServiceShared>,
    /// The I/O thread (unparked when a force is queued; joined on close; started by the driver).
    pub thread: Option<JoinHandle<()>>,
    /// The device this link drives.
    pub device: ServiceDevice,
    /// The service's events channel (e-brake, stall, stability ceiling, rate warnings).
    pub events: events::EventChannel,
}

impl std::fmt::Debug for ServiceLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceLink")
            .field("device", &self.device)
            .finish_non_exhaustive()
    }
}

impl ServiceLink {
    /// Wakes the I/O thread (lock-free: an atomic and, if it sleeps, a futex wake).
    pub fn wake(&self) {
        if let Some(thread) = &self.thread {
            thread.thread().unpark();
        }
    }

    /// Stops the I/O thread (it sends a zero force and a close frame first) and waits for it.
    pub fn shut_down(&mut self) {
        self.events.shut_down();
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

impl Drop for ServiceLink {
    fn drop(&mut self) {
        self.shut_down();
    }
}

/// Settings of a connection.
#[derive(Debug, Clone, PartialEq)]
pub struct ServiceConfig {
    /// `ws://HOST:PORT[/PATH]`.
    pub url: String,
    /// Drive this device id; `None` takes the first Inverse3 of the inventory.
    pub device_id: Option<String>,
    /// Time allowed for the TCP connect, the handshake and the inventory.
    pub connect_timeout: Duration,
    /// How long the I/O thread waits for the reply to a command before it goes on (the reply is still
    /// counted when it comes).
    pub reply_timeout: Duration,
    /// How long the I/O thread sleeps with nothing to send before it looks again (a queued force wakes it at
    /// once).
    pub idle_wait: Duration,
    /// Profile name shown in Haply Hub.
    pub profile_name: String,
    /// The events channel; `None`: the simulation channel's host on port [`DEFAULT_EVENTS_PORT`].
    pub events_url: Option<String>,
}

impl ServiceConfig {
    /// The connection a `--device haply-inverse` spec gives: `ws://HOST:PORT[/PATH][,events=ws://HOST:PORT]`,
    /// the simulation channel's URL and, when given, the events channel's (otherwise the simulation host on
    /// port [`DEFAULT_EVENTS_PORT`]). `None` when either part is not a `ws://` URL with something after it.
    pub fn from_spec(spec: &str) -> Option<ServiceConfig> {
        let is_url = |url: &str| url.starts_with("ws://") && url.len() > "ws://".len();
        let (url, events_url) = match spec.split_once(",events=") {
            Some((url, events)) => (url, Some(events)),
            None => (spec, None),
        };
        if !is_url(url) || events_url.is_some_and(|events| !is_url(events) || events.contains(','))
        {
            return None;
        }
        Some(ServiceConfig {
            url: url.to_owned(),
            events_url: events_url.map(str::to_owned),
            ..ServiceConfig::default()
        })
    }
}

impl Default for ServiceConfig {
    fn default() -> Self {
        ServiceConfig {
            url: DEFAULT_URL.to_owned(),
            device_id: None,
            connect_timeout: Duration::from_secs(1),
            reply_timeout: Duration::from_millis(20),
            idle_wait: Duration::from_micros(500),
            profile_name: "voxhap".to_owned(),
            events_url: None,
        }
    }
}

/// The TCP stream under the WebSocket. While `deadline` is set (connecting), every read and write is given
/// only the time left before it, so a service that sends its handshake one byte at a time cannot stretch the
/// connect past its deadline.
#[derive(Debug)]
pub struct ServiceStream {
    stream: TcpStream,
    deadline: Option<Instant>,
}

impl ServiceStream {
    /// The time left before the deadline (`None`: no deadline); an error once it has passed.
    fn time_left(&self) -> std::io::Result<Option<Duration>> {
        let Some(deadline) = self.deadline else {
            return Ok(None);
        };
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the connect deadline passed",
            ));
        }
        Ok(Some(left))
    }
}

impl Read for ServiceStream {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if let Some(left) = self.time_left()? {
            self.stream.set_read_timeout(Some(left))?;
        }
        self.stream.read(buf)
    }
}

impl Write for ServiceStream {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if let Some(left) = self.time_left()? {
            self.stream.set_write_timeout(Some(left))?;
        }
        self.stream.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

type Socket = WebSocket<ServiceStream>;

/// A connection whose session is set up and read back: the socket (non-blocking from here on), the device it
/// drives and its state so far (label 0).
#[derive(Debug)]
pub struct Session {
    /// The simulation channel.
    pub port: io::ServicePort,
    /// The driven device.
    pub device: ServiceDevice,
    /// The state the inventory and the set-up's answer left.
    pub snapshot: ServiceSnapshot,
}

fn open_error(url: &str, reason: &str, kind: std::io::ErrorKind) -> DeviceError {
    let advice = match kind {
        std::io::ErrorKind::ConnectionRefused | std::io::ErrorKind::TimedOut => {
            "is the Haply Inverse Service running? (`systemctl status haply-inverse-service`, or open Haply \
             Hub; docs/devices/haply-inverse3.md)"
        }
        _ => super::open_advice(kind),
    };
    DeviceError::Open {
        path: url.to_owned(),
        message: format!("{reason}: {advice}"),
    }
}

/// `host:port` and the request path of a `ws://` URL.
fn split_url(url: &str) -> Result<(&str, &str), DeviceError> {
    let rest = url.strip_prefix("ws://").ok_or_else(|| DeviceError::Config {
        what: format!("Inverse Service URL {url:?} must start with ws:// (the service speaks plain WebSocket on localhost)"),
    })?;
    let (authority, _) = rest.split_once('/').unwrap_or((rest, ""));
    if authority.is_empty() || !authority.contains(':') {
        return Err(DeviceError::Config {
            what: format!("Inverse Service URL {url:?} needs HOST:PORT, e.g. {DEFAULT_URL}"),
        });
    }
    Ok((authority, rest))
}

/// Reads the next text frame within `deadline`: `Ok(None)` on timeout; pings are answered by tungstenite.
/// For the blocking socket of the connect phase.
fn read_text(
    socket: &mut Socket,
    deadline: Instant,
) -> Result<Option<Message>, tungstenite::Error> {
    loop {
        match socket.read() {
            Ok(message @ (Message::Text(_) | Message::Binary(_))) => return Ok(Some(message)),
            Ok(Message::Close(_)) => return Err(tungstenite::Error::ConnectionClosed),
            Ok(_) => {}
            Err(tungstenite::Error::Io(error))
                if matches!(
                    error.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                if Instant::now() >= deadline {
                    return Ok(None);
                }
            }
            Err(error) => return Err(error),
        }
    }
}

/// Reads the service's inventory and closes (`voxhap devices`): sends nothing but the WebSocket handshake.
/// The whole exchange takes at most `timeout`.
pub fn inventory(url: &str, timeout: Duration) -> Result<Vec<ServiceDevice>, DeviceError> {
    let deadline = Instant::now() + timeout;
    let (mut socket, frame) = connect_and_read_inventory(url, deadline, timeout)?;
    let _ = socket.close(None);
    let _ = socket.flush();
    Ok(frame
        .inverse3
        .iter()
        .map(|entry| service_device(entry, frame.session_id.clone()))
        .collect())
}

fn service_device(entry: &WireInverse3, session_id: Option<String>) -> ServiceDevice {
    let info = entry.config.clone().unwrap_or_default();
    ServiceDevice {
        device_id: entry.device_id.clone(),
        device_type: info.device_type.unwrap_or_else(|| "inverse3".to_owned()),
        firmware: info.firmware,
        handedness: info.handedness,
        session_id,
        configuration: Configuration::Unconfirmed("not read back yet".to_owned()),
        filters: info.filters,
    }
}

/// What the service kept that voxhap did not ask for: every difference, in words, shown joined by "; ".
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}", .differences.join("; "))]
pub struct ConfigurationMismatch {
    /// Each difference, e.g. `mount position (0.1, 0, 0) (asked for none: the preset's own)`.
    pub differences: Vec<String>,
}

/// Checks the configuration the service reports after the session set-up against what voxhap asked for
/// ([`SESSION_PRESET`], [`SESSION_BASIS`], no mount, no workspace transform). `Err` lists every difference.
pub fn check_configuration(entry: &WireInverse3) -> Result<Configuration, ConfigurationMismatch> {
    let mut wrong = Vec::new();
    let mut missing = Vec::new();
    match entry.config.as_ref() {
        Some(config) => {
            match config.preset.as_deref() {
                Some(SESSION_PRESET) => {}
                Some(other) => {
                    wrong.push(format!("preset {other:?} (asked for {SESSION_PRESET:?})"))
                }
                None => missing.push("preset"),
            }
            match config.basis.as_deref() {
                Some(SESSION_BASIS) => {}
                Some(other) => wrong.push(format!("basis {other:?} (asked for {SESSION_BASIS:?})")),
                None => missing.push("basis"),
            }
            match config.mount {
                Some(mount) if !mount.is_identity() => {
                    wrong.push(format!("mount {mount} (asked for none: the preset's own)"))
                }
                Some(_) => {}
                None => missing.push("mount"),
            }
        }
        None => missing.push("config"),
    }
    if let Some(transform) = entry.state.and_then(|s| s.transform) {
        if !transform.is_identity() {
            wrong.push(format!(
                "workspace transform {transform} (voxhap expects the identity)"
            ));
        }
    }
    if !wrong.is_empty() {
        return Err(ConfigurationMismatch { differences: wrong });
    }
    Ok(if missing.is_empty() {
        Configuration::Confirmed
    } else {
        Configuration::Unconfirmed(format!(
            "the service's answer did not include {}",
            missing.join(", ")
        ))
    })
}

fn connect_timeout_error(timeout: Duration, waiting_for: &'static str) -> DeviceError {
    DeviceError::Timeout {
        waited_us: u64::try_from(timeout.as_micros()).unwrap_or(u64::MAX),
        waiting_for,
    }
}

/// TCP connect, WebSocket handshake and the inventory, all before `deadline` (`timeout` is its length, for
/// the error).
fn connect_and_read_inventory(
    url: &str,
    deadline: Instant,
    timeout: Duration,
) -> Result<(Socket, WireFrame), DeviceError> {
    let (authority, _) = split_url(url)?;
    let address = authority
        .to_socket_addrs()
        .map_err(|e| open_error(url, &e.to_string(), e.kind()))?
        .next()
        .ok_or_else(|| {
            open_error(
                url,
                "the host name has no address",
                std::io::ErrorKind::NotFound,
            )
        })?;
    let left = deadline.saturating_duration_since(Instant::now());
    if left.is_zero() {
        return Err(connect_timeout_error(
            timeout,
            "a TCP connection to the Inverse Service",
        ));
    }
    let stream = TcpStream::connect_timeout(&address, left)
        .map_err(|e| open_error(url, &e.to_string(), e.kind()))?;
    let io = |e: std::io::Error| open_error(url, &e.to_string(), e.kind());
    stream.set_nodelay(true).map_err(io)?;
    let stream = ServiceStream {
        stream,
        deadline: Some(deadline),
    };
    let ws_config = WebSocketConfig::default()
        .max_message_size(Some(MAX_MESSAGE_BYTES))
        .max_frame_size(Some(MAX_MESSAGE_BYTES));
    let (mut socket, _) = tungstenite::client::client_with_config(url, stream, Some(ws_config))
        .map_err(|e| {
            if Instant::now() >= deadline {
                connect_timeout_error(timeout, "the Inverse Service's WebSocket handshake")
            } else {
                open_error(
                    url,
                    &format!("WebSocket handshake failed ({e})"),
                    std::io::ErrorKind::InvalidData,
                )
            }
        })?;
    loop {
        let message = read_text(&mut socket, deadline)
            .map_err(|e| open_error(url, &e.to_string(), std::io::ErrorKind::ConnectionReset))?
            .ok_or(connect_timeout_error(
                timeout,
                "the Inverse Service's device inventory",
            ))?;
        if let Message::Text(text) = &message {
            match parse_frame_text(text.as_str()) {
                Ok(frame) => return Ok((socket, frame)),
                Err(error @ WireError::TypeDrift { .. }) => {
                    return Err(DeviceError::Open {
                        path: url.to_owned(),
                        message: format!(
                            "the Inverse Service's device inventory cannot be read: {error}"
                        ),
                    })
                }
                Err(WireError::NotJson { .. }) => {}
            }
        }
        if Instant::now() >= deadline {
            return Err(DeviceError::Protocol {
                what: "the Inverse Service's first message is not a device inventory",
            });
        }
    }
}

/// Connects, reads the inventory, picks the device, configures the session (identity basis) and reads back
/// what the service uses. Everything (TCP connect, WebSocket handshake, inventory, the answer to the
/// configuration) shares one deadline, `connect_timeout` from the start, however slowly the service sends its
/// bytes. The driver then starts its I/O thread on the session.
pub fn handshake(config: &ServiceConfig) -> Result<Session, DeviceError> {
    let url = config.url.as_str();
    let io = |e: std::io::Error| open_error(url, &e.to_string(), e.kind());
    let deadline = Instant::now() + config.connect_timeout;
    let (mut socket, inventory) =
        connect_and_read_inventory(url, deadline, config.connect_timeout)?;
    let entry = inventory
        .inverse3
        .iter()
        .find(|d| config.device_id.as_deref().is_none_or(|id| id == d.device_id))
        .ok_or_else(|| DeviceError::Open {
            path: url.to_owned(),
            message: match &config.device_id {
                Some(id) => format!(
                    "the Inverse Service lists no Inverse3 with id {id:?} (it lists {:?})",
                    inventory.inverse3.iter().map(|d| &d.device_id).collect::<Vec<_>>()
                ),
                None => "the Inverse Service lists no Inverse3: is it plugged in, powered and shown in Haply Hub?"
                    .to_owned(),
            },
        })?;
    let mut device = service_device(entry, inventory.session_id.clone());
    let mut snapshot = ServiceSnapshot {
        answers_sequence: 0,
        position_m: DVec3::ZERO,
        velocity_m_per_s: DVec3::ZERO,
        arm_force_n: None,
    };
    snapshot.apply(entry.state.as_ref());
    // Configure the session (profile, basis, preset, full state) and read back what the service now uses.
    socket
        .send(Message::text(setup_message(
            &device.device_id,
            &config.profile_name,
        )))
        .map_err(|e| open_error(url, &e.to_string(), std::io::ErrorKind::ConnectionReset))?;
    let reply = read_text(&mut socket, deadline)
        .map_err(|e| open_error(url, &e.to_string(), std::io::ErrorKind::ConnectionReset))?
        .ok_or(connect_timeout_error(
            config.connect_timeout,
            "the Inverse Service's answer to the session configuration",
        ))?;
    let unreadable = |what: String| DeviceError::Open {
        path: url.to_owned(),
        message: format!("the Inverse Service's answer to the session configuration {what}"),
    };
    let frame = match &reply {
        Message::Text(text) => parse_frame_text(text.as_str())
            .map_err(|e| unreadable(format!("cannot be read: {e}")))?,
        _ => return Err(unreadable("is not a text message".to_owned())),
    };
    let answer = frame
        .inverse3
        .iter()
        .find(|d| d.device_id == device.device_id)
        .ok_or_else(|| unreadable(format!("has no state for device {:?}", device.device_id)))?;
    device.configuration = check_configuration(answer).map_err(|wrong| DeviceError::Open {
        path: url.to_owned(),
        message: format!(
            "the Inverse Service keeps a configuration for {} that voxhap did not ask for and could not \
             replace: {wrong}. Positions and forces would be moved or scaled; reset the device's mount, preset \
             and workspace transform in Haply Hub (or the service's HTTP API), or stop the program that sets them",
            device.device_id
        ),
    })?;
    if let Some(filters) = answer.config.as_ref().and_then(|c| c.filters.clone()) {
        device.filters = Some(filters);
    }
    snapshot.apply(answer.state.as_ref());
    // From here on the I/O thread never blocks on the socket: it polls it (module docs).
    socket.get_mut().deadline = None;
    socket.get_ref().stream.set_nonblocking(true).map_err(io)?;
    Ok(Session {
        port: io::ServicePort::new(socket),
        device,
        snapshot,
    })
}
