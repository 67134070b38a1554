//! The Inverse Service link's protocol core: what the I/O thread sends, how each message the service sends is
//! counted against the messages sent, how the published state is labelled, when the link is flooded, and how
//! old a state the servo thread takes may be. Decoded messages and times in; commands, labelled states, ages
//! and faults out. No I/O, no clock reads, no allocation (the quinn-proto pattern): the I/O thread
//! (`haply_inverse_io.rs`) only moves messages between the WebSocket and this core, through the shared runner
//! ([`crate::drivers::exchange::messages_within`]).
//!
//! The rules it keeps, from Haply's documents (docs.haply.co/inverseSDK/service/api/simulation "Simulation
//! Channel", "Core contract": after the inventory "the server sends exactly one State Update message for each
//! message received from the client"; docs.haply.co/inverseSDK/service/realtime/websocket-protocol "Core rule:
//! one response per message"):
//!
//! - **Replies in order.** The i-th message the service sends after the inventory answers the i-th message
//!   sent. A message that comes when every message sent has had its reply is an **extra** (a second reply, an
//!   unsolicited update: outside Haply's contract); it updates the position, is counted, and answers nothing.
//! - **Labels never younger than the state.** Each state published is labelled with the sequence of the force
//!   it answers at the latest: its reply's message, but never one sent after the socket was last found empty
//!   (the floor). TCP keeps the order, so every message read after the socket was found empty was written by
//!   the service after the force sent before that moment; counted against the wrong force because of extras,
//!   a state is still at most as new as that force. So the age the driver reports ([`judge`]) is never younger
//!   than the state is, whatever the service sends.
//! - **Drain.** Every message already received is read before each send and while waiting for a reply, so a
//!   service that sends more than one message per command builds no backlog; more than
//!   [`MAX_DRAIN_MESSAGES`] read without the socket once found empty is a flood ([`LinkFault::Flooded`]).
//! - **Keepalive.** With no force queued for [`KEEPALIVE_INTERVAL`] a zero force goes out, labelled with the
//!   newest sequence sent (Haply's tutorial "01. Print Inverse3" keeps its session ticking the same way).
//!   A non-finite force is never sent (zero instead).

use crate::transport::inverse_service::events::SafetyEvent;
use crate::transport::inverse_service::{
    ForceCommand, ServiceSnapshot, WireError, WireFrame, FORCE_RING_CAPACITY, KEEPALIVE_INTERVAL,
    MAX_DRAIN_MESSAGES,
};
use glam::DVec3;
use std::time::{Duration, Instant};

/// Fault code of a Haply e-brake (`ebrake_triggered`): voxhap's "emergency stop".
pub const FAULT_EMERGENCY_STOP: u8 = 1;
/// Fault code of a Haply motor stall (`stall_detected`).
pub const FAULT_MOTOR_STALL: u8 = 8;
/// Fault code of Haply's stability ceiling (`stability_ceiling`).
pub const FAULT_STABILITY_CEILING: u8 = 9;

/// What the runner read from the service, decoded (the decoder is `inverse_wire`).
#[derive(Debug, Clone, Copy)]
pub enum Incoming<'a> {
    /// A text message that decoded.
    Frame(&'a WireFrame),
    /// A text message the decoder refused (not JSON, or a field in another type than Haply documents).
    Undecodable(&'a WireError),
    /// A binary message (the service sends text).
    Binary,
}

/// What one message did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Took {
    /// It held a usable state for the driven device: publish this snapshot.
    State(ServiceSnapshot),
    /// It held none (counted as malformed); `drift`: because of a type drift.
    Unused {
        /// A field voxhap uses came in another JSON type than Haply documents.
        drift: bool,
    },
}

/// A fault of the link itself (the link is dropped and opened again).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkFault {
    /// More than [`MAX_DRAIN_MESSAGES`] read without the socket once found empty.
    Flooded,
}

/// One message to send.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outgoing {
    /// The force's sequence (a keepalive carries the newest sent).
    pub sequence: u64,
    /// The force (N, Haply's frame), always finite.
    pub force_n: DVec3,
}

/// The counters the link reports (module docs); mirrored into the shared atomics by the I/O thread.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Messages sent (forces and keepalives).
    pub sent: u64,
    /// States received and used.
    pub states: u64,
    /// Messages that could not be used.
    pub malformed: u64,
    /// Forces dropped because a newer one was queued behind them.
    pub coalesced: u64,
    /// Messages beyond one reply per message sent.
    pub extra: u64,
    /// Messages with a type drift (counted in `malformed` too).
    pub drifted: u64,
}

/// The link's protocol state (module docs). One per connection.
#[derive(Debug, Clone)]
pub struct LinkCore {
    /// Sequences of the messages sent whose replies have not come, oldest first, as a ring.
    unanswered: [u64; FORCE_RING_CAPACITY],
    head: usize,
    len: usize,
    /// The newest force sequence sent.
    last_sent: u64,
    /// The newest force sequence sent before the socket was last found empty.
    floor: u64,
    /// Messages read since the socket was last found empty.
    since_empty: usize,
    /// When the last message went out (the start, before the first).
    last_send_at: Instant,
    /// The newest state, with its label.
    snapshot: ServiceSnapshot,
    counters: LinkCounters,
}

impl LinkCore {
    /// A link whose session set-up left `snapshot` (label 0: it answers no force), started at `now` (the first
    /// keepalive is due [`KEEPALIVE_INTERVAL`] after it).
    pub fn new(snapshot: ServiceSnapshot, now: Instant) -> Self {
        LinkCore {
            unanswered: [0; FORCE_RING_CAPACITY],
            head: 0,
            len: 0,
            last_sent: 0,
            floor: 0,
            since_empty: 0,
            last_send_at: now,
            snapshot: ServiceSnapshot {
                answers_sequence: 0,
                ..snapshot
            },
            counters: LinkCounters::default(),
        }
    }

    /// What to send at `now`: the newest queued force (`newest`, with `dropped` older ones queued behind it
    /// coalesced away), else a zero keepalive when nothing went out for [`KEEPALIVE_INTERVAL`], else nothing.
    pub fn next_command(
        &mut self,
        newest: Option<ForceCommand>,
        dropped: u64,
        now: Instant,
    ) -> Option<Outgoing> {
        self.counters.coalesced += dropped;
        let (sequence, force_n) = match newest {
            Some(command) => (command.sequence, command.force_n),
            None => {
                if now.saturating_duration_since(self.last_send_at) < KEEPALIVE_INTERVAL {
                    return None;
                }
                (self.last_sent, DVec3::ZERO)
            }
        };
        let force_n = if force_n.is_finite() {
            force_n
        } else {
            DVec3::ZERO
        };
        Some(Outgoing { sequence, force_n })
    }

    /// A message went out at `at`. With [`FORCE_RING_CAPACITY`] messages unanswered the oldest is forgotten
    /// (the driver has long reported the missing states).
    pub fn command_sent(&mut self, sequence: u64, at: Instant) {
        self.last_send_at = at;
        self.last_sent = self.last_sent.max(sequence);
        self.counters.sent += 1;
        if self.len == FORCE_RING_CAPACITY {
            self.head = (self.head + 1) % FORCE_RING_CAPACITY;
            self.len -= 1;
        }
        self.unanswered[(self.head + self.len) % FORCE_RING_CAPACITY] = sequence;
        self.len += 1;
    }

    /// A reply is still awaited (some message sent has had none).
    pub fn awaiting(&self) -> bool {
        self.len > 0
    }

    /// The socket had nothing more to read: every message read from now on was written after the newest
    /// force sent so far.
    pub fn socket_empty(&mut self) {
        self.floor = self.last_sent;
        self.since_empty = 0;
    }

    /// One message from the service, for the device `device_id`: the reply to the oldest unanswered message,
    /// or an extra one.
    pub fn message(&mut self, incoming: Incoming<'_>, device_id: &str) -> Result<Took, LinkFault> {
        self.since_empty += 1;
        if self.since_empty > MAX_DRAIN_MESSAGES {
            return Err(LinkFault::Flooded);
        }
        let answers = if self.len > 0 {
            let sequence = self.unanswered[self.head];
            self.head = (self.head + 1) % FORCE_RING_CAPACITY;
            self.len -= 1;
            Some(sequence)
        } else {
            self.counters.extra += 1;
            None
        };
        let used = match incoming {
            Incoming::Frame(frame) => frame
                .inverse3
                .iter()
                .find(|entry| entry.device_id == device_id)
                .is_some_and(|entry| self.snapshot.apply(entry.state.as_ref())),
            Incoming::Undecodable(WireError::TypeDrift { .. }) => {
                self.counters.drifted += 1;
                self.counters.malformed += 1;
                return Ok(Took::Unused { drift: true });
            }
            Incoming::Undecodable(WireError::NotJson { .. }) | Incoming::Binary => false,
        };
        if !used {
            self.counters.malformed += 1;
            return Ok(Took::Unused { drift: false });
        }
        // An extra message updates the position and keeps the label.
        if let Some(answers) = answers {
            let label = answers.min(self.floor);
            self.snapshot.answers_sequence = self.snapshot.answers_sequence.max(label);
        }
        self.counters.states += 1;
        Ok(Took::State(self.snapshot))
    }

    /// The counters so far.
    pub fn counters(&self) -> LinkCounters {
        self.counters
    }

    /// The newest state and its label.
    pub fn snapshot(&self) -> ServiceSnapshot {
        self.snapshot
    }
}

/// What the servo thread does with the newest state it found while it waits for the one answering its
/// newest force.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Use it; it is this many ticks (forces) old.
    Use {
        /// Forces sent after the one the state answers.
        age_ticks: u32,
    },
    /// Not yet: wait on (the wait is not over).
    Wait,
    /// The wait is over and no state recent enough came.
    Late,
}

/// The servo thread's verdict on a state labelled `answers` (0: it answers no force) while it wants the
/// answer to force `wanted`: used at once when it answers `wanted`; once the wait is over (`waited_out`) used
/// if it answers one of the `max_stale_ticks` forces before (with that age), else late. Its age counts
/// towards the supervisor's staleness bound.
pub fn judge(answers: u64, wanted: u64, waited_out: bool, max_stale_ticks: u64) -> Verdict {
    let age = wanted.saturating_sub(answers);
    let usable = answers >= wanted || (waited_out && answers > 0 && age <= max_stale_ticks);
    if usable {
        Verdict::Use {
            age_ticks: u32::try_from(age).unwrap_or(u32::MAX),
        }
    } else if waited_out {
        Verdict::Late
    } else {
        Verdict::Wait
    }
}

/// The device fault a Haply safety event is, in voxhap's fault table (docs/safety.md): an e-brake is the
/// emergency stop (1), a stall the motor stall (8), the stability ceiling its own fault (9).
pub fn fault_code(event: SafetyEvent) -> u8 {
    match event {
        SafetyEvent::EbrakeTriggered => FAULT_EMERGENCY_STOP,
        SafetyEvent::StallDetected => FAULT_MOTOR_STALL,
        SafetyEvent::StabilityCeiling => FAULT_STABILITY_CEILING,
    }
}

/// The longest the servo thread waits for this tick's answer at a servo `period`: the configured wait, but
/// never more than 0.4 of the period, so a late answer costs less than half a tick at any rate (0.4 ms at
/// 1 kHz, the default).
pub fn reply_wait_for(configured: Duration, period: Duration) -> Duration {
    configured.min(period * 2 / 5)
}

#[cfg(test)]
#[path = "haply_inverse_link_tests.rs"]
mod tests;
