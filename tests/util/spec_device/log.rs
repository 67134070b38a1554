//! What the device logs: every SetForce and every other message received, every frame written and every trigger
//! as it fired, in one order (a shared event index).

use super::config::Trigger;
use std::time::Instant;

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
pub(super) struct Log {
    pub(super) next_index: u64,
    pub(super) forces: Vec<ForceRecord>,
    pub(super) messages: Vec<MessageRecord>,
    pub(super) sent: Vec<SentRecord>,
    pub(super) triggers: Vec<TriggerRecord>,
    pub(super) dropped_frames: u64,
}

impl Log {
    pub(super) fn index(&mut self) -> u64 {
        self.next_index += 1;
        self.next_index
    }
}
