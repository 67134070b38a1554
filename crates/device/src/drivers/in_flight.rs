//! The commands a request/reply link has sent whose replies have not been read yet, for a device that answers
//! each command with one reply, in order, without a sequence number, and whose reply may come after the next
//! command went out: the Novint Falcon, whose 16-byte reply waits for the FTDI latency timer (1 ms) and the next
//! 1 ms USB frame, so it comes 1-2 ms after its command ([`crate::latency::FALCON`]), later than a 1 kHz
//! servo tick's wait.
//!
//! The i-th reply answers the i-th command, so a reply read while `k` later commands are still unanswered is
//! `k` ticks old: the age this core reports, while it is sure of its count ([`Tally::Counting`]). A reply that
//! never comes makes every later reply look older than it is (the safe direction); so does a reply when no
//! command is unanswered (a device that answered twice: the next state is reported one tick older, as
//! [`super::reply_age::ReplyAge`] does).
//!
//! The count is never guessed down. Bytes that are not a well-formed frame may be a garbled reply or junk that
//! answers nothing; a reply missing `lost_after` after its command may be lost or merely late; a count that
//! keeps the states older than the staleness bound may hide lost replies. Writing a reply off in any of these
//! cases could make a later state look younger than it is, so instead the core resynchronises
//! ([`Tally::Resync`]): every age is unknown ([`UNKNOWN_AGE`]), one zero-torque command goes out and then
//! none, until no byte has come for `lost_after` after the last command or byte. Then every reply still owed
//! has come or never will, nothing is unanswered, and counting starts again from an exact zero. This is how
//! libnifalcon runs the link all the time: it sends the next frame only once the previous one was answered
//! (src/firmware/FalconFirmwareNovintSDK.cpp:113-154).
//!
//! A protocol core: no I/O and no clock reads (the caller passes the times in), and no allocation.

use std::time::{Duration, Instant};

/// The most commands kept unanswered; beyond it the count is not trusted and the link resynchronises (a 2 ms
/// worst latency at 4 kHz is 8).
pub const IN_FLIGHT_CAPACITY: usize = 32;

/// The age of a state the core cannot place: older than any staleness bound.
pub const UNKNOWN_AGE: u32 = u32::MAX;

/// Whether the core's count is exact.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tally {
    /// The count is exact, up to replies not yet known to be lost (which make states look older).
    Counting {
        /// Since when every state's age has been above the resynchronising age (`None` when the last one was
        /// not).
        over_age_since: Option<Instant>,
    },
    /// The count is unknown: ages are [`UNKNOWN_AGE`] until the link has been quiet long enough.
    Resync {
        /// When the doubt began.
        began: Instant,
        /// The last command sent or byte received.
        last_activity: Instant,
        /// The zero-torque command of this resynchronisation went out.
        zero_sent: bool,
    },
}

/// What the caller may send now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NextCommand {
    /// The tick's command.
    Force,
    /// Zero torque (the last command before the link goes quiet).
    Zero,
    /// Nothing: the link must stay quiet.
    Nothing,
}

/// Why the count stopped being exact (the last resynchronisation's cause).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Doubt {
    /// Bytes that were not a well-formed frame.
    Malformed,
    /// A reply still missing `lost_after` after its command.
    Overdue,
    /// Every state older than the resynchronising age for `lost_after`.
    OverAge,
    /// More commands unanswered than the ring holds.
    Full,
}

/// The unanswered commands of one link (module docs). Cleared on every open.
#[derive(Debug, Clone)]
pub struct InFlight {
    /// When each unanswered command went out, oldest first, as a ring.
    sent_at: [Option<Instant>; IN_FLIGHT_CAPACITY],
    head: usize,
    len: usize,
    /// A reply not waiting this long after its command may never come; also how long the link must be quiet
    /// before counting starts again.
    lost_after: Duration,
    /// States older than this (ticks) for `lost_after` in a row start a resynchronisation.
    resync_age: u32,
    /// A reply that answered nothing was dropped since the last state.
    out_of_step: bool,
    tally: Tally,
    /// Resynchronisations since the last clear, and the last one's cause.
    resyncs: u64,
    last_doubt: Option<Doubt>,
}

impl InFlight {
    /// No command unanswered, counting; a reply not waiting `lost_after` after its command, or states older
    /// than `resync_age` ticks for `lost_after`, start a resynchronisation.
    pub fn new(lost_after: Duration, resync_age: u32) -> Self {
        InFlight {
            sent_at: [None; IN_FLIGHT_CAPACITY],
            head: 0,
            len: 0,
            lost_after,
            resync_age,
            out_of_step: false,
            tally: Tally::Counting {
                over_age_since: None,
            },
            resyncs: 0,
            last_doubt: None,
        }
    }

    /// Forgets every command (the link was opened again, its queues purged and found quiet).
    pub fn clear(&mut self) {
        *self = InFlight::new(self.lost_after, self.resync_age);
    }

    /// Whether the count is exact now.
    pub fn tally(&self) -> Tally {
        self.tally
    }

    /// True while resynchronising.
    pub fn resyncing(&self) -> bool {
        matches!(self.tally, Tally::Resync { .. })
    }

    /// Resynchronisations since the last clear.
    pub fn resyncs(&self) -> u64 {
        self.resyncs
    }

    /// Why the last resynchronisation began.
    pub fn last_doubt(&self) -> Option<Doubt> {
        self.last_doubt
    }

    /// What may go out now.
    pub fn next_command(&self) -> NextCommand {
        match self.tally {
            Tally::Counting { .. } => NextCommand::Force,
            Tally::Resync {
                zero_sent: false, ..
            } => NextCommand::Zero,
            Tally::Resync { .. } => NextCommand::Nothing,
        }
    }

    /// A command went out at `at`.
    pub fn command_sent(&mut self, at: Instant) {
        match &mut self.tally {
            Tally::Resync {
                last_activity,
                zero_sent,
                ..
            } => {
                *last_activity = (*last_activity).max(at);
                *zero_sent = true;
            }
            Tally::Counting { .. } => {
                if self.len == IN_FLIGHT_CAPACITY {
                    // The count is past belief: resynchronise (the next command is the zero one).
                    self.doubt(Doubt::Full, at);
                    return;
                }
                let slot = (self.head + self.len) % IN_FLIGHT_CAPACITY;
                self.sent_at[slot] = Some(at);
                self.len += 1;
            }
        }
    }

    /// Bytes came at `at` (whatever they were): while resynchronising, the link is not quiet.
    pub fn bytes_came(&mut self, at: Instant) {
        if let Tally::Resync { last_activity, .. } = &mut self.tally {
            *last_activity = (*last_activity).max(at);
        }
    }

    /// Bytes that were not a well-formed frame came at `at`: a garbled reply or junk, which cannot be told
    /// apart, so the count is no longer known.
    pub fn malformed(&mut self, at: Instant) {
        self.doubt(Doubt::Malformed, at);
    }

    /// A well-formed reply was read: counting, it answers the oldest unanswered command (true), or none
    /// (false: a reply nobody asked for, and the next state is reported a tick older); resynchronising, it is
    /// placed nowhere (true: its age is unknown, not surplus).
    pub fn reply_read(&mut self) -> bool {
        if self.resyncing() {
            return true;
        }
        if self.pop_oldest().is_some() {
            true
        } else {
            self.out_of_step = true;
            false
        }
    }

    /// The port held no byte when it was polled at `at`. Counting: a command sent more than `lost_after`
    /// before `at` still unanswered starts a resynchronisation. Resynchronising: if nothing was sent or
    /// received for more than `lost_after` before `at`, every reply owed has come or never will: counting
    /// starts again from zero, and this returns true (the caller drops any partial frame it holds).
    pub fn nothing_waiting(&mut self, at: Instant) -> bool {
        match self.tally {
            Tally::Counting { .. } => {
                if self
                    .oldest()
                    .is_some_and(|sent| at.saturating_duration_since(sent) > self.lost_after)
                {
                    self.doubt(Doubt::Overdue, at);
                }
                false
            }
            Tally::Resync { last_activity, .. } => {
                if at.saturating_duration_since(last_activity) > self.lost_after {
                    self.forget_commands();
                    self.tally = Tally::Counting {
                        over_age_since: None,
                    };
                    true
                } else {
                    false
                }
            }
        }
    }

    /// The age (ticks) of the newest reply read, handed out at `at`: counting, the commands sent after the one
    /// it answers, plus one after a reply that answered nothing (and the out-of-step count starts over);
    /// resynchronising, [`UNKNOWN_AGE`]. A count that stays above the resynchronising age for `lost_after`
    /// starts a resynchronisation (lost replies may be inflating it, and only a quiet link tells).
    pub fn state_age(&mut self, at: Instant) -> u32 {
        let Tally::Counting { over_age_since } = self.tally else {
            return UNKNOWN_AGE;
        };
        let age = u32::try_from(self.len)
            .unwrap_or(u32::MAX)
            .saturating_add(u32::from(self.out_of_step));
        self.out_of_step = false;
        if age <= self.resync_age {
            self.tally = Tally::Counting {
                over_age_since: None,
            };
            return age;
        }
        match over_age_since {
            Some(since) if at.saturating_duration_since(since) > self.lost_after => {
                self.doubt(Doubt::OverAge, at);
                UNKNOWN_AGE
            }
            Some(_) => age,
            None => {
                self.tally = Tally::Counting {
                    over_age_since: Some(at),
                };
                age
            }
        }
    }

    /// When the current resynchronisation began (`None` while counting).
    pub fn resync_began(&self) -> Option<Instant> {
        match self.tally {
            Tally::Resync { began, .. } => Some(began),
            Tally::Counting { .. } => None,
        }
    }

    /// Commands unanswered (counting; none while resynchronising).
    pub fn unanswered(&self) -> usize {
        self.len
    }

    /// Enters (or extends) a resynchronisation at `at`: the count is dropped, and the link must be quiet from
    /// the later of `at` and the newest command.
    fn doubt(&mut self, why: Doubt, at: Instant) {
        match &mut self.tally {
            Tally::Resync { last_activity, .. } => *last_activity = (*last_activity).max(at),
            Tally::Counting { .. } => {
                let newest = self.newest().map_or(at, |sent| sent.max(at));
                self.forget_commands();
                self.resyncs += 1;
                self.last_doubt = Some(why);
                self.tally = Tally::Resync {
                    began: at,
                    last_activity: newest,
                    zero_sent: false,
                };
            }
        }
    }

    fn forget_commands(&mut self) {
        self.sent_at = [None; IN_FLIGHT_CAPACITY];
        self.head = 0;
        self.len = 0;
        self.out_of_step = false;
    }

    fn oldest(&self) -> Option<Instant> {
        if self.len == 0 {
            None
        } else {
            self.sent_at[self.head]
        }
    }

    fn newest(&self) -> Option<Instant> {
        if self.len == 0 {
            None
        } else {
            self.sent_at[(self.head + self.len - 1) % IN_FLIGHT_CAPACITY]
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
    use super::{Doubt, InFlight, NextCommand, IN_FLIGHT_CAPACITY, UNKNOWN_AGE};
    use std::time::{Duration, Instant};

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// 50 ms and 3 ticks (the Falcon driver's figures), and the instant the test's clock starts at.
    fn flight() -> (Instant, InFlight) {
        (Instant::now(), InFlight::new(ms(50), 3))
    }

    /// One reply per command, in order, each coming 1-2 ms after it at 1 kHz (libnifalcon's link: the FTDI
    /// latency timer of 1 ms, FalconCommLibUSB.cpp:560, then a 1 ms USB frame): worked out by hand, the reply
    /// read in tick n answers command n-1 and is one tick old; a reply that came two ticks late is two.
    #[test]
    fn a_reply_read_behind_k_unanswered_commands_is_k_ticks_old() {
        let (t0, mut flight) = flight();
        flight.command_sent(t0);
        // Tick 1: nothing came in tick 0's wait; command 1 goes out, then reply 0 arrives.
        assert!(!flight.nothing_waiting(t0));
        flight.command_sent(t0 + ms(1));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(1)), 1);
        // Tick 2: command 2, reply 1.
        flight.command_sent(t0 + ms(2));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(2)), 1);
        // Tick 3: reply 2 is late; command 3 and 4 go out before it comes.
        flight.command_sent(t0 + ms(3));
        flight.command_sent(t0 + ms(4));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(4)), 2);
        assert_eq!(flight.unanswered(), 2);
        assert_eq!(flight.resyncs(), 0);
    }

    /// Bytes that are not a frame may be junk (no reply) or a garbled reply: nothing is written off. Every
    /// age is unknown, one zero command goes out and then none, until 50 ms passed with no byte and no
    /// command; then counting starts from zero, and the first reply after is exact.
    #[test]
    fn malformed_bytes_make_every_age_unknown_until_the_link_was_quiet() {
        let (t0, mut flight) = flight();
        flight.command_sent(t0);
        flight.command_sent(t0 + ms(1));
        flight.malformed(t0 + ms(1));
        assert_eq!(flight.last_doubt(), Some(Doubt::Malformed));
        assert_eq!(flight.next_command(), NextCommand::Zero);
        flight.command_sent(t0 + ms(2));
        assert_eq!(flight.next_command(), NextCommand::Nothing);
        // The replies still owed come, and say nothing of their age.
        flight.bytes_came(t0 + ms(4));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(4)), UNKNOWN_AGE);
        // Quiet since 4 ms: not at 54 ms (exactly 50), at 55 ms yes.
        assert!(!flight.nothing_waiting(t0 + ms(54)));
        assert_eq!(flight.state_age(t0 + ms(54)), UNKNOWN_AGE);
        assert!(flight.nothing_waiting(t0 + ms(55)));
        assert_eq!(flight.next_command(), NextCommand::Force);
        assert_eq!(flight.unanswered(), 0);
        flight.command_sent(t0 + ms(56));
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(57)), 0);
        assert_eq!(flight.resyncs(), 1);
    }

    /// A reply still missing 50 ms after its command may be lost or late: the count resynchronises rather than
    /// write it off (a late reply taken for the next command's would look a tick younger than it is).
    #[test]
    fn an_overdue_reply_resynchronises_rather_than_being_written_off() {
        let (t0, mut flight) = flight();
        flight.command_sent(t0);
        assert!(!flight.nothing_waiting(t0 + ms(50)));
        assert!(!flight.resyncing());
        assert!(!flight.nothing_waiting(t0 + ms(51)));
        assert_eq!(flight.last_doubt(), Some(Doubt::Overdue));
        assert_eq!(flight.next_command(), NextCommand::Zero);
        // The late reply comes after all: placed nowhere, age unknown.
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0 + ms(60)), UNKNOWN_AGE);
    }

    /// Lost replies make every later state look older than it is, for as long as the stream runs: with ages
    /// above the bound (3) for 50 ms the count resynchronises, so the force comes back after a quiet link.
    #[test]
    fn ages_above_the_bound_for_50_ms_resynchronise() {
        let (t0, mut flight) = flight();
        for k in 0..4 {
            flight.command_sent(t0 + ms(k));
        }
        // Replies 0-2 lost; from here each tick one reply and one command: the count says 4 each time.
        for k in 4..=55u64 {
            flight.command_sent(t0 + ms(k));
            assert!(flight.reply_read());
            let age = flight.state_age(t0 + ms(k));
            if k <= 54 {
                assert_eq!(age, 4, "tick {k}");
            } else {
                assert_eq!(age, UNKNOWN_AGE, "tick {k}");
            }
        }
        assert_eq!(flight.last_doubt(), Some(Doubt::OverAge));
    }

    /// A reply when nothing is unanswered answers nothing: the next state is one tick older, once.
    #[test]
    fn a_reply_nobody_asked_for_ages_the_next_state_once() {
        let (t0, mut flight) = flight();
        assert!(!flight.reply_read());
        flight.command_sent(t0);
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0), 1);
        flight.command_sent(t0);
        assert!(flight.reply_read());
        assert_eq!(flight.state_age(t0), 0);
    }

    /// A full ring does not grow: the count resynchronises.
    #[test]
    fn a_full_ring_resynchronises() {
        let (t0, mut flight) = flight();
        for _ in 0..=IN_FLIGHT_CAPACITY {
            flight.command_sent(t0);
        }
        assert_eq!(flight.last_doubt(), Some(Doubt::Full));
        assert_eq!(flight.next_command(), NextCommand::Zero);
        flight.clear();
        assert_eq!((flight.unanswered(), flight.resyncs()), (0, 0));
        assert_eq!(flight.next_command(), NextCommand::Force);
    }
}
