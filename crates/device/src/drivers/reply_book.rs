//! What a driver that converts force itself keeps for the host, one type for the serial drivers (Haply 2DIY,
//! WoodenHaptics serial, Novint Falcon) and the WoodenHaptics HID driver: the pose force is converted with and the host's verdict on the newest
//! reading ([`HapticDevice::input_checked`](crate::HapticDevice::input_checked)), the age of the state handed
//! out ([`HapticDevice::state_age_ticks`](crate::HapticDevice::state_age_ticks)), and the messages nobody asked
//! for, counted and reported ([`HapticDevice::take_event`](crate::HapticDevice::take_event)).
//!
//! A driver holds one [`ReplyBook`] in a field `book`; `reply_book_methods!` writes the trait methods the
//! book answers inside the driver's `impl HapticDevice`. Allocation-free and lock-free (called every tick).

use super::reply_age::ReplyAge;
use super::report_stream::NewestReport;
use crate::{DeviceEvent, SurplusCount};

/// Tells how many servo ticks old the state a driver handed out last may be.
pub trait StateAge: Default {
    /// The age (ticks).
    fn ticks(&self) -> u32;
}

/// Drivers whose replies carry no sequence number and answer one command each (Haply 2DIY, WoodenHaptics).
impl StateAge for ReplyAge {
    fn ticks(&self) -> u32 {
        self.age()
    }
}

/// A driver whose device streams reports (WoodenHaptics HID): its receive core keeps the newest report's age.
impl StateAge for NewestReport {
    fn ticks(&self) -> u32 {
        self.age()
    }
}

/// A driver that works the age out itself (the Falcon, from its [`InFlight`](super::in_flight::InFlight))
/// keeps the number.
impl StateAge for u32 {
    fn ticks(&self) -> u32 {
        *self
    }
}

/// The bookkeeping of one driver (module docs), for poses of type `P` (joint angles, a Jacobian, a position)
/// and ages kept by `A`.
#[derive(Debug)]
pub struct ReplyBook<P, A> {
    /// The newest pose the host accepted: the only one force is converted with.
    accepted: Option<P>,
    /// The newest reading's pose, until the host's verdict on it.
    candidate: Option<P>,
    /// The age of the state handed out last.
    pub age: A,
    surplus: SurplusCount,
    event: Option<DeviceEvent>,
}

impl<P: Copy, A: StateAge> ReplyBook<P, A> {
    /// Nothing accepted, read or counted yet.
    pub fn new() -> Self {
        ReplyBook {
            accepted: None,
            candidate: None,
            age: A::default(),
            surplus: SurplusCount::default(),
            event: None,
        }
    }

    /// The driver (re)opens: no pose accepted or pending, the age starts over, surplus counts from here (the
    /// supervisor sums over links). An event not yet taken stays.
    pub fn opened(&mut self) {
        *self = ReplyBook {
            event: self.event.take(),
            ..ReplyBook::new()
        };
    }

    /// A reading begins: the pose pending from the last one is dropped (the host's verdict is on the newest).
    pub fn reading_begins(&mut self) {
        self.candidate = None;
    }

    /// The newest reading's pose, pending the host's verdict.
    pub fn propose(&mut self, pose: P) {
        self.candidate = Some(pose);
    }

    /// The host's verdict on the newest reading: its pose is adopted when `accepted`; otherwise (or with none
    /// pending) the last accepted one stays. True when a pose was adopted.
    pub fn input_checked(&mut self, accepted: bool) -> bool {
        match self.candidate.take() {
            Some(pose) if accepted => {
                self.accepted = Some(pose);
                true
            }
            _ => false,
        }
    }

    /// The pose force is converted with: the newest the host accepted (`None` before the first).
    pub fn accepted(&self) -> Option<P> {
        self.accepted
    }

    /// The accepted pose no longer holds (its coordinates were reset): none until the host accepts another.
    pub fn forget_accepted(&mut self) {
        self.accepted = None;
    }

    /// The age of the state handed out last (ticks).
    pub fn age_ticks(&self) -> u32 {
        self.age.ticks()
    }

    /// Counts `n` messages nobody asked for; a reporting threshold crossed leaves an event to take.
    pub fn count_surplus(&mut self, n: u64) {
        if let Some(event) = self.surplus.add(n) {
            self.event = Some(event);
        }
    }

    /// Surplus messages since the last open.
    pub fn surplus_total(&self) -> u64 {
        self.surplus.total()
    }

    /// The event to report, if any.
    pub fn take_event(&mut self) -> Option<DeviceEvent> {
        self.event.take()
    }
}

impl<P: Copy, A: StateAge> Default for ReplyBook<P, A> {
    fn default() -> Self {
        ReplyBook::new()
    }
}

/// The [`HapticDevice`](crate::HapticDevice) methods a driver's [`ReplyBook`] (in its field `book`) answers,
/// written inside the driver's `impl HapticDevice`: `reply_book_methods!(LATENCY)` writes `input_checked`,
/// `state_age_ticks`, `take_event` and `link_latency` (`Some(LATENCY)`, the driver's
/// [`LinkLatency`](crate::latency::LinkLatency)); `reply_book_methods!(LATENCY, input_checked written by the
/// driver)` all but `input_checked`, for a driver that does more on the verdict.
macro_rules! reply_book_methods {
    ($latency:expr, input_checked written by the driver) => {
        fn state_age_ticks(&self) -> u32 {
            self.book.age_ticks()
        }

        fn link_latency(&self) -> Option<$crate::latency::LinkLatency> {
            Some($latency)
        }

        fn take_event(&mut self) -> Option<$crate::DeviceEvent> {
            self.book.take_event()
        }
    };
    ($latency:expr) => {
        fn input_checked(&mut self, accepted: bool) {
            self.book.input_checked(accepted);
        }

        $crate::drivers::reply_book::reply_book_methods!($latency, input_checked written by the driver);
    };
}

pub(crate) use reply_book_methods;

#[cfg(test)]
mod tests {
    use super::ReplyBook;
    use crate::DeviceEvent;

    /// Worked by hand: a pose is adopted only when the host accepts the reading it came from; a rejected
    /// reading, or a verdict with no reading pending, keeps the last accepted pose.
    #[test]
    fn only_an_accepted_reading_changes_the_pose() {
        let mut book = ReplyBook::<u8, u32>::new();
        book.propose(1);
        assert!(!book.input_checked(false));
        assert_eq!(book.accepted(), None);
        book.propose(2);
        assert!(book.input_checked(true));
        assert_eq!(book.accepted(), Some(2));
        book.propose(3);
        assert!(!book.input_checked(false));
        assert_eq!(book.accepted(), Some(2));
        // A reading that failed proposes nothing: the pose pending before it is not adopted.
        book.propose(4);
        book.reading_begins();
        assert!(!book.input_checked(true));
        assert_eq!(book.accepted(), Some(2));
        book.forget_accepted();
        assert_eq!(book.accepted(), None);
    }

    /// An open starts the pose, the age and the surplus count over and keeps an event not yet taken: 1 surplus
    /// message is reported, 5 more are not (the next report is at 10), and after the open 1 is reported again.
    #[test]
    fn an_open_starts_over_but_keeps_the_pending_event() {
        let mut book = ReplyBook::<u8, u32>::new();
        book.propose(1);
        book.input_checked(true);
        book.age = 7;
        book.count_surplus(1);
        book.opened();
        assert_eq!(
            (book.accepted(), book.age_ticks(), book.surplus_total()),
            (None, 0, 0)
        );
        assert_eq!(book.take_event(), Some(DeviceEvent::Surplus { total: 1 }));
        assert_eq!(book.take_event(), None);
        book.count_surplus(1);
        book.count_surplus(5);
        assert_eq!(book.take_event(), Some(DeviceEvent::Surplus { total: 1 }));
        assert_eq!(book.surplus_total(), 6);
    }
}
