//! The servo loop's timing: absolute deadlines, waiting for them, and skipping (never bursting) after an
//! overrun.
//!
//! Tick `n` is due at `origin + n * period`. The loop waits for the deadline, runs the tick, and moves on to
//! the next deadline. If the tick (or a scheduling hiccup) finished after the *next* deadline had already
//! passed, the schedule does not run the missed ticks back to back to catch up (that would hit the device
//! with a burst of stale updates); it counts an overrun, skips to the first deadline still in the future,
//! and the tick numbers jump by the ticks skipped. Deadlines stay on the original grid, so there is no
//! drift.
//!
//! Waiting ([`Waiter`]): the real waiter ([`SpinSleepWaiter`]) sleeps with `clock_nanosleep(CLOCK_MONOTONIC,
//! TIMER_ABSTIME)` until `spin_ns` before the deadline (absolute, so a late wake-up does not shift later
//! deadlines), then spins reading the clock until the deadline. Tests use [`MockWaiter`], which jumps a
//! [`MockClock`] to the deadline plus a scripted lateness, so they run faster than real time and
//! deterministically.

use std::sync::Arc;
use voxhap_device::supervisor::TickClock;
use voxhap_solver::clock::{Clock, MockClock};

/// Waits for absolute deadlines on some clock.
pub trait Waiter: Send {
    /// Now (ns, on the waiter's clock).
    fn now_ns(&self) -> u64;
    /// Returns at or after `deadline_ns`.
    fn wait_until(&mut self, deadline_ns: u64);
    /// The clock behind the waiter, for the solver's time budget.
    fn clock(&self) -> &dyn Clock;
    /// What kind of clock it is, for the supervisor's timing of the readings a tick brings.
    fn tick_clock(&self) -> TickClock;
}

/// `CLOCK_MONOTONIC` in nanoseconds (the clock `clock_nanosleep` sleeps on).
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicRawClock;

impl Clock for MonotonicRawClock {
    fn now_ns(&self) -> u64 {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always supported on Linux.
        unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
        (ts.tv_sec as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(ts.tv_nsec as u64)
    }
}

/// Sleep on an absolute deadline, then spin the last `spin_ns`.
#[derive(Debug, Clone, Copy)]
pub struct SpinSleepWaiter {
    clock: MonotonicRawClock,
    /// How long before the deadline to stop sleeping and start spinning (ns).
    pub spin_ns: u64,
}

impl SpinSleepWaiter {
    /// A waiter that spins the last `spin_ns` before each deadline.
    pub fn new(spin_ns: u64) -> Self {
        SpinSleepWaiter {
            clock: MonotonicRawClock,
            spin_ns,
        }
    }
}

impl Waiter for SpinSleepWaiter {
    fn now_ns(&self) -> u64 {
        self.clock.now_ns()
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        let wake_ns = deadline_ns.saturating_sub(self.spin_ns);
        if self.now_ns() < wake_ns {
            let ts = libc::timespec {
                tv_sec: (wake_ns / 1_000_000_000) as libc::time_t,
                tv_nsec: (wake_ns % 1_000_000_000) as libc::c_long,
            };
            // Interrupted sleeps (EINTR) just fall through to the spin, which re-checks the clock.
            // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
            unsafe {
                libc::clock_nanosleep(
                    libc::CLOCK_MONOTONIC,
                    libc::TIMER_ABSTIME,
                    &ts,
                    std::ptr::null_mut(),
                )
            };
        }
        while self.now_ns() < deadline_ns {
            std::hint::spin_loop();
        }
    }

    fn clock(&self) -> &dyn Clock {
        &self.clock
    }

    fn tick_clock(&self) -> TickClock {
        TickClock::Monotonic
    }
}

/// A waiter on a [`MockClock`]: `wait_until` sets the clock to the deadline plus the next scripted lateness
/// (or exactly the deadline when the script is empty, or if the clock is already past it, leaves it).
#[derive(Debug)]
pub struct MockWaiter {
    clock: Arc<MockClock>,
    lateness_ns: std::collections::VecDeque<u64>,
}

impl MockWaiter {
    /// A waiter driving `clock`.
    pub fn new(clock: Arc<MockClock>) -> Self {
        MockWaiter {
            clock,
            lateness_ns: std::collections::VecDeque::new(),
        }
    }

    /// The next waits return this late (ns), one entry per wait.
    pub fn script_lateness(&mut self, lateness_ns: &[u64]) {
        self.lateness_ns.extend(lateness_ns);
    }
}

impl Waiter for MockWaiter {
    fn now_ns(&self) -> u64 {
        self.clock.now_ns()
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        let late = self.lateness_ns.pop_front().unwrap_or(0);
        let target = deadline_ns.saturating_add(late);
        if self.clock.now_ns() < target {
            self.clock.set_ns(target);
        }
    }

    fn clock(&self) -> &dyn Clock {
        &*self.clock
    }

    fn tick_clock(&self) -> TickClock {
        // Advanced only by the waits: it stands still during a tick.
        TickClock::Virtual
    }
}

/// Where the schedule stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schedule {
    origin_ns: u64,
    period_ns: u64,
    /// Index of the tick due next.
    next_tick: u64,
}

/// What [`Schedule::advance`] decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Advance {
    /// True if the next deadline had already passed when the tick finished.
    pub overrun: bool,
    /// Deadlines skipped (0 without an overrun).
    pub skipped: u64,
}

impl Schedule {
    /// Tick 0 due at `origin_ns`, then every `period_ns` (> 0).
    pub fn new(origin_ns: u64, period_ns: u64) -> Self {
        Schedule {
            origin_ns,
            period_ns: period_ns.max(1),
            next_tick: 0,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Index of the tick due next.
    pub fn next_tick(&self) -> u64 {
        self.next_tick
    }

    /// When the next tick is due (ns).
    pub fn next_deadline_ns(&self) -> u64 {
        self.deadline_ns(self.next_tick)
    }

    fn deadline_ns(&self, tick: u64) -> u64 {
        self.origin_ns
            .saturating_add(tick.saturating_mul(self.period_ns))
    }

    /// The tick due now has finished at `now_ns`: move to the next deadline, skipping every deadline that has
    /// already passed.
    pub fn advance(&mut self, now_ns: u64) -> Advance {
        let candidate = self.next_tick + 1;
        if now_ns < self.deadline_ns(candidate) {
            self.next_tick = candidate;
            return Advance::default();
        }
        // First tick whose deadline is still ahead of now.
        let behind = now_ns.saturating_sub(self.origin_ns) / self.period_ns + 1;
        let next = behind.max(candidate + 1);
        let skipped = next - candidate;
        self.next_tick = next;
        Advance {
            overrun: true,
            skipped,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_time_ticks_follow_the_grid() {
        let mut s = Schedule::new(1_000, 1_000_000);
        for n in 0..5 {
            assert_eq!(s.next_deadline_ns(), 1_000 + n * 1_000_000);
            assert_eq!(
                s.advance(s.next_deadline_ns() + 300_000),
                Advance::default()
            );
        }
    }

    #[test]
    fn an_overrun_skips_instead_of_bursting() {
        let mut s = Schedule::new(0, 1_000_000);
        // Tick 0 finishes 3.5 periods late: deadlines 1, 2 and 3 ms have passed; the next is 4 ms.
        let a = s.advance(3_500_000);
        assert_eq!(
            a,
            Advance {
                overrun: true,
                skipped: 3
            }
        );
        assert_eq!(s.next_tick(), 4);
        assert_eq!(s.next_deadline_ns(), 4_000_000);
        // Finishing exactly on the next deadline counts as missing it.
        let a = s.advance(5_000_000);
        assert_eq!((a.overrun, a.skipped, s.next_tick()), (true, 1, 6));
    }

    #[test]
    fn mock_waiter_applies_scripted_lateness() {
        let clock = Arc::new(MockClock::new(0));
        let mut w = MockWaiter::new(clock.clone());
        w.script_lateness(&[5, 0]);
        w.wait_until(100);
        assert_eq!(clock.now_ns(), 105);
        w.wait_until(100);
        assert_eq!(clock.now_ns(), 105, "never moves the clock backwards");
        w.wait_until(200);
        assert_eq!(clock.now_ns(), 200);
    }

    #[test]
    fn real_waiter_never_returns_early() {
        let mut w = SpinSleepWaiter::new(50_000);
        for _ in 0..5 {
            let deadline = w.now_ns() + 200_000;
            w.wait_until(deadline);
            assert!(w.now_ns() >= deadline);
        }
    }
}
