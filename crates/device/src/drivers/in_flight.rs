//! The commands a request/reply link has sent whose replies have not been read yet, for a device that answers
//! each command with one reply, in order, without a sequence number, and whose reply may come after the next
//! command went out: the Novint Falcon, whose 16-byte reply waits for the FTDI latency timer (1 ms) and the next
//! 1 ms USB frame, so it comes 1-2 ms after its command ([`crate::latency::FALCON`]), later than a 1 kHz
//! servo tick's wait.
//!
//! The i-th reply answers the i-th command, so a reply read while `k` later commands are still unanswered is
//! `k` ticks old: the age this core reports. A reply that never comes would make every later reply look one
//! tick older than it is (the safe direction). A reply that came garbled (a malformed frame the receive core
//! dropped) is written off at once ([`InFlight::write_off`]); one that never came is written off once the
//! port was found empty longer than `lost_after` after its command ([`InFlight::nothing_waiting`]): a bound
//! well beyond the link's documented worst latency, since writing off a reply that is merely late would make
//! the later ones look younger than they are. A
//! reply when no command is unanswered answers nothing (a device that answered twice): the next state is
//! reported one tick older, as [`super::reply_age::ReplyAge`] does.
//!
//! A protocol core: no I/O and no clock reads (the caller passes the times in), and no allocation.

use std::time::{Duration, Instant};

/// The most commands kept unanswered; beyond it the oldest is written off as lost (a 2 ms worst latency at
/// 4 kHz is 8).
pub const IN_FLIGHT_CAPACITY: usize = 32;

/// The unanswered commands of one link (module docs). Cleared on every open.
#[derive(Debug, Clone)]
pub struct InFlight {
    /// When each unanswered command went out, oldest first, as a ring.
    sent_at: [Option<Instant>; IN_FLIGHT_CAPACITY],
    head: usize,
    len: usize,
    /// A reply not waiting this long after its command never came.
    lost_after: Duration,
    /// A reply that answered nothing was dropped since the last state.
    out_of_step: bool,
    /// Replies written off as lost since the last clear.
    lost: u64,
}

impl InFlight {
    /// No command unanswered; a reply not waiting `lost_after` after its command counts as lost.
    pub fn new(lost_after: Duration) -> Self {
        InFlight {
            sent_at: [None; IN_FLIGHT_CAPACITY],
            head: 0,
            len: 0,
            lost_after,
            out_of_step: false,
            lost: 0,
        }
    }

    /// Forgets every command (the link was opened again and its queues purged).
    pub fn clear(&mut self) {
        *self = InFlight::new(self.lost_after);
    }

    /// A command went out at `at`. With [`IN_FLIGHT_CAPACITY`] unanswered, the oldest is written off.
    pub fn command_sent(&mut self, at: Instant) {
        if self.len == IN_FLIGHT_CAPACITY {
            self.pop_oldest();
            self.lost += 1;
        }
        let slot = (self.head + self.len) % IN_FLIGHT_CAPACITY;
        self.sent_at[slot] = Some(at);
        self.len += 1;
    }

    /// A reply was read: it answers the oldest unanswered command (true), or none (false: a reply nobody asked
    /// for, and the next state is reported a tick older).
    pub fn reply_read(&mut self) -> bool {
        if self.pop_oldest().is_some() {
            true
        } else {
            self.out_of_step = true;
            false
        }
    }

    /// `n` replies came garbled and were dropped: the `n` oldest commands are answered.
    pub fn write_off(&mut self, n: u64) {
        for _ in 0..n {
            if self.pop_oldest().is_none() {
                break;
            }
            self.lost += 1;
        }
    }

    /// The port held no reply when it was read at `at`: every command sent more than `lost_after` before
    /// `at` has lost its reply. Returns how many were written off.
    pub fn nothing_waiting(&mut self, at: Instant) -> u32 {
        let mut written_off = 0;
        while let Some(sent) = self.oldest() {
            if at.saturating_duration_since(sent) <= self.lost_after {
                break;
            }
            self.pop_oldest();
            self.lost += 1;
            written_off += 1;
        }
        written_off
    }

    /// The age (ticks) of the newest reply read, handed out now: the commands sent after the one it answers,
    /// plus one after a reply that answered nothing. Starts the out-of-step count over.
    pub fn state_age(&mut self) -> u32 {
        let age = u32::try_from(self.len)
            .unwrap_or(u32::MAX)
            .saturating_add(u32::from(self.out_of_step));
        self.out_of_step = false;
        age
    }

    /// Commands unanswered.
    pub fn unanswered(&self) -> usize {
        self.len
    }

    /// Replies written off as lost since the last clear.
    pub fn lost(&self) -> u64 {
        self.lost
    }

    fn oldest(&self) -> Option<Instant> {
        if self.len == 0 {
            None
        } else {
            self.sent_at[self.head]
        }
    }

    fn pop_oldest(&mut self) -> Option<Instant> {
        let oldest = self.oldest()?;
        self.sent_at[self.head] = None;
        self.head = (self.head + 1) % IN_FLIGHT_CAPACITY;
        self.len -= 1;
        Some(oldest)
    }
}

#[cfg(test)]
mod tests {
    use super::{InFlight, IN_FLIGHT_CAPACITY};
    use std::time::{Duration, Instant};

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// One reply per command, in order, each coming 1-2 ms after it at 1 kHz (libnifalcon's link: the FTDI
    /// latency timer of 1 ms, FalconCommLibUSB.cpp:560, then a 1 ms USB frame): worked out by hand, the reply
    /// read in tick n answers command n-1 and is one tick old; a reply that came two ticks late is two.
    #[test]
    fn a_reply_read_behind_k_unanswered_commands_is_k_ticks_old() {
        let t0 = Instant::now();
        let mut flight = InFlight::new(ms(2));
        flight.command_sent(t0);
        // Tick 1: nothing came in tick 0's wait; command 1 goes out, then reply 0 arrives.
        flight.nothing_waiting(t0);
        flight.command_sent(t0 + ms(1));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 1);
        // Tick 2: command 2, reply 1.
        flight.command_sent(t0 + ms(2));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 1);
        // Tick 3: reply 2 is late; command 3 and 4 go out before it comes.
        flight.command_sent(t0 + ms(3));
        flight.command_sent(t0 + ms(4));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 2);
        assert_eq!(flight.unanswered(), 2);
        assert_eq!(flight.lost(), 0);
    }

    /// A reply that never came is written off only once the port was empty longer than the worst latency
    /// after its command; until then the next replies are reported older (never younger) than they are.
    #[test]
    fn a_lost_reply_is_written_off_after_the_worst_latency() {
        let t0 = Instant::now();
        let mut flight = InFlight::new(ms(2));
        flight.command_sent(t0);
        flight.command_sent(t0 + ms(1));
        // At 2 ms command 0's reply may still come.
        assert_eq!(flight.nothing_waiting(t0 + ms(2)), 0);
        flight.command_sent(t0 + ms(2));
        // At 3 ms it cannot: written off; command 1's (sent at 1 ms) may still come.
        assert_eq!(flight.nothing_waiting(t0 + ms(3)), 1);
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 1);
        assert_eq!(flight.lost(), 1);
        // A garbled reply answers the oldest command at once.
        flight.command_sent(t0 + ms(3));
        flight.write_off(1);
        assert_eq!((flight.unanswered(), flight.lost()), (1, 2));
    }

    /// A reply when nothing is unanswered answers nothing: the next state is one tick older, once.
    #[test]
    fn a_reply_nobody_asked_for_ages_the_next_state_once() {
        let t0 = Instant::now();
        let mut flight = InFlight::new(ms(2));
        assert!(!flight.reply_read());
        flight.command_sent(t0);
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 1);
        flight.command_sent(t0);
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(), 0);
    }

    /// A full ring writes off its oldest command rather than growing.
    #[test]
    fn a_full_ring_writes_off_the_oldest() {
        let t0 = Instant::now();
        let mut flight = InFlight::new(ms(2));
        for _ in 0..=IN_FLIGHT_CAPACITY {
            flight.command_sent(t0);
        }
        assert_eq!(flight.unanswered(), IN_FLIGHT_CAPACITY);
        assert_eq!(flight.lost(), 1);
        flight.clear();
        assert_eq!((flight.unanswered(), flight.lost()), (0, 0));
    }
}
