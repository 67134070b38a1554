//! Time as an argument (CONTRIBUTING.md item 2): a `Clock` trait, the real monotonic clock and a mock that tests
//! advance by hand. Nothing on the servo path reads the OS clock directly; it is handed a `Clock`.

#[cfg(target_has_atomic = "64")]
use core::sync::atomic::{AtomicU64, Ordering};
#[cfg(feature = "std")]
use std::time::Instant;

/// A monotonic clock reporting nanoseconds since an arbitrary fixed origin.
pub trait Clock {
    fn now_ns(&self) -> u64;
}

/// The OS monotonic clock (`Instant`), counted from the moment this value was made.
#[cfg(feature = "std")]
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin: Instant,
}

#[cfg(feature = "std")]
impl MonotonicClock {
    pub fn new() -> Self {
        Self {
            origin: Instant::now(),
        }
    }
}

#[cfg(feature = "std")]
impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(feature = "std")]
impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }
}

/// A clock that only moves when told to: deterministic sims and tests.
#[cfg(target_has_atomic = "64")]
#[derive(Debug, Default)]
pub struct MockClock {
    now_ns: AtomicU64,
}

#[cfg(target_has_atomic = "64")]
impl MockClock {
    pub fn new(start_ns: u64) -> Self {
        Self {
            now_ns: AtomicU64::new(start_ns),
        }
    }

    pub fn advance_ns(&self, delta_ns: u64) {
        self.now_ns.fetch_add(delta_ns, Ordering::Relaxed);
    }

    pub fn set_ns(&self, now_ns: u64) {
        self.now_ns.store(now_ns, Ordering::Relaxed);
    }
}

#[cfg(target_has_atomic = "64")]
impl Clock for MockClock {
    fn now_ns(&self) -> u64 {
        self.now_ns.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mock_clock_moves_only_when_told() {
        let clock = MockClock::new(5);
        assert_eq!(clock.now_ns(), 5);
        clock.advance_ns(10);
        assert_eq!(clock.now_ns(), 15);
        clock.set_ns(3);
        assert_eq!(clock.now_ns(), 3);
    }

    #[test]
    fn monotonic_clock_does_not_go_back() {
        let clock = MonotonicClock::new();
        let a = clock.now_ns();
        let b = clock.now_ns();
        assert!(b >= a);
    }
}
