//! A test double of the Haply Inverse Service, written from Haply's documents and Haply's own client alone,
//! never from voxhap's driver: real WebSockets on 127.0.0.1 (port 0, or the same port again after a "restart").
//! Each behaviour and its source:
//!
//! - **Simulation channel** (docs.haply.co/inverseSDK/service/realtime/websocket-protocol, "Core rule: one
//!   response per message" and "Step 1 — Initial inventory"): on connect one inventory, the documented
//!   example's fields (`session_id`, per Inverse3 `device_id`, `config` with `preset`, `basis`, `mount`,
//!   `filters`, `state` with `cursor_position`, `cursor_velocity`, `current_cursor_force`, `transform`, and
//!   `status`); then exactly one state update per client message (state and status; config only when asked
//!   for, below).
//! - **Full state on request** (Haply's Rust client, crate `haply` 1.3.1, src/device_model/commands.rs:392-398
//!   `force_render_full_state`; src/device.rs:148 "Forces a full state update"): a message whose `session`
//!   carries `force_render_full_state` is answered with `config` too.
//! - **Device configuration, persistent across programs** (voxhap's shared REFERENCES.md, Inverse Service 3.5:
//!   `preset`, `basis`, `mount` persist; docs.haply.co tutorial "07. Basis & Mount Playground": `configure.basis`,
//!   `configure.preset`, `configure.mount`, "mount and preset cannot coexist in the same device configure block",
//!   a preset replaces a mount override): the double keeps them across connections; [`InverseService::set_mount`]
//!   and [`InverseService::set_workspace_transform`] play "another program" (Haply Hub) setting them. A block
//!   with both `mount` and `preset` is refused (logged, nothing changed). With `keep_configuration` the double
//!   ignores every configure (an older service, or another program that re-imposes its mount at once).
//! - **What the frame does to positions and forces** (a model: Haply documents that basis, mount and workspace
//!   transform move, turn and scale the reported frame, not the equations): reported position =
//!   W(M(p)) then the basis permutation, where M and W are the mount and workspace transforms
//!   (scale, then rotate, then translate) and p is the handle in the default frame; a commanded force is turned
//!   back through the permutation and the rotations and multiplied by the scales before it reaches the arm.
//!   The arm's force is reported as `current_cursor_force` (docs.haply.co tutorial "01. Print Inverse3": "State
//!   fields read ... current_cursor_force"); while the e-brake is on it is zero ("Emergency brake engaged —
//!   device locked", docs.haply.co "Events & Monitoring").
//! - **The handle** stays where [`InverseService::set_position`] put it (Haply's example pose (0.0, -0.12,
//!   0.15) m at start), or with [`InverseService::sweep`] moves along a Lissajous path that reaches every face
//!   of the reachable box SOFA's Haply plugin measured, (-0.245, -0.262, 0.011)..(0.259, 0.152, 0.317) m (voxhap's
//!   shared REFERENCES.md), at most about 0.5 m/s; [`InverseService::reached`] gives the extent reported so far.
//! - **Events channel** (docs.haply.co/inverseSDK/service/api/events "Events Channel": a read-only WebSocket,
//!   one message per event; docs.haply.co "Events & Monitoring" for the shape and the `safety_type` values):
//!   [`InverseService::events_url`]; [`InverseService::send_event`] sends one event to every client,
//!   [`InverseService::ebrake`] the documented `device-safety-triggered` / `ebrake_triggered` one,
//!   [`InverseService::safety_event`] any documented `safety_type` with its documented level, and
//!   [`InverseService::rate_report`] Haply's client's `system-rate-report`.
//!
//! Misbehaviours outside Haply's documentation, for the driver's robustness: more than one reply per message
//! (`replies_per_message`), an unsolicited state update every `unsolicited_every_ms`, malformed replies, a
//! reply held back (`delay_next_reply_ms`), no replies (`mute`), dropping each connection after some replies
//! (`close_after_replies`) or at once (`refuse`), a slow-loris handshake (`slow_handshake_from`), and
//! `drift_position_type` (the position sent as a string). With `stamp`, the x of every state message carries its
//! index (1, 2, ...): x = [`STAMP_BASE_M`] + index · [`STAMP_STEP_M`]; `written` is the last index written.
//! `stalls_us` records each time a connection's thread was kept off the CPU for a millisecond or more.

use glam::{DQuat, DVec3};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tungstenite::{Message, WebSocket};

/// What the double received.
#[derive(Debug, Clone, PartialEq)]
pub enum ServiceEvent {
    /// A client connected (the inventory was sent).
    Connected,
    /// A `set_cursor_force` for this device id with this vector (N).
    Force { device_id: String, vector: [f64; 3] },
    /// The session part of a message.
    Session(Value),
    /// A device `configure` block.
    Configure(Value),
    /// A configure block refused (mount and preset together).
    ConfigureRefused(Value),
    /// A message that is not JSON.
    Unparsable(String),
}

/// A transform as Haply writes it: scale, then rotate, then translate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    pub position: DVec3,
    pub rotation: DQuat,
    pub scale: DVec3,
}

impl Transform {
    pub const IDENTITY: Transform = Transform {
        position: DVec3::ZERO,
        rotation: DQuat::IDENTITY,
        scale: DVec3::ONE,
    };

    fn apply(&self, p: DVec3) -> DVec3 {
        self.rotation * (self.scale * p) + self.position
    }

    /// A force in the reported frame back to the frame before this transform.
    fn force_back(&self, f: DVec3) -> DVec3 {
        self.scale * (self.rotation.inverse() * f)
    }

    fn json(&self) -> Value {
        let (p, r, s) = (self.position, self.rotation, self.scale);
        json!({
            "position": {"x": p.x, "y": p.y, "z": p.z},
            "rotation": {"w": r.w, "x": r.x, "y": r.y, "z": r.z},
            "scale": {"x": s.x, "y": s.y, "z": s.z}
        })
    }

    fn from_json(value: &Value) -> Transform {
        let get =
            |part: &str, axis: &str, default: f64| value[part][axis].as_f64().unwrap_or(default);
        Transform {
            position: DVec3::new(
                get("position", "x", 0.0),
                get("position", "y", 0.0),
                get("position", "z", 0.0),
            ),
            rotation: DQuat::from_xyzw(
                get("rotation", "x", 0.0),
                get("rotation", "y", 0.0),
                get("rotation", "z", 0.0),
                get("rotation", "w", 1.0),
            ),
            scale: DVec3::new(
                get("scale", "x", 1.0),
                get("scale", "y", 1.0),
                get("scale", "z", 1.0),
            ),
        }
    }
}

/// The device's configuration, kept across connections.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceConfiguration {
    pub preset: String,
    pub basis: String,
    pub mount: Transform,
    pub workspace_transform: Transform,
}

/// The reachable box SOFA's Haply plugin measured (voxhap's shared REFERENCES.md), in Haply's default frame.
pub const REACHABLE_MIN_M: [f64; 3] = [-0.245, -0.262, 0.011];
pub const REACHABLE_MAX_M: [f64; 3] = [0.259, 0.152, 0.317];
/// Periods of the sweep's three axes (s): peak speeds of 0.30, 0.28 and 0.26 m/s.
const SWEEP_PERIODS_S: [f64; 3] = [5.3, 4.7, 3.7];

/// State shared with the server threads.
#[derive(Debug)]
pub struct ServiceShared {
    pub log: Mutex<Vec<ServiceEvent>>,
    /// The handle in Haply's default frame (m), when it is not sweeping.
    pub position_m: Mutex<[f64; 3]>,
    /// The sweep's start, while sweeping.
    sweep_from: Mutex<Option<Instant>>,
    /// Lowest and highest reported coordinates, per axis.
    extent: Mutex<([f64; 3], [f64; 3])>,
    pub configuration: Mutex<DeviceConfiguration>,
    /// Ignore every configure block.
    pub keep_configuration: AtomicBool,
    /// Emergency brake engaged: the arm takes no force.
    pub ebrake: AtomicBool,
    /// The last force the arm received (N, default frame).
    arm_force: Mutex<DVec3>,
    /// Every `current_cursor_force` sent in a state update, in order.
    pub reported_forces: Mutex<Vec<[f64; 3]>>,
    pub malformed_replies: AtomicU32,
    pub delay_next_reply_ms: AtomicU64,
    pub replies_per_message: AtomicU32,
    pub unsolicited_every_ms: AtomicU64,
    pub stamp: AtomicBool,
    pub written: AtomicU64,
    next_index: AtomicU64,
    pub mute: AtomicBool,
    pub close_after_replies: AtomicU32,
    pub refuse: AtomicBool,
    pub slow_handshake_from: AtomicU32,
    /// Send `cursor_position` as a string (a type drift).
    pub drift_position_type: AtomicBool,
    /// TCP connections accepted on the simulation channel.
    pub accepted: AtomicU32,
    /// How long (µs) a connection's thread was kept off the CPU, each time it was for at least a millisecond:
    /// the time between two turns of its loop beyond the longest a turn waits for a message ([`READ_WAIT`]).
    pub stalls_us: Mutex<Vec<u64>>,
    event_clients: Mutex<Vec<WebSocket<TcpStream>>>,
    /// Clients that completed the events channel's handshake.
    pub event_clients_accepted: AtomicU32,
    stop: AtomicBool,
}

pub const STAMP_BASE_M: f64 = -0.05;
pub const STAMP_STEP_M: f64 = 1e-6;

/// The message index a stamped position carries.
pub fn stamp_of(x_m: f64) -> u64 {
    ((x_m - STAMP_BASE_M) / STAMP_STEP_M).round() as u64
}

pub const DEVICE_ID: &str = "049D";

/// The longest a connection's thread waits for a client message before it looks again.
pub const READ_WAIT: Duration = Duration::from_millis(5);

/// The running double.
pub struct InverseService {
    pub shared: Arc<ServiceShared>,
    address: SocketAddr,
    events_address: SocketAddr,
    threads: Vec<JoinHandle<()>>,
}

fn vector(v: DVec3) -> Value {
    json!({"x": v.x, "y": v.y, "z": v.z})
}

fn permute(basis: &str, v: DVec3) -> DVec3 {
    let axis = |c: char| match c {
        'X' => v.x,
        'Y' => v.y,
        _ => v.z,
    };
    let mut chars = basis.chars();
    let (a, b, c) = (
        chars.next().unwrap_or('X'),
        chars.next().unwrap_or('Y'),
        chars.next().unwrap_or('Z'),
    );
    DVec3::new(axis(a), axis(b), axis(c))
}

fn unpermute(basis: &str, v: DVec3) -> DVec3 {
    let mut out = DVec3::ZERO;
    for (i, c) in basis.chars().take(3).enumerate() {
        let slot = match c {
            'X' => 0,
            'Y' => 1,
            _ => 2,
        };
        out[slot] = v[i];
    }
    out
}

impl ServiceShared {
    /// The handle in the default frame now.
    fn handle(&self) -> DVec3 {
        if let Some(from) = *self.sweep_from.lock().unwrap() {
            let t = from.elapsed().as_secs_f64();
            let mut p = DVec3::ZERO;
            for axis in 0..3 {
                let (lo, hi) = (REACHABLE_MIN_M[axis], REACHABLE_MAX_M[axis]);
                let phase = std::f64::consts::TAU * t / SWEEP_PERIODS_S[axis];
                // Starts at the box's lower corner and reaches both faces every period.
                p[axis] = 0.5 * (lo + hi) - 0.5 * (hi - lo) * phase.cos();
            }
            return p;
        }
        DVec3::from_array(*self.position_m.lock().unwrap())
    }

    fn reported(&self, p: DVec3) -> DVec3 {
        let c = self.configuration.lock().unwrap();
        permute(&c.basis, c.workspace_transform.apply(c.mount.apply(p)))
    }

    fn state(&self, position: Value) -> Value {
        let c = self.configuration.lock().unwrap().clone();
        let arm = *self.arm_force.lock().unwrap();
        self.reported_forces.lock().unwrap().push(arm.to_array());
        json!({
            "cursor_position": position,
            "cursor_velocity": {"x": 0.0, "y": 0.0, "z": 0.0},
            "current_cursor_force": vector(arm),
            "control_mode": "idle",
            "transform": c.workspace_transform.json()
        })
    }

    fn config(&self) -> Value {
        let c = self.configuration.lock().unwrap().clone();
        json!({
            "type": "inverse3",
            "port": "COM12",
            "device_info": {"major_version": 7, "minor_version": 4, "id": DEVICE_ID, "device_type": 4, "uuid": "…"},
            "handedness": "right",
            "preset": c.preset,
            "basis": {"permutation": c.basis},
            "mount": c.mount.json(),
            "filters": {"force_gate": {"gain": 0.3}, "damping": {"scalar": 0.0}}
        })
    }

    /// A state message (with `config` when `full`), stamped when asked: returns it and its index.
    fn state_message(&self, full: bool) -> (Message, u64) {
        let index = self.next_index.fetch_add(1, Ordering::AcqRel) + 1;
        let mut p = self.reported(self.handle());
        if self.stamp.load(Ordering::Acquire) {
            p.x = STAMP_BASE_M + index as f64 * STAMP_STEP_M;
        }
        {
            let mut extent = self.extent.lock().unwrap();
            extent.0 = extent.0.map_with_index(p, f64::min);
            extent.1 = extent.1.map_with_index(p, f64::max);
        }
        let position = if self.drift_position_type.load(Ordering::Acquire) {
            json!(format!("{}, {}, {}", p.x, p.y, p.z))
        } else {
            vector(p)
        };
        let mut device = json!({"device_id": DEVICE_ID, "state": self.state(position), "status": {"ready": true}});
        if full {
            device["config"] = self.config();
        }
        let mut message = json!({"inverse3": [device]});
        if full {
            message["session_id"] = json!(7);
        }
        (Message::text(message.to_string()), index)
    }

    /// A commanded force (reported frame) reaches the arm, unless the e-brake holds it.
    fn command_force(&self, f: DVec3) {
        let arm = if self.ebrake.load(Ordering::Acquire) {
            DVec3::ZERO
        } else {
            let c = self.configuration.lock().unwrap();
            c.mount
                .force_back(c.workspace_transform.force_back(unpermute(&c.basis, f)))
        };
        *self.arm_force.lock().unwrap() = arm;
    }

    /// A device configure block (tutorial 07 rules).
    fn configure(&self, block: &Value) {
        let mut log = self.log.lock().unwrap();
        if block.get("mount").is_some() && block.get("preset").is_some() {
            log.push(ServiceEvent::ConfigureRefused(block.clone()));
            return;
        }
        log.push(ServiceEvent::Configure(block.clone()));
        if self.keep_configuration.load(Ordering::Acquire) {
            return;
        }
        let mut c = self.configuration.lock().unwrap();
        if let Some(preset) = block["preset"]["preset"].as_str() {
            c.preset = preset.to_owned();
            // A preset replaces any mount override; the *_centered ones move the origin to the box centre.
            c.mount = Transform::IDENTITY;
            if preset.ends_with("_centered") {
                c.mount.position = -0.5
                    * (DVec3::from_array(REACHABLE_MIN_M) + DVec3::from_array(REACHABLE_MAX_M));
            }
        }
        if let Some(basis) = block["basis"]["permutation"].as_str() {
            c.basis = basis.to_owned();
        }
        if let Some(mount) = block.get("mount") {
            c.mount = Transform::from_json(&mount["transform"]);
        }
    }
}

trait MapWithIndex {
    fn map_with_index(self, p: DVec3, f: fn(f64, f64) -> f64) -> Self;
}

impl MapWithIndex for [f64; 3] {
    fn map_with_index(self, p: DVec3, f: fn(f64, f64) -> f64) -> Self {
        [f(self[0], p.x), f(self[1], p.y), f(self[2], p.z)]
    }
}

impl InverseService {
    /// Starts on 127.0.0.1, port 0, in Haply's default configuration (the documented inventory's).
    pub fn start() -> InverseService {
        let shared = Arc::new(ServiceShared {
            log: Mutex::new(Vec::new()),
            position_m: Mutex::new([0.0, -0.12, 0.15]),
            sweep_from: Mutex::new(None),
            extent: Mutex::new(([f64::INFINITY; 3], [f64::NEG_INFINITY; 3])),
            configuration: Mutex::new(DeviceConfiguration {
                preset: "defaults".to_owned(),
                basis: "XYZ".to_owned(),
                mount: Transform::IDENTITY,
                workspace_transform: Transform::IDENTITY,
            }),
            keep_configuration: AtomicBool::new(false),
            ebrake: AtomicBool::new(false),
            arm_force: Mutex::new(DVec3::ZERO),
            reported_forces: Mutex::new(Vec::new()),
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
            drift_position_type: AtomicBool::new(false),
            accepted: AtomicU32::new(0),
            stalls_us: Mutex::new(Vec::new()),
            event_clients: Mutex::new(Vec::new()),
            event_clients_accepted: AtomicU32::new(0),
            stop: AtomicBool::new(false),
        });
        let (address, simulation) = spawn("127.0.0.1:0".parse().unwrap(), &shared, accept_loop);
        let (events_address, events) =
            spawn("127.0.0.1:0".parse().unwrap(), &shared, events_accept_loop);
        InverseService {
            shared,
            address,
            events_address,
            threads: vec![simulation, events],
        }
    }

    /// `ws://127.0.0.1:PORT` of the simulation channel.
    pub fn url(&self) -> String {
        format!("ws://{}", self.address)
    }

    /// `ws://127.0.0.1:PORT` of the events channel.
    pub fn events_url(&self) -> String {
        format!("ws://{}", self.events_address)
    }

    /// Stops the service: every connection and both listening sockets close.
    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
        self.shared.event_clients.lock().unwrap().clear();
    }

    /// Starts again (after [`InverseService::stop`]) on the same ports, keeping the log and configuration.
    pub fn start_again(&mut self) {
        self.stop();
        self.shared.stop.store(false, Ordering::Release);
        let (_, simulation) = spawn(self.address, &self.shared, accept_loop);
        let (_, events) = spawn(self.events_address, &self.shared, events_accept_loop);
        self.threads = vec![simulation, events];
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

    /// Puts the handle here (Haply's default frame, m) and stops any sweep.
    pub fn set_position(&self, position_m: [f64; 3]) {
        *self.shared.sweep_from.lock().unwrap() = None;
        *self.shared.position_m.lock().unwrap() = position_m;
    }

    /// Moves the handle along the sweep through the whole reachable box, from now on.
    pub fn sweep(&self) {
        *self.shared.sweep_from.lock().unwrap() = Some(Instant::now());
    }

    /// The lowest and highest reported coordinate per axis so far.
    pub fn reached(&self) -> ([f64; 3], [f64; 3]) {
        *self.shared.extent.lock().unwrap()
    }

    /// "Another program" sets a persistent mount (tutorial 07's `configure.mount`).
    pub fn set_mount(&self, mount: Transform) {
        let mut c = self.shared.configuration.lock().unwrap();
        c.mount = mount;
        c.preset = "custom".to_owned();
    }

    /// "Another program" sets a workspace transform.
    pub fn set_workspace_transform(&self, transform: Transform) {
        self.shared
            .configuration
            .lock()
            .unwrap()
            .workspace_transform = transform;
    }

    /// The configuration in force now.
    pub fn configuration(&self) -> DeviceConfiguration {
        self.shared.configuration.lock().unwrap().clone()
    }

    /// Sends one event to every client of the events channel.
    pub fn send_event(&self, event: Value) {
        let text = event.to_string();
        let mut clients = self.shared.event_clients.lock().unwrap();
        clients.retain_mut(|client| client.send(Message::text(text.clone())).is_ok());
    }

    /// The documented e-brake event ("Events & Monitoring": `device-safety-triggered`, `safety_type`
    /// `ebrake_triggered`, level error); the arm is locked from now on.
    pub fn ebrake(&self) {
        self.shared.ebrake.store(true, Ordering::Release);
        *self.shared.arm_force.lock().unwrap() = DVec3::ZERO;
        self.safety_event("ebrake_triggered");
    }

    /// One documented `device-safety-triggered` event of the driven device ("Events & Monitoring", table
    /// "device-safety-triggered sub-types": the `safety_type`, its level and meaning, which is the message).
    /// What the arm then does is not documented (except the e-brake's lock, [`InverseService::ebrake`]), so
    /// the double changes nothing else. Panics on a `safety_type` that table does not list.
    pub fn safety_event(&self, safety_type: &str) {
        let (level, meaning) = match safety_type {
            "ebrake_triggered" => ("error", "Emergency brake engaged — device locked"),
            "ebrake_released" => ("notice", "Emergency brake released"),
            "fod_stage_changed" => ("warning", "FOD stage changed: guard -> hard"),
            "stall_detected" => ("warning", "Motor stall detected"),
            "stability_ceiling" => ("warning", "Stability ceiling reached"),
            other => panic!("Haply documents no safety_type {other:?}"),
        };
        self.send_event(json!({
            "name": "device-safety-triggered",
            "category": "device",
            "level": level,
            "data": {"device_family": "inverse", "device_id": DEVICE_ID, "safety_type": safety_type},
            "message": meaning
        }));
    }

    /// A control-rate report as Haply's own client reads it (crate `haply` 1.3.1, src/interfaces/events.rs:
    /// `EventData::SystemRateReport` with `min_frequency`, `max_frequency`, `mean_frequency`,
    /// `median_frequency`, name `system-rate-report`, category `system`); "Events & Monitoring" lists control
    /// rate anomalies among the events, level warning for something that "seems off".
    pub fn rate_report(&self, min_hz: u32, max_hz: u32, mean_hz: u32, median_hz: u32) {
        self.send_event(json!({
            "name": "system-rate-report",
            "category": "system",
            "level": "warning",
            "data": {"min_frequency": min_hz, "max_frequency": max_hz, "mean_frequency": mean_hz,
                     "median_frequency": median_hz},
            "message": "control rate below target"
        }));
    }
}

impl Drop for InverseService {
    fn drop(&mut self) {
        self.stop();
    }
}

fn spawn(
    address: SocketAddr,
    shared: &Arc<ServiceShared>,
    run: fn(TcpListener, &Arc<ServiceShared>),
) -> (SocketAddr, JoinHandle<()>) {
    // std sets SO_REUSEADDR on Unix, so a restart can bind the same port at once.
    let listener = TcpListener::bind(address).expect("bind the Inverse Service double");
    listener.set_nonblocking(true).unwrap();
    let address = listener.local_addr().unwrap();
    let shared = shared.clone();
    (address, std::thread::spawn(move || run(listener, &shared)))
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

/// The events channel: accepts clients; [`InverseService::send_event`] writes to them. Clients send nothing.
fn events_accept_loop(listener: TcpListener, shared: &Arc<ServiceShared>) {
    while !shared.stop.load(Ordering::Acquire) {
        match listener.accept() {
            Ok((stream, _)) => {
                let _ = stream.set_nonblocking(false);
                let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
                let _ = stream.set_read_timeout(Some(Duration::from_secs(1)));
                if let Ok(socket) = tungstenite::accept(stream) {
                    shared.event_clients.lock().unwrap().push(socket);
                    shared.event_clients_accepted.fetch_add(1, Ordering::AcqRel);
                }
            }
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
    }
}

/// The slow-loris handshake: reads the HTTP request, then answers one byte per 100 ms without end.
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

/// Logs a client message and applies its session and configure parts; true when it asks for the full state.
fn take_message(shared: &ServiceShared, message: &str) -> bool {
    let Ok(value) = serde_json::from_str::<Value>(message) else {
        shared
            .log
            .lock()
            .unwrap()
            .push(ServiceEvent::Unparsable(message.to_owned()));
        return false;
    };
    let mut full = false;
    if let Some(session) = value.get("session") {
        full = session.get("force_render_full_state").is_some();
        shared
            .log
            .lock()
            .unwrap()
            .push(ServiceEvent::Session(session.clone()));
    }
    for device in value["inverse3"].as_array().into_iter().flatten() {
        if let Some(block) = device.get("configure") {
            shared.configure(block);
        }
        if let Some(force) = device["commands"].get("set_cursor_force") {
            let v = &force["vector"];
            let get = |axis: &str| v.get(axis).and_then(Value::as_f64).unwrap_or(0.0);
            let vector = [get("x"), get("y"), get("z")];
            shared.command_force(DVec3::from_array(vector));
            shared.log.lock().unwrap().push(ServiceEvent::Force {
                device_id: device["device_id"].as_str().unwrap_or("").to_owned(),
                vector,
            });
        }
    }
    full
}

fn serve(stream: TcpStream, shared: &ServiceShared) {
    let number = shared.accepted.fetch_add(1, Ordering::AcqRel) + 1;
    if shared.refuse.load(Ordering::Acquire) {
        return;
    }
    stream.set_nodelay(true).unwrap();
    stream.set_nonblocking(false).unwrap();
    stream.set_read_timeout(Some(READ_WAIT)).unwrap();
    let slow_from = shared.slow_handshake_from.load(Ordering::Acquire);
    if slow_from != 0 && number >= slow_from {
        slow_handshake(stream, shared);
        return;
    }
    let Ok(mut socket) = tungstenite::accept(stream) else {
        return;
    };
    // The inventory: the full state, with the session id.
    let (inventory, _) = shared.state_message(true);
    if socket.send(inventory).is_err() {
        return;
    }
    shared.log.lock().unwrap().push(ServiceEvent::Connected);
    let mut malformed_turn = 0u32;
    let mut replies = 0u32;
    let mut last_unsolicited = Instant::now();
    let mut turn = Instant::now();
    while !shared.stop.load(Ordering::Acquire) {
        let stall = turn.elapsed().saturating_sub(READ_WAIT);
        turn = Instant::now();
        if stall >= Duration::from_millis(1) {
            let stall_us = u64::try_from(stall.as_micros()).unwrap_or(u64::MAX);
            shared.stalls_us.lock().unwrap().push(stall_us);
        }
        let every_ms = shared.unsolicited_every_ms.load(Ordering::Acquire);
        if every_ms > 0 && last_unsolicited.elapsed() >= Duration::from_millis(every_ms) {
            last_unsolicited = Instant::now();
            let (update, index) = shared.state_message(false);
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
        let full = take_message(shared, &message);
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
                let (reply, index) = shared.state_message(full);
                (reply, Some(index))
            };
            if delay_ms > 0 {
                std::thread::sleep(Duration::from_millis(delay_ms));
                // Held back on purpose: not a stall.
                turn = Instant::now();
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
