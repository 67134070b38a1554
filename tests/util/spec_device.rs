//! A voxhap-protocol device written from protocol/SPEC.md alone, run in a thread on the device side of a
//! pseudo-terminal, that logs everything the host sends and can misbehave on request.
//!
//! Where it sits: a test spawns it ([`SpecDevice::spawn`]), starts the real host (`voxhap serve --device
//! serial:PATH`) on [`SpecDeviceHandle::path`], and asserts on the device-side logs ([`SpecDeviceHandle::forces`],
//! [`SpecDeviceHandle::messages`], [`SpecDeviceHandle::sent`]) and the helpers built on them
//! ([`SpecDeviceHandle::max_force_while_not_enabled`], [`SpecDeviceHandle::max_slew_n_per_ms`],
//! [`SpecDeviceHandle::nonzero_forces_after_index`], ...). It is an independent second reading of the SPEC: COBS,
//! CRC-16/CCITT-FALSE and the payload layouts are implemented here from the SPEC text, not with the
//! `voxhap-protocol` crate, and nothing here was written from the host's driver code. Two tests in
//! tests/device_spec.rs check the double itself: its codec against `protocol/vectors/*.hex`, and its state machine
//! against a host written with the reference crate.
//!
//! ```ignore
//! let config = SpecDeviceConfig { refuse_enable: Some(reject::FAULTED), ..Default::default() };
//! let mut device = SpecDevice::spawn(config);
//! // run `voxhap serve --device serial:{device.path()}` ...
//! device.stop();
//! assert_eq!(device.max_force_while_not_enabled(), 0.0);
//! ```
//!
//! Behaviour, by SPEC section:
//! - §4.1 / §4.3: the pty's slave side is put in raw mode at creation; the device sends a lone 0x00 at start-up
//!   (and after a reset) and before every DeviceInfo.
//! - §4.2 / §4.4: frames are `COBS(type ‖ payload ‖ CRC-16 LE) ‖ 0x00`; a frame that fails COBS, length, CRC, type
//!   or payload-size checks is dropped and counted ([`SpecDeviceHandle::dropped_frames`]), never answered. A
//!   SetForce with a non-finite component is **logged** (so a test can see the host sent it) and then dropped as the
//!   SPEC says (`invalid_value`).
//! - §6 table: session closed / open, drive Idle / Enabled / Faulted, Hello (DeviceInfo, Rejected on a version
//!   mismatch), Heartbeat → HeartbeatReply always, Rejected(NO_SESSION) for anything but SetForce while closed,
//!   Enable / Disable / ClearFault / SetStateRate with their Rejected replies.
//! - §6.1: the status bits; §6.2: the force clamp at `max_force_n` (in f64); §6.3: Fault frames (WATCHDOG_EXPIRED
//!   drops to Idle, codes ≥ 1 latch until ClearFault); §6.4: State sequence +1 per State from power-up.
//! - §6.5: the watchdog (default 50 ms, set per Enable) is checked by the device's own 1 kHz control loop, whether
//!   or not bytes arrive.
//! - §6.6: lockstep: one State per SetForce (a control cycle runs as soon as a SetForce is received, so the State
//!   is sampled and sent at once); streaming at SetStateRate(r) from the device clock.
//! - §6.7: the double's outbox is unbounded: it never drops a reply of its own accord (only on purpose, below).
//! - §6.8: a device with `position_dof` 1 or 2 reports the components it does not sense as 0 (unless told to
//!   report garbage there, `unused_components`), and one with `force_dof` 1 or 2 applies only the components it
//!   renders (the log keeps all three as received).
//! - Not modelled: buttons (always 0) and non-finite samples (the scripted handle is always finite, so no ENCODER
//!   fault arises by itself; a test can inject one with `fault`).
//!
//! The logs: every SetForce received ([`ForceRecord`]: arrival [`Instant`], host sequence, force, whether the drive
//! was Enabled at that moment), every other message received ([`MessageRecord`], including a `PortClosed` event
//! when the host closes the pty), every frame written ([`SentRecord`]) and every trigger as it fired
//! ([`TriggerRecord`]). All four share one event counter (`index`) so that their order is exact.
//!
//! Misbehaviour ([`SpecDeviceConfig`] fields, each off by default): refuse every Enable; start Faulted; raise a
//! Fault at a [`Trigger`] (a time after the first Enable, or the first moment an applied force is above a
//! threshold); corrupt the first N DeviceInfo replies (bad CRC); speak another major version; stop replying for a
//! while; delay every reply; delay DeviceInfo (and so everything after it) by a configurable time; corrupt a
//! fraction of the bytes it writes (seeded); send every Nth frame cut in half; add a position jump; report a fixed
//! (absurd or inconsistent) velocity; report garbage in the components a 1- or 2-DOF device does not use; reset (a
//! brown-out). The handle follows a
//! scripted function of time ([`HandleFn`]), and can be held still from a trigger on; `max_force_n`,
//! `max_stiffness_n_per_m` and the workspace are what DeviceInfo declares. A test can also have the device thread
//! run an action of its own at a trigger (`call_at`), so that it acts on the host while force is flowing, not some
//! scheduling delay later.

use std::collections::VecDeque;
use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// Wire format (SPEC sections 3 and 4), written from the text.

/// Message type bytes (SPEC section 3).
pub mod types {
    pub const HELLO: u8 = 0x01;
    pub const ENABLE: u8 = 0x02;
    pub const DISABLE: u8 = 0x03;
    pub const SET_FORCE: u8 = 0x04;
    pub const HEARTBEAT: u8 = 0x05;
    pub const CLEAR_FAULT: u8 = 0x06;
    pub const SET_STATE_RATE: u8 = 0x07;
    pub const DEVICE_INFO: u8 = 0x81;
    pub const STATE: u8 = 0x82;
    pub const HEARTBEAT_REPLY: u8 = 0x83;
    pub const FAULT: u8 = 0x84;
    pub const REJECTED: u8 = 0x85;
}

/// Status bits (SPEC section 6.1).
pub mod status {
    pub const SESSION_OPEN: u16 = 1 << 0;
    pub const ENABLED: u16 = 1 << 1;
    pub const FAULTED: u16 = 1 << 2;
    pub const WATCHDOG_TRIPPED: u16 = 1 << 3;
    pub const FORCE_CLAMPED: u16 = 1 << 4;
    pub const LOCKSTEP: u16 = 1 << 5;
}

/// Fault codes (SPEC section 3.2).
pub mod fault {
    pub const WATCHDOG_EXPIRED: u8 = 0;
    pub const EMERGENCY_STOP: u8 = 1;
    pub const OVER_CURRENT: u8 = 3;
}

/// Reject reasons (SPEC section 3.2).
pub mod reject {
    pub const NO_SESSION: u8 = 1;
    pub const VERSION_MISMATCH: u8 = 2;
    pub const FAULTED: u8 = 3;
    pub const INVALID_ARGUMENT: u8 = 4;
}

/// Payload size of each type (SPEC section 3), `None` for a type this direction does not know.
pub fn payload_len(message_type: u8) -> Option<usize> {
    Some(match message_type {
        types::HELLO => 2,
        types::ENABLE => 4,
        types::DISABLE => 0,
        types::SET_FORCE => 18,
        types::HEARTBEAT => 4,
        types::CLEAR_FAULT => 0,
        types::SET_STATE_RATE => 2,
        types::DEVICE_INFO => 62,
        types::STATE => 46,
        types::HEARTBEAT_REPLY => 14,
        types::FAULT => 11,
        types::REJECTED => 2,
        _ => return None,
    })
}

/// CRC-16/CCITT-FALSE, table-driven exactly as SPEC section 4.2 spells it (16-bit masks included).
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut table = [0u32; 256];
    for (i, entry) in table.iter_mut().enumerate() {
        let mut t = (i as u32) << 8;
        for _ in 0..8 {
            t = if t & 0x8000 != 0 {
                ((t << 1) ^ 0x1021) & 0xFFFF
            } else {
                (t << 1) & 0xFFFF
            };
        }
        *entry = t;
    }
    let mut crc: u32 = 0xFFFF;
    for &b in bytes {
        crc = ((crc << 8) & 0xFFFF) ^ table[(((crc >> 8) ^ u32::from(b)) & 0xFF) as usize];
    }
    crc as u16
}

/// COBS-stuffs `raw` (SPEC section 4.2); the result has no 0x00 and no delimiter.
pub fn cobs_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(raw.len() + 2);
    for piece in raw.split(|&b| b == 0) {
        // Frames here are far below 254 bytes, so every piece fits one code byte.
        assert!(
            piece.len() < 254,
            "pieces of 254 bytes never occur in this protocol"
        );
        out.push(piece.len() as u8 + 1);
        out.extend_from_slice(piece);
    }
    out
}

/// Unstuffs one frame (the bytes between delimiters), or `None` when the chain of codes is broken.
pub fn cobs_decode(stuffed: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(stuffed.len());
    let mut at = 0;
    while at < stuffed.len() {
        let code = usize::from(stuffed[at]);
        if code == 0 || at + code > stuffed.len() {
            return None;
        }
        out.extend_from_slice(&stuffed[at + 1..at + code]);
        at += code;
        if code < 0xFF && at < stuffed.len() {
            out.push(0);
        }
    }
    Some(out)
}

/// A whole wire frame: `COBS(type ‖ payload ‖ crc_lo ‖ crc_hi) ‖ 0x00`.
pub fn encode_frame(message_type: u8, payload: &[u8]) -> Vec<u8> {
    let mut raw = Vec::with_capacity(payload.len() + 3);
    raw.push(message_type);
    raw.extend_from_slice(payload);
    let crc = crc16(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    let mut wire = cobs_encode(&raw);
    wire.push(0);
    wire
}

/// Why a frame was dropped (SPEC section 4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameDrop {
    Cobs,
    Oversize,
    TooShort,
    Crc,
    UnknownType,
    BadLength,
}

/// Decodes the stuffed bytes of one frame (delimiter removed) into `(type, payload)`.
pub fn decode_frame(stuffed: &[u8]) -> Result<(u8, Vec<u8>), FrameDrop> {
    if stuffed.len() > 66 {
        return Err(FrameDrop::Oversize);
    }
    let raw = cobs_decode(stuffed).ok_or(FrameDrop::Cobs)?;
    if raw.len() > 65 {
        return Err(FrameDrop::Oversize);
    }
    if raw.len() < 3 {
        return Err(FrameDrop::TooShort);
    }
    let (body, crc) = raw.split_at(raw.len() - 2);
    if crc16(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameDrop::Crc);
    }
    let message_type = body[0];
    let expected = payload_len(message_type).ok_or(FrameDrop::UnknownType)?;
    if body.len() - 1 != expected {
        return Err(FrameDrop::BadLength);
    }
    Ok((message_type, body[1..].to_vec()))
}

fn u16_at(p: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([p[at], p[at + 1]])
}

fn u32_at(p: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([p[at], p[at + 1], p[at + 2], p[at + 3]])
}

fn f32_at(p: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(p, at))
}

fn vec3_at(p: &[u8], at: usize) -> [f32; 3] {
    [f32_at(p, at), f32_at(p, at + 4), f32_at(p, at + 8)]
}

fn put_vec3(out: &mut Vec<u8>, v: [f32; 3]) {
    for c in v {
        out.extend_from_slice(&c.to_le_bytes());
    }
}

fn label(text: &str) -> [u8; 12] {
    let mut out = [0u8; 12];
    for (slot, byte) in out
        .iter_mut()
        .zip(text.bytes().filter(|b| (0x20..=0x7E).contains(b)))
    {
        *slot = byte;
    }
    out
}

/// SPEC 6.8: a device with 2 DOF uses x and y, one with 1 DOF x alone; the other components are 0. Any other
/// DOF count uses all three.
pub fn used_components(v: [f32; 3], dof: u8) -> [f32; 3] {
    match dof {
        1 => [v[0], 0.0, 0.0],
        2 => [v[0], v[1], 0.0],
        _ => v,
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Configuration.

/// When an injected misbehaviour starts. The device checks each trigger at every control cycle and latches it the
/// first time it holds (logged as a [`TriggerRecord`]); two settings with equal triggers fire at the same cycle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Trigger {
    /// This long after the first accepted Enable.
    AfterFirstEnable(Duration),
    /// At the first control cycle at which the drive is Enabled and the last SetForce received since the latest
    /// Enable was applied and longer than this many newtons: force is flowing at that moment, however long the
    /// host took to get there.
    ForceAbove(f32),
}

/// The time a scripted handle sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleTime {
    /// Seconds since the device was spawned.
    pub since_spawn_s: f64,
    /// Seconds since the first accepted Enable, if there was one.
    pub since_first_enable_s: Option<f64>,
}

/// Handle position (device frame, metres) as a function of time.
pub type HandleFn = Arc<dyn Fn(HandleTime) -> [f32; 3] + Send + Sync>;

/// What the device is and how it misbehaves. `SpecDeviceConfig::default()` is a well-behaved 3-DOF arm, 8 N,
/// stiffness 2000 N/m, workspace ±8 × ±6 × ±5 cm, handle still at (0.02, 0, 0.04) m (the built-in scene's start).
#[derive(Clone)]
pub struct SpecDeviceConfig {
    /// Protocol version sent in DeviceInfo, `(major, minor)`.
    pub version: (u8, u8),
    pub model: String,
    pub serial_number: String,
    pub position_dof: u8,
    pub force_dof: u8,
    pub workspace_min_m: [f32; 3],
    pub workspace_max_m: [f32; 3],
    pub max_force_n: f32,
    pub max_stiffness_n_per_m: f32,
    /// Rate-table bit set (SPEC section 3.2), default {250, 500, 1000} Hz.
    pub supported_rates: u8,
    /// The handle position.
    pub handle: HandleFn,
    /// Reject every Enable with this reason (e.g. [`reject::INVALID_ARGUMENT`]), changing nothing.
    pub refuse_enable: Option<u8>,
    /// Start Faulted with this latched code (Enable is then rejected with FAULTED until ClearFault).
    pub start_faulted: Option<u8>,
    /// Raise `Fault(code)` at the trigger (once). Code 0 drops to Idle; codes ≥ 1 latch.
    pub fault: Option<(Trigger, u8)>,
    /// The first N DeviceInfo replies go out with a bad CRC.
    pub corrupt_device_infos: u32,
    /// Write nothing at all for this long from the trigger (the device still receives, logs and runs its watchdog).
    pub silence: Option<(Trigger, Duration)>,
    /// Every frame is written this long after it was produced.
    pub reply_delay: Duration,
    /// Each DeviceInfo (with its leading 0x00) is written this long after the Hello it answers arrived (on top
    /// of `reply_delay`), and, since the device writes in order, so is everything it produced after it: a device
    /// slow to answer Hello (a bootloader, a USB-serial adapter's latency timer, a long round trip). The session
    /// itself opens when the Hello arrives (SPEC section 6).
    pub device_info_delay: Duration,
    /// `device_info_delay` acts only from this trigger on (`None`: from the start).
    pub device_info_delay_from: Option<Trigger>,
    /// Each written byte is replaced by a random one with this probability (seeded by `seed`).
    pub corrupt_fraction: f64,
    /// Every Nth frame written is cut to its first half, without the delimiter.
    pub partial_frame_every: Option<u32>,
    /// From the trigger on, the reported position is offset by this many metres (an encoder jump).
    pub position_glitch: Option<(Trigger, [f32; 3])>,
    /// From the trigger on, the reported velocity is this constant (m/s) instead of the handle's own.
    pub velocity_override: Option<(Trigger, [f32; 3])>,
    /// Against SPEC 6.8: a 1- or 2-DOF device reports these (position m, velocity m/s) in the components its
    /// `position_dof` leaves unused, instead of 0. (`None`: 0, as the SPEC says.)
    pub unused_components: Option<([f32; 3], [f32; 3])>,
    /// RNG seed for `corrupt_fraction`.
    pub seed: u64,
    /// `corrupt_fraction` and `partial_frame_every` act only from this trigger on (`None`: from the start).
    pub noise_from: Option<Trigger>,
    /// At the trigger the device resets (a brown-out): session closed, Idle, counters and settings back to
    /// power-up, pending replies lost, a lone 0x00 sent as at start-up (SPEC sections 4.3 and 6).
    pub reset: Option<Trigger>,
    /// From the trigger on, the handle stays where it was when the trigger fired (the hand stops moving).
    pub handle_hold: Option<Trigger>,
    /// Called once, on the device thread, at the control cycle the trigger fires: lets a test act on the host at
    /// that exact moment (freeze it, signal it to stop) rather than some scheduling delay later.
    pub call_at: Option<(Trigger, Callback)>,
}

/// A test's action run by the device thread ([`SpecDeviceConfig::call_at`]).
pub type Callback = Arc<dyn Fn() + Send + Sync>;

impl Default for SpecDeviceConfig {
    fn default() -> Self {
        Self {
            version: (1, 0),
            model: "spec-device".to_owned(),
            serial_number: "SPEC-1".to_owned(),
            position_dof: 3,
            force_dof: 3,
            workspace_min_m: [-0.08, -0.06, -0.05],
            workspace_max_m: [0.08, 0.06, 0.05],
            max_force_n: 8.0,
            max_stiffness_n_per_m: 2000.0,
            supported_rates: 0b0001_1100,
            handle: Arc::new(|_| [0.02, 0.0, 0.04]),
            refuse_enable: None,
            start_faulted: None,
            fault: None,
            corrupt_device_infos: 0,
            silence: None,
            reply_delay: Duration::ZERO,
            device_info_delay: Duration::ZERO,
            device_info_delay_from: None,
            corrupt_fraction: 0.0,
            partial_frame_every: None,
            position_glitch: None,
            velocity_override: None,
            unused_components: None,
            seed: 1,
            noise_from: None,
            reset: None,
            handle_hold: None,
            call_at: None,
        }
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Logs.

/// One SetForce as received.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceRecord {
    /// Position in the shared event order of all three logs.
    pub index: u64,
    pub at: Instant,
    /// The host's sequence number.
    pub sequence: u32,
    pub force_n: [f32; 3],
    /// True if the device was Enabled when it arrived (the force is applied, clamped).
    pub enabled: bool,
}

impl ForceRecord {
    /// |force|, newtons (NaN if a component is not finite).
    pub fn magnitude_n(&self) -> f32 {
        self.force_n.iter().map(|f| f * f).sum::<f32>().sqrt()
    }

    pub fn is_finite(&self) -> bool {
        self.force_n.iter().all(|f| f.is_finite())
    }

    pub fn is_zero(&self) -> bool {
        self.force_n == [0.0; 3] || self.force_n.iter().all(|&f| f == 0.0)
    }
}

/// Any host message other than SetForce, plus the port being closed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HostMessage {
    Hello {
        major: u8,
        minor: u8,
    },
    Enable {
        watchdog_timeout_us: u32,
    },
    Disable,
    Heartbeat {
        counter: u32,
    },
    ClearFault,
    SetStateRate {
        hz: u16,
    },
    /// The host closed its end of the pty (seen as a hang-up on the device side).
    PortClosed,
}

/// One non-SetForce message as received.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MessageRecord {
    pub index: u64,
    pub at: Instant,
    pub message: HostMessage,
}

/// One frame as written (after any delay; `intact` is false if it was corrupted or cut on purpose).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SentRecord {
    pub index: u64,
    pub at: Instant,
    pub message_type: u8,
    /// Fault code for a Fault, reason for a Rejected, status bits for a State or HeartbeatReply.
    pub detail: u16,
    pub intact: bool,
}

/// A trigger as it fired (the control cycle at which it first held).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriggerRecord {
    pub index: u64,
    pub at: Instant,
    pub trigger: Trigger,
}

#[derive(Default)]
struct Log {
    next_index: u64,
    forces: Vec<ForceRecord>,
    messages: Vec<MessageRecord>,
    sent: Vec<SentRecord>,
    triggers: Vec<TriggerRecord>,
    dropped_frames: u64,
}

impl Log {
    fn index(&mut self) -> u64 {
        self.next_index += 1;
        self.next_index
    }
}

// ---------------------------------------------------------------------------------------------------------------
// The device.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drive {
    Idle,
    Enabled,
    Faulted,
}

struct Outgoing {
    due: Instant,
    message_type: u8,
    detail: u16,
    bytes: Vec<u8>,
    intact: bool,
}

struct Device {
    config: SpecDeviceConfig,
    master: OwnedFd,
    log: Arc<Mutex<Log>>,
    spawned: Instant,
    // SPEC section 6 state.
    session_open: bool,
    drive: Drive,
    watchdog_timeout_us: u64,
    last_feed: Instant,
    applied_force_n: [f32; 3],
    force_clamped: bool,
    watchdog_tripped: bool,
    faults: u16,
    last_force_sequence: u32,
    state_sequence: u32,
    state_rate_hz: u16,
    next_state_at: Instant,
    // Bookkeeping.
    first_enable: Option<Instant>,
    /// |force| of the last SetForce applied since the latest Enable (`None` until one is).
    last_applied_n: Option<f32>,
    /// Triggers that have fired, and when.
    fired: Vec<(Trigger, Instant)>,
    fault_done: bool,
    reset_done: bool,
    silence_from: Option<Instant>,
    device_infos_sent: u32,
    frames_written: u32,
    rng: u64,
    rx: Vec<u8>,
    rx_overflow: bool,
    outbox: VecDeque<Outgoing>,
    last_position: [f32; 3],
    last_sample_at: Instant,
    host_attached: bool,
    /// Our own fd on the slave side, held until the host has sent its first byte (so nothing written before the
    /// host opens the pty is lost), then closed so that the host closing the port shows as a hang-up.
    slave: Option<OwnedFd>,
}

impl Device {
    fn now_us(&self, at: Instant) -> u64 {
        at.duration_since(self.spawned).as_micros() as u64
    }

    /// Whether `trigger` has fired (latched at a control cycle, [`Device::latch_triggers`]).
    fn triggered(&self, trigger: Trigger) -> bool {
        self.fired_at(trigger).is_some()
    }

    fn fired_at(&self, trigger: Trigger) -> Option<Instant> {
        self.fired
            .iter()
            .find(|(t, _)| *t == trigger)
            .map(|&(_, at)| at)
    }

    /// Whether the condition of `trigger` holds now.
    fn holds(&self, trigger: Trigger, now: Instant) -> bool {
        match trigger {
            Trigger::AfterFirstEnable(d) => self.first_enable.is_some_and(|t| now >= t + d),
            Trigger::ForceAbove(newtons) => {
                self.drive == Drive::Enabled && self.last_applied_n.is_some_and(|f| f > newtons)
            }
        }
    }

    /// Latches every configured trigger whose condition holds now, logs it, and runs a `call_at` action whose
    /// trigger just fired.
    fn latch_triggers(&mut self, now: Instant) {
        let c = &self.config;
        let triggers = [
            c.fault.map(|(t, _)| t),
            c.silence.map(|(t, _)| t),
            c.position_glitch.map(|(t, _)| t),
            c.velocity_override.map(|(t, _)| t),
            c.noise_from,
            c.reset,
            c.handle_hold,
            c.call_at.as_ref().map(|(t, _)| *t),
        ];
        for trigger in triggers.into_iter().flatten() {
            if self.triggered(trigger) || !self.holds(trigger, now) {
                continue;
            }
            self.fired.push((trigger, now));
            if let Some((_, action)) = self.config.call_at.as_ref().filter(|(t, _)| *t == trigger) {
                action();
            }
            let mut log = self.log.lock().unwrap();
            let index = log.index();
            log.triggers.push(TriggerRecord {
                index,
                at: now,
                trigger,
            });
        }
    }

    fn status(&self) -> u16 {
        let mut s = 0;
        if self.session_open {
            s |= status::SESSION_OPEN;
        }
        match self.drive {
            Drive::Enabled => s |= status::ENABLED,
            Drive::Faulted => s |= status::FAULTED,
            Drive::Idle => {}
        }
        if self.watchdog_tripped {
            s |= status::WATCHDOG_TRIPPED;
        }
        if self.force_clamped && self.drive == Drive::Enabled {
            s |= status::FORCE_CLAMPED;
        }
        if self.state_rate_hz == 0 {
            s |= status::LOCKSTEP;
        }
        s
    }

    fn queue(&mut self, message_type: u8, payload: &[u8], detail: u16, now: Instant) {
        let mut bytes = encode_frame(message_type, payload);
        let mut intact = true;
        if message_type == types::DEVICE_INFO {
            self.device_infos_sent += 1;
            if self.device_infos_sent <= self.config.corrupt_device_infos {
                // Flip the CRC (then stuff again so the COBS framing itself stays valid).
                let mut raw = vec![message_type];
                raw.extend_from_slice(payload);
                let crc = crc16(&raw) ^ 0x5A5A;
                raw.extend_from_slice(&crc.to_le_bytes());
                bytes = cobs_encode(&raw);
                bytes.push(0);
                intact = false;
            }
        }
        self.outbox.push_back(Outgoing {
            due: now + self.config.reply_delay,
            message_type,
            detail,
            bytes,
            intact,
        });
    }

    fn reject(&mut self, message_type: u8, reason: u8, now: Instant) {
        self.queue(
            types::REJECTED,
            &[message_type, reason],
            u16::from(reason),
            now,
        );
    }

    fn raise_fault(&mut self, code: u8, now: Instant) {
        if code == fault::WATCHDOG_EXPIRED {
            self.watchdog_tripped = true;
            if self.drive == Drive::Enabled {
                self.drive = Drive::Idle;
            }
        } else {
            self.faults |= 1 << code;
            self.drive = Drive::Faulted;
        }
        self.applied_force_n = [0.0; 3];
        let mut payload = vec![code];
        payload.extend_from_slice(&self.faults.to_le_bytes());
        payload.extend_from_slice(&self.now_us(now).to_le_bytes());
        self.queue(types::FAULT, &payload, u16::from(code), now);
    }

    fn send_device_info(&mut self, now: Instant) {
        let c = &self.config;
        let mut p = vec![c.version.0, c.version.1];
        p.extend_from_slice(&label(&c.model));
        p.extend_from_slice(&label(&c.serial_number));
        p.extend_from_slice(&[c.position_dof, c.force_dof, 0, c.supported_rates]);
        let (min, max) = (c.workspace_min_m, c.workspace_max_m);
        put_vec3(&mut p, min);
        put_vec3(&mut p, max);
        p.extend_from_slice(&c.max_force_n.to_le_bytes());
        p.extend_from_slice(&c.max_stiffness_n_per_m.to_le_bytes());
        // A slow answer: the DeviceInfo is due later; the outbox is written in order, so whatever the device
        // queues after it waits too.
        let slow = self
            .config
            .device_info_delay_from
            .is_none_or(|t| self.triggered(t));
        let now = if slow {
            now + self.config.device_info_delay
        } else {
            now
        };
        // SPEC section 4.3: a lone 0x00 before each DeviceInfo.
        self.outbox.push_back(Outgoing {
            due: now + self.config.reply_delay,
            message_type: 0,
            detail: 0,
            bytes: vec![0],
            intact: true,
        });
        self.queue(types::DEVICE_INFO, &p, 0, now);
    }

    /// The handle as sensed now: scripted position plus any glitch, and the velocity (finite difference or the
    /// injected override).
    fn sample(&mut self, now: Instant) -> ([f32; 3], [f32; 3]) {
        // A held handle is where the script had it when the hold began.
        let script_at = self
            .config
            .handle_hold
            .and_then(|t| self.fired_at(t))
            .unwrap_or(now);
        let time = HandleTime {
            since_spawn_s: script_at.duration_since(self.spawned).as_secs_f64(),
            since_first_enable_s: self
                .first_enable
                .map(|t| script_at.saturating_duration_since(t).as_secs_f64()),
        };
        let mut position = (self.config.handle)(time);
        if let Some((trigger, jump)) = self.config.position_glitch {
            if self.triggered(trigger) {
                for (p, j) in position.iter_mut().zip(jump) {
                    *p += j;
                }
            }
        }
        let dt = now.duration_since(self.last_sample_at).as_secs_f32();
        let mut velocity = if dt > 1e-4 {
            let v = [0, 1, 2].map(|i| (position[i] - self.last_position[i]) / dt);
            self.last_position = position;
            self.last_sample_at = now;
            v
        } else {
            [0.0; 3]
        };
        if let Some((trigger, v)) = self.config.velocity_override {
            if self.triggered(trigger) {
                velocity = v;
            }
        }
        // SPEC 6.8: a 1- or 2-DOF device reports its unused components as 0 (or, misbehaving, as garbage).
        let dof = self.config.position_dof;
        position = used_components(position, dof);
        velocity = used_components(velocity, dof);
        if let Some((garbage_position, garbage_velocity)) = self.config.unused_components {
            let unused = match dof {
                1 | 2 => usize::from(dof)..3,
                _ => 3..3,
            };
            position[unused.clone()].copy_from_slice(&garbage_position[unused.clone()]);
            velocity[unused.clone()].copy_from_slice(&garbage_velocity[unused]);
        }
        (position, velocity)
    }

    fn send_state(&mut self, now: Instant) {
        let (position, velocity) = self.sample(now);
        self.state_sequence = self.state_sequence.wrapping_add(1);
        let mut p = Vec::with_capacity(46);
        p.extend_from_slice(&self.state_sequence.to_le_bytes());
        p.extend_from_slice(&self.now_us(now).to_le_bytes());
        put_vec3(&mut p, position);
        put_vec3(&mut p, velocity);
        p.extend_from_slice(&self.last_force_sequence.to_le_bytes());
        p.extend_from_slice(&0u16.to_le_bytes());
        let status = self.status();
        p.extend_from_slice(&status.to_le_bytes());
        p.extend_from_slice(&self.faults.to_le_bytes());
        self.queue(types::STATE, &p, status, now);
    }

    fn on_frame(&mut self, message_type: u8, p: &[u8], now: Instant) {
        let record = |device: &mut Device, message: HostMessage| {
            let mut log = device.log.lock().unwrap();
            let index = log.index();
            log.messages.push(MessageRecord {
                index,
                at: now,
                message,
            });
        };
        match message_type {
            types::SET_FORCE => {
                let sequence = u32_at(p, 0);
                let force_n = vec3_at(p, 4);
                let flags = u16_at(p, 16);
                {
                    let enabled = self.drive == Drive::Enabled && self.session_open;
                    let mut log = self.log.lock().unwrap();
                    let index = log.index();
                    log.forces.push(ForceRecord {
                        index,
                        at: now,
                        sequence,
                        force_n,
                        enabled,
                    });
                }
                if force_n.iter().any(|f| !f.is_finite()) {
                    // SPEC section 1: dropped as invalid_value; not answered.
                    self.log.lock().unwrap().dropped_frames += 1;
                    return;
                }
                if !self.session_open {
                    return; // SPEC section 6: ignored, not answered.
                }
                self.last_force_sequence = sequence;
                if self.drive == Drive::Enabled {
                    // SPEC 6.8: a 1- or 2-DOF device ignores the components it does not render (the log above
                    // keeps what arrived, so a test still sees them).
                    let force_n = used_components(force_n, self.config.force_dof);
                    let norm = force_n
                        .iter()
                        .map(|f| f64::from(*f).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    self.last_applied_n = Some(norm as f32);
                    let max = f64::from(self.config.max_force_n);
                    if norm > max {
                        self.applied_force_n = force_n.map(|f| (f64::from(f) * max / norm) as f32);
                        self.force_clamped = true;
                    } else {
                        self.applied_force_n = force_n;
                        self.force_clamped = false;
                    }
                    self.last_feed = now;
                }
                // Lockstep: one State per SetForce, sampled now (SPEC section 6.6); REQUEST_STATE when streaming.
                if self.state_rate_hz == 0 || flags & 1 != 0 {
                    self.send_state(now);
                }
            }
            types::HELLO => {
                record(
                    self,
                    HostMessage::Hello {
                        major: p[0],
                        minor: p[1],
                    },
                );
                self.send_device_info(now);
                if self.drive == Drive::Enabled {
                    self.drive = Drive::Idle;
                }
                self.applied_force_n = [0.0; 3];
                self.state_rate_hz = 0;
                self.watchdog_timeout_us = 50_000;
                self.session_open = p[0] == self.config.version.0;
                if !self.session_open {
                    self.reject(types::HELLO, reject::VERSION_MISMATCH, now);
                }
            }
            types::HEARTBEAT => {
                let counter = u32_at(p, 0);
                record(self, HostMessage::Heartbeat { counter });
                let mut reply = counter.to_le_bytes().to_vec();
                reply.extend_from_slice(&self.now_us(now).to_le_bytes());
                let status = self.status();
                reply.extend_from_slice(&status.to_le_bytes());
                self.queue(types::HEARTBEAT_REPLY, &reply, status, now);
            }
            other => {
                let message = match other {
                    types::ENABLE => HostMessage::Enable {
                        watchdog_timeout_us: u32_at(p, 0),
                    },
                    types::DISABLE => HostMessage::Disable,
                    types::CLEAR_FAULT => HostMessage::ClearFault,
                    types::SET_STATE_RATE => HostMessage::SetStateRate { hz: u16_at(p, 0) },
                    _ => return, // a device-to-host type: dropped as unknown_type
                };
                record(self, message);
                if !self.session_open {
                    return self.reject(other, reject::NO_SESSION, now);
                }
                match message {
                    HostMessage::Enable {
                        watchdog_timeout_us,
                    } => self.enable(watchdog_timeout_us, now),
                    HostMessage::Disable => {
                        if self.drive == Drive::Enabled {
                            self.drive = Drive::Idle;
                        }
                        self.applied_force_n = [0.0; 3];
                    }
                    HostMessage::ClearFault if self.drive == Drive::Faulted => {
                        self.faults = 0;
                        self.drive = Drive::Idle;
                    }
                    HostMessage::SetStateRate { hz } => {
                        let table = [100, 200, 250, 500, 1000, 2000, 4000, 8000];
                        let supported = table.iter().enumerate().any(|(bit, &r)| {
                            r == hz && self.config.supported_rates & (1 << bit) != 0
                        });
                        if hz == 0 || supported {
                            self.state_rate_hz = hz;
                            self.next_state_at = now;
                        } else {
                            self.reject(other, reject::INVALID_ARGUMENT, now);
                        }
                    }
                    _ => {}
                }
            }
        }
    }

    fn enable(&mut self, requested_us: u32, now: Instant) {
        if let Some(reason) = self.config.refuse_enable {
            return self.reject(types::ENABLE, reason, now);
        }
        if self.drive == Drive::Faulted {
            return self.reject(types::ENABLE, reject::FAULTED, now);
        }
        let timeout_us = match requested_us {
            0 => 50_000,
            t @ 1_000..=1_000_000 => t,
            _ => return self.reject(types::ENABLE, reject::INVALID_ARGUMENT, now),
        };
        self.drive = Drive::Enabled;
        self.last_applied_n = None;
        self.watchdog_timeout_us = u64::from(timeout_us);
        self.last_feed = now;
        self.applied_force_n = [0.0; 3];
        self.force_clamped = false;
        self.watchdog_tripped = false;
        self.first_enable.get_or_insert(now);
    }

    /// One periodic 1 kHz control cycle: watchdog, injected faults, streamed States.
    fn control_cycle(&mut self, now: Instant) {
        self.latch_triggers(now);
        if self.drive == Drive::Enabled
            && now.duration_since(self.last_feed) > Duration::from_micros(self.watchdog_timeout_us)
        {
            self.raise_fault(fault::WATCHDOG_EXPIRED, now);
        }
        if let Some((trigger, code)) = self.config.fault {
            if !self.fault_done && self.triggered(trigger) {
                self.fault_done = true;
                self.raise_fault(code, now);
            }
        }
        if let Some(trigger) = self.config.reset {
            if !self.reset_done && self.triggered(trigger) {
                self.reset_done = true;
                self.power_up(now);
            }
        }
        if self.silence_from.is_none() {
            if let Some((trigger, _)) = self.config.silence {
                if self.triggered(trigger) {
                    self.silence_from = Some(now);
                }
            }
        }
        if self.session_open && self.state_rate_hz != 0 && now >= self.next_state_at {
            let period = Duration::from_secs_f64(1.0 / f64::from(self.state_rate_hz));
            self.next_state_at = if now.duration_since(self.next_state_at) >= period {
                now + period
            } else {
                self.next_state_at + period
            };
            self.send_state(now);
        }
    }

    /// Back to the power-up state (SPEC section 6: session closed, drive Idle, zero force), as after a reset.
    fn power_up(&mut self, now: Instant) {
        self.session_open = false;
        self.drive = Drive::Idle;
        self.watchdog_timeout_us = 50_000;
        self.applied_force_n = [0.0; 3];
        self.force_clamped = false;
        self.watchdog_tripped = false;
        self.faults = 0;
        self.last_force_sequence = 0;
        self.state_sequence = 0;
        self.state_rate_hz = 0;
        self.rx.clear();
        self.outbox.clear();
        self.outbox.push_back(Outgoing {
            due: now,
            message_type: 0,
            detail: 0,
            bytes: vec![0],
            intact: true,
        });
    }

    fn silent(&self, now: Instant) -> bool {
        match (self.silence_from, self.config.silence) {
            (Some(from), Some((_, duration))) => now < from + duration,
            _ => false,
        }
    }

    fn next_random(&mut self) -> u64 {
        // xorshift64*
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn transmit(&mut self, now: Instant) {
        while self.outbox.front().is_some_and(|o| o.due <= now) {
            let Some(mut out) = self.outbox.pop_front() else {
                break;
            };
            if self.silent(now) {
                continue; // silence: the frame is lost, not postponed
            }
            let noisy = self.config.noise_from.is_none_or(|t| self.triggered(t));
            if out.message_type != 0 && noisy {
                self.frames_written += 1;
                if let Some(every) = self.config.partial_frame_every {
                    if every > 0 && self.frames_written.is_multiple_of(every) {
                        out.bytes.truncate(out.bytes.len() / 2);
                        out.intact = false;
                    }
                }
            }
            if noisy && self.config.corrupt_fraction > 0.0 {
                for i in 0..out.bytes.len() {
                    let r = self.next_random();
                    let unit = (r >> 11) as f64 / (1u64 << 53) as f64;
                    if unit < self.config.corrupt_fraction {
                        out.bytes[i] = (self.next_random() >> 56) as u8;
                        out.intact = false;
                    }
                }
            }
            write_all(self.master.as_raw_fd(), &out.bytes);
            if out.message_type != 0 {
                let mut log = self.log.lock().unwrap();
                let index = log.index();
                log.sent.push(SentRecord {
                    index,
                    at: Instant::now(),
                    message_type: out.message_type,
                    detail: out.detail,
                    intact: out.intact,
                });
            }
        }
    }

    /// Feeds received bytes through the frame collector (SPEC section 4.4).
    fn receive(&mut self, bytes: &[u8], now: Instant) {
        for &b in bytes {
            if b != 0 {
                if self.rx.len() < 66 {
                    self.rx.push(b);
                } else {
                    self.rx_overflow = true;
                }
                continue;
            }
            let frame = std::mem::take(&mut self.rx);
            let overflow = std::mem::replace(&mut self.rx_overflow, false);
            if frame.is_empty() && !overflow {
                continue; // idle filler
            }
            match (overflow, decode_frame(&frame)) {
                (false, Ok((message_type, payload))) => self.on_frame(message_type, &payload, now),
                _ => self.log.lock().unwrap().dropped_frames += 1,
            }
        }
    }

    fn run(mut self, stop: Arc<AtomicBool>) {
        // SPEC section 4.3: a lone 0x00 at start-up.
        write_all(self.master.as_raw_fd(), &[0]);
        let period = Duration::from_millis(1);
        let mut next_cycle = Instant::now();
        let mut buffer = [0u8; 512];
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            let wait = next_cycle.saturating_duration_since(now);
            let wait = match self.outbox.front() {
                Some(o) => wait.min(o.due.saturating_duration_since(now)),
                None => wait,
            };
            let mut pfd = libc::pollfd {
                fd: self.master.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            let wait = wait.min(period);
            let timeout = libc::timespec {
                tv_sec: 0,
                tv_nsec: wait.subsec_nanos() as libc::c_long,
            };
            // SAFETY: one valid pollfd and a valid timespec for the duration of the call; no signal mask.
            let ready = unsafe { libc::ppoll(&mut pfd, 1, &timeout, std::ptr::null()) };
            let now = Instant::now();
            if ready > 0 && pfd.revents & libc::POLLIN != 0 {
                // SAFETY: reading into a buffer we own, at most its length.
                let n = unsafe {
                    libc::read(
                        self.master.as_raw_fd(),
                        buffer.as_mut_ptr().cast(),
                        buffer.len(),
                    )
                };
                if n > 0 {
                    self.host_attached = true;
                    self.slave = None;
                    let received = buffer[..n as usize].to_vec();
                    self.receive(&received, now);
                } else {
                    self.hang_up(now);
                }
            } else if ready > 0 && pfd.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
                self.hang_up(now);
            }
            let now = Instant::now();
            if now >= next_cycle {
                self.control_cycle(now);
                next_cycle += period;
                if next_cycle < now {
                    next_cycle = now + period; // fell behind: skip, never burst
                }
            }
            self.transmit(Instant::now());
        }
    }

    fn hang_up(&mut self, now: Instant) {
        if self.host_attached {
            self.host_attached = false;
            self.rx.clear();
            let mut log = self.log.lock().unwrap();
            let index = log.index();
            log.messages.push(MessageRecord {
                index,
                at: now,
                message: HostMessage::PortClosed,
            });
        }
        // No slave is open: poll reports a hang-up at once, so pace the loop here.
        std::thread::sleep(Duration::from_micros(500));
    }
}

fn write_all(fd: libc::c_int, mut bytes: &[u8]) {
    let deadline = Instant::now() + Duration::from_millis(50);
    while !bytes.is_empty() && Instant::now() < deadline {
        // SAFETY: writing from a slice we own, at most its length.
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        if n > 0 {
            bytes = &bytes[n as usize..];
        } else if std::io::Error::last_os_error().kind() == std::io::ErrorKind::WouldBlock {
            std::thread::sleep(Duration::from_micros(200));
        } else {
            return; // no reader (the host closed the port): the bytes are lost, as on a real line
        }
    }
}

/// Spawns devices.
pub struct SpecDevice;

impl SpecDevice {
    /// Creates a pty, starts the device thread on its master side and returns the handle. The slave side is kept
    /// open (raw mode) until the host has sent its first byte, so that nothing is lost before the host opens it.
    pub fn spawn(config: SpecDeviceConfig) -> SpecDeviceHandle {
        let (mut master, mut slave) = (0, 0);
        let mut name = [0 as libc::c_char; 128];
        // SAFETY: openpty writes two fds and a NUL-terminated name into buffers we own (128 bytes is ample).
        let rc = unsafe {
            libc::openpty(
                &mut master,
                &mut slave,
                name.as_mut_ptr(),
                std::ptr::null(),
                std::ptr::null(),
            )
        };
        assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
        // SAFETY: both fds were just returned by openpty and are owned by nobody else.
        let (master, slave) =
            unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        // SAFETY: termios is plain data; tcgetattr fills it, cfmakeraw edits it, tcsetattr applies it to our fd.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(slave.as_raw_fd(), &mut t), 0);
            libc::cfmakeraw(&mut t);
            assert_eq!(libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t), 0);
            let flags = libc::fcntl(master.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        // SAFETY: openpty NUL-terminated the name.
        let path = unsafe { CStr::from_ptr(name.as_ptr()) }
            .to_string_lossy()
            .into_owned();
        let log = Arc::new(Mutex::new(Log::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let now = Instant::now();
        let drive = if config.start_faulted.is_some() {
            Drive::Faulted
        } else {
            Drive::Idle
        };
        let faults = config.start_faulted.map_or(0, |code| 1u16 << code);
        let device = Device {
            rng: config.seed.max(1),
            config,
            master,
            log: Arc::clone(&log),
            spawned: now,
            session_open: false,
            drive,
            watchdog_timeout_us: 50_000,
            last_feed: now,
            applied_force_n: [0.0; 3],
            force_clamped: false,
            watchdog_tripped: false,
            faults,
            last_force_sequence: 0,
            state_sequence: 0,
            state_rate_hz: 0,
            next_state_at: now,
            first_enable: None,
            last_applied_n: None,
            fired: Vec::new(),
            fault_done: false,
            reset_done: false,
            silence_from: None,
            device_infos_sent: 0,
            frames_written: 0,
            rx: Vec::with_capacity(66),
            rx_overflow: false,
            outbox: VecDeque::new(),
            last_position: [0.0; 3],
            last_sample_at: now,
            host_attached: false,
            slave: Some(slave),
        };
        let thread_stop = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("spec-device".to_owned())
            .spawn(move || device.run(thread_stop))
            .expect("spawn the spec device thread");
        SpecDeviceHandle {
            path,
            log,
            stop,
            thread: Some(thread),
        }
    }
}

/// A running device; stopped (thread joined, pty closed) by [`SpecDeviceHandle::stop`] or on drop.
pub struct SpecDeviceHandle {
    path: String,
    log: Arc<Mutex<Log>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl SpecDeviceHandle {
    /// The pty slave path; the host opens it as `serial:PATH`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Every SetForce received so far, in order.
    pub fn forces(&self) -> Vec<ForceRecord> {
        self.log.lock().unwrap().forces.clone()
    }

    /// Every other message received so far (and `PortClosed` events), in order.
    pub fn messages(&self) -> Vec<MessageRecord> {
        self.log.lock().unwrap().messages.clone()
    }

    /// Every frame written so far, in order.
    pub fn sent(&self) -> Vec<SentRecord> {
        self.log.lock().unwrap().sent.clone()
    }

    /// When `trigger` fired, if it has.
    pub fn fired(&self, trigger: Trigger) -> Option<TriggerRecord> {
        self.log
            .lock()
            .unwrap()
            .triggers
            .iter()
            .find(|r| r.trigger == trigger)
            .copied()
    }

    /// The last SetForce received, if any (cheap: nothing else is copied).
    pub fn last_force(&self) -> Option<ForceRecord> {
        self.log.lock().unwrap().forces.last().copied()
    }

    /// The number of SetForce frames received so far (cheap: nothing is copied).
    pub fn force_count(&self) -> usize {
        self.log.lock().unwrap().forces.len()
    }

    /// The number of SetForce frames received after `instant` (cheap: nothing is copied).
    pub fn force_count_after(&self, instant: Instant) -> usize {
        let log = self.log.lock().unwrap();
        log.forces.len() - log.forces.partition_point(|f| f.at <= instant)
    }

    /// The number of SetForce frames received after the event with this `index` (cheap: nothing is copied).
    pub fn force_count_after_index(&self, index: u64) -> usize {
        let log = self.log.lock().unwrap();
        log.forces.len() - log.forces.partition_point(|f| f.index <= index)
    }

    /// Frames received and dropped (bad COBS, CRC, length, type, or a non-finite force).
    pub fn dropped_frames(&self) -> u64 {
        self.log.lock().unwrap().dropped_frames
    }

    /// Stops the device thread and closes the pty.
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }

    /// Messages of one kind (compared by variant).
    pub fn messages_like(&self, like: HostMessage) -> Vec<MessageRecord> {
        self.messages()
            .into_iter()
            .filter(|m| std::mem::discriminant(&m.message) == std::mem::discriminant(&like))
            .collect()
    }

    /// The largest |force| received while the device was not Enabled (0 if none).
    pub fn max_force_while_not_enabled(&self) -> f32 {
        self.forces()
            .iter()
            .filter(|f| !f.enabled)
            .map(|f| {
                if f.is_finite() {
                    f.magnitude_n()
                } else {
                    f32::INFINITY
                }
            })
            .fold(0.0, f32::max)
    }

    /// The largest |force| received (infinite if any was not finite).
    pub fn max_force_n(&self) -> f32 {
        self.forces()
            .iter()
            .map(|f| {
                if f.is_finite() {
                    f.magnitude_n()
                } else {
                    f32::INFINITY
                }
            })
            .fold(0.0, f32::max)
    }

    /// SetForce frames with a non-finite component.
    pub fn non_finite_forces(&self) -> usize {
        self.forces().iter().filter(|f| !f.is_finite()).count()
    }

    /// The steepest rise of |force| between consecutive SetForce frames, per host tick: the rise divided by the
    /// number of sequence steps between them (at least 1). At the host's 1 kHz rate one tick is 1 ms, so this is
    /// the slew in N per ms, independent of when the frames happened to arrive.
    pub fn max_slew_n_per_ms(&self) -> f32 {
        let forces = self.forces();
        forces
            .windows(2)
            .map(|w| {
                let steps = w[1].sequence.wrapping_sub(w[0].sequence).clamp(1, 1000);
                (w[1].magnitude_n() - w[0].magnitude_n()) / steps as f32
            })
            .fold(0.0, f32::max)
    }

    /// Non-zero SetForce frames received after the event with this `index`.
    pub fn nonzero_forces_after_index(&self, index: u64) -> usize {
        self.forces()
            .iter()
            .filter(|f| f.index > index && !f.is_zero())
            .count()
    }
}

impl Drop for SpecDeviceHandle {
    fn drop(&mut self) {
        self.stop();
    }
}
