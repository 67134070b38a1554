//! The receive core of a device that streams input reports faster than the host reads them (WoodenHaptics 1.5's
//! legacy HID firmware sends one whenever its endpoint is polled, mbed-code/main.cpp of
//! WoodenHaptics/woody-experimental): reports in, the newest out, with how old it may be. The runner
//! ([`super::exchange::newest_report_within`]) reads the queue into it; the core keeps the newest report,
//! counts the older ones it skipped, and ages the state ([`ReplyAge`]): a report read in the tick after a
//! command is 0 ticks old, one read after `k` ticks whose waits brought none is `k`, since it may have been
//! sent just after the last report read (reports carry a counter, no time). No I/O, no clock, no allocation.

use super::reply_age::ReplyAge;

/// The longest report kept (a full-speed HID report).
pub const REPORT_CAPACITY: usize = 64;

/// The newest report of one tick's read, and the bookkeeping across ticks (module docs).
#[derive(Debug, Clone)]
pub struct NewestReport {
    newest: [u8; REPORT_CAPACITY],
    len: usize,
    /// A report came in this tick's read.
    fresh: bool,
    /// Older reports skipped to reach the newest, since the start.
    skipped: u64,
    age: ReplyAge,
}

impl Default for NewestReport {
    fn default() -> Self {
        NewestReport {
            newest: [0; REPORT_CAPACITY],
            len: 0,
            fresh: false,
            skipped: 0,
            age: ReplyAge::default(),
        }
    }
}

impl NewestReport {
    /// A command went out (a tick began).
    pub fn command_sent(&mut self) {
        self.age.command_sent();
    }

    /// A tick's read begins: no report yet.
    pub fn begin(&mut self) {
        self.fresh = false;
    }

    /// A report came (longer than [`REPORT_CAPACITY`] is kept to that length, which a decoder refuses by its
    /// length anyway); an earlier one of this read is skipped.
    pub fn report(&mut self, bytes: &[u8]) {
        if self.fresh {
            self.skipped += 1;
        }
        self.len = bytes.len().min(REPORT_CAPACITY);
        self.newest[..self.len].copy_from_slice(&bytes[..self.len]);
        self.fresh = true;
    }

    /// The newest report of this read, if one came, and its age: the state is handed out.
    pub fn take(&mut self) -> Option<(&[u8], u32)> {
        if !std::mem::take(&mut self.fresh) {
            return None;
        }
        let age = self.age.reply_read();
        Some((&self.newest[..self.len], age))
    }

    /// The age of the last report handed out.
    pub fn age(&self) -> u32 {
        self.age.age()
    }

    /// Older reports skipped to reach the newest, since the start.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }
}

#[cfg(test)]
mod tests {
    use super::NewestReport;

    /// Worked by hand: three reports in one read give the third, two skipped, 0 ticks old; a read with none
    /// gives nothing; after two ticks without a report the next is two ticks old.
    #[test]
    fn the_newest_report_is_kept_and_aged_by_the_ticks_without_one() {
        let mut core = NewestReport::default();
        core.command_sent();
        core.begin();
        for n in 1..=3u8 {
            core.report(&[n; 8]);
        }
        assert_eq!(core.take(), Some((&[3u8; 8][..], 0)));
        assert_eq!(core.skipped(), 2);
        assert_eq!(core.take(), None);
        for _ in 0..2 {
            core.command_sent();
            core.begin();
            assert_eq!(core.take(), None);
        }
        core.command_sent();
        core.begin();
        core.report(&[4; 8]);
        assert_eq!(core.take(), Some((&[4u8; 8][..], 2)));
        assert_eq!(core.age(), 2);
    }
}
