//! How old the state a request/reply driver hands out may be, for devices whose replies carry no sequence
//! number (WoodenHaptics serial, Haply 2DIY, Novint Falcon): one reply per command, in order.
//!
//! A reply read after command n answers n, or an earlier command whose reply missed its read (it timed out and
//! the reply came later), or, from a device that answers more than once, an earlier command answered again. The
//! bytes cannot tell these apart, so the driver reports the oldest the reply may be, in commands (servo ticks):
//! the commands in a row before n whose reply never came, plus one when the device was out of step just
//! before (a late reply or lines nobody asked for were dropped since the last reply). A clean exchange reports
//! 0; a device that answers twice reports 1 on every tick; after `k` missed replies the next state reports `k`
//! (or more). The supervisor counts this age towards its staleness bound (`stale_state_ticks`): a state it says
//! is older than the bound is never used to compute force. Allocation-free, no clock.
//!
//! How long a driver waits for the reply to this tick's command ([`reply_wait`]) derives from the servo
//! period: three quarters of it, so a reply that never comes costs at most one tick (the supervisor writes the
//! command and then reads the state in the same tick; the rest of the tick is the solve's).

use std::time::Duration;

/// The shortest reply wait, whatever the period (a reply wait of zero would only poll).
pub const MIN_REPLY_WAIT: Duration = Duration::from_micros(50);

/// The reply wait at the default 1 kHz servo rate: [`reply_wait`] of 1 ms.
pub const DEFAULT_REPLY_WAIT: Duration = Duration::from_micros(750);

/// The longest a request/reply driver waits for the reply to this tick's command in a servo loop of `period`:
/// three quarters of the period, at least [`MIN_REPLY_WAIT`].
pub fn reply_wait(period: Duration) -> Duration {
    (period * 3 / 4).max(MIN_REPLY_WAIT)
}

/// The age bookkeeping of one link (module docs). Reset on every open.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct ReplyAge {
    /// Commands in a row, before the one awaited, whose reply never came.
    missed: u32,
    /// A command was sent and its reply not read yet.
    awaiting: bool,
    /// Lines nobody asked for, or a late reply, were dropped since the last reply.
    out_of_step: bool,
    /// The age of the last reply read (commands).
    age: u32,
}

impl ReplyAge {
    /// A command went out. The one before it, if its reply is still awaited, missed it.
    pub fn command_sent(&mut self) {
        if self.awaiting {
            self.missed = self.missed.saturating_add(1);
        }
        self.awaiting = true;
    }

    /// A reply that came after its read had timed out was dropped (before the next command): the command it
    /// answers is accounted for, but the device is out of step.
    pub fn late_reply_dropped(&mut self) {
        if self.awaiting {
            self.awaiting = false;
        } else {
            self.missed = self.missed.saturating_sub(1);
        }
        self.out_of_step = true;
    }

    /// Lines nobody asked for were dropped (before a command or behind a reply).
    pub fn surplus_dropped(&mut self) {
        self.out_of_step = true;
    }

    /// A reply was read: returns its age (module docs); the bookkeeping starts over from it.
    pub fn reply_read(&mut self) -> u32 {
        let age = self.missed.saturating_add(u32::from(self.out_of_step));
        *self = ReplyAge {
            age,
            ..ReplyAge::default()
        };
        age
    }

    /// The age of the last reply read.
    pub fn age(&self) -> u32 {
        self.age
    }
}

#[cfg(test)]
mod tests {
    use super::{reply_wait, ReplyAge, DEFAULT_REPLY_WAIT, MIN_REPLY_WAIT};
    use std::time::Duration;

    /// A lost reply costs less than one tick at any period, and the default is the 1 kHz value.
    #[test]
    fn the_reply_wait_fits_in_one_tick() {
        for period_us in [100u64, 250, 500, 1_000, 2_000, 4_000] {
            let period = Duration::from_micros(period_us);
            assert!(reply_wait(period) < period, "{period:?}");
            assert!(reply_wait(period) >= MIN_REPLY_WAIT);
        }
        assert_eq!(reply_wait(Duration::from_millis(1)), DEFAULT_REPLY_WAIT);
        assert_eq!(reply_wait(Duration::from_micros(20)), MIN_REPLY_WAIT);
    }

    /// The cases of the module docs, each worked out by hand from one reply per command, in order: the steps
    /// since the last reply read, then the age of the next reply read.
    #[test]
    fn ages_follow_the_commands_a_reply_may_answer() {
        // One step between two replies read.
        type Step = fn(&mut ReplyAge);
        let sent: Step = ReplyAge::command_sent;
        let surplus: Step = ReplyAge::surplus_dropped;
        let late: Step = ReplyAge::late_reply_dropped;
        let cases: [(&str, &[Step], u32); 5] = [
            ("clean lockstep", &[sent], 0),
            // The reply read after the third command may answer the first of them, two commands before it.
            ("two replies missed", &[sent, sent, sent], 2),
            ("back in step", &[sent], 0),
            // A second answer dropped before the command: the reply read may be another one (one tick old).
            ("a second answer dropped", &[sent, surplus], 1),
            // A reply that missed its read came before the next command and was dropped: the next reply may
            // be late too.
            ("a late reply dropped", &[sent, late, sent], 1),
        ];
        let mut age = ReplyAge::default();
        for (case, steps, expected) in cases {
            for step in steps {
                step(&mut age);
            }
            assert_eq!(age.reply_read(), expected, "{case}");
        }
        assert_eq!(age.age(), 1);
    }
}
