//! The servo loop's schedule with no work in it: the baseline `voxhap bench-loop --baseline` runs in windows
//! alternating with the loop's, to tell overruns the machine causes from overruns voxhap causes.
//!
//! A thread takes the same real-time setup as the servo thread ([`super::rt::apply`]: `SCHED_FIFO`, locked
//! memory, the same pinned CPU) and keeps the same [`Schedule`] with the same [`SpinSleepWaiter`] (sleep until
//! `spin_ns` before each deadline, then spin), but its tick does nothing. Whatever lateness and overruns it
//! records come from the kernel and the hypervisor (timer wake-ups, interrupts, the CPU being taken away from
//! the virtual machine), so when the baseline shows the same stalls as the loop, removing them is a matter for
//! the machine (an isolated core, a host without CPU overcommit), not for the tick.

use super::rt::{self, RtMode};
use super::schedule::{Schedule, SpinSleepWaiter, Waiter};
use super::stats::Histogram;
use serde::Serialize;
use std::sync::Arc;
use voxhap_api::RealtimeReport;

/// What one run of the empty schedule counted (its lateness goes into the histogram the caller gives).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct EmptyScheduleRun {
    /// Deadlines waited for.
    pub ticks: u64,
    /// Waits that returned after the next deadline had passed.
    pub overruns: u64,
    /// Deadlines skipped by those overruns.
    pub skipped_ticks: u64,
    /// What the thread was granted of the servo thread's real-time setup.
    pub realtime: RealtimeReport,
}

/// Errors of [`run_empty_schedule`].
#[derive(Debug, thiserror::Error)]
pub enum BaselineError {
    /// The rate or duration is not a positive finite number.
    #[error("baseline: {what} must be a positive finite number, got {value}")]
    NotPositive {
        /// Which argument.
        what: &'static str,
        /// Its value.
        value: f64,
    },
    /// `RtMode::Strict` and the OS refused part of the real-time setup.
    #[error("baseline: {0}")]
    Realtime(#[from] rt::RtRefused),
    /// The thread could not be started.
    #[error("baseline: could not start its thread: {0}")]
    Thread(std::io::Error),
    /// The thread panicked.
    #[error("baseline: its thread panicked")]
    Panicked,
}

/// Runs the empty schedule for `seconds` at `rate_hz` on its own thread, with the real-time setup `mode` on
/// `cpu` (as the servo thread would get it), spinning the last `spin_ns` before each deadline (capped as the
/// servo thread caps it), and records each wait's lateness into `lateness` (windows of one comparison pool
/// into one histogram); blocks until done.
pub fn run_empty_schedule(
    rate_hz: f64,
    spin_ns: u64,
    mode: RtMode,
    cpu: Option<usize>,
    seconds: f64,
    lateness: Arc<Histogram>,
) -> Result<EmptyScheduleRun, BaselineError> {
    for (what, value) in [("the rate", rate_hz), ("the duration", seconds)] {
        if !(value.is_finite() && value > 0.0) {
            return Err(BaselineError::NotPositive { what, value });
        }
    }
    let period_ns = ((1e9 / rate_hz).round() as u64).max(1);
    // The servo thread's cap on spinning (a quarter of the period, under Linux's real-time limit).
    let spin_ns = super::session::capped_busy_wait_ns(spin_ns, period_ns);
    let duration_ns = (seconds * 1e9).min(u64::MAX as f64 / 2.0) as u64;
    let thread = std::thread::Builder::new()
        .name("voxhap-baseline".to_owned())
        .spawn(move || -> Result<EmptyScheduleRun, BaselineError> {
            let (granted, _warnings) = rt::apply(mode, cpu)?;
            let mut waiter = SpinSleepWaiter::new(spin_ns);
            let start_ns = waiter.now_ns();
            let end_ns = start_ns.saturating_add(duration_ns);
            let mut schedule = Schedule::new(start_ns.saturating_add(period_ns), period_ns);
            let (mut ticks, mut overruns, mut skipped_ticks) = (0u64, 0u64, 0u64);
            while schedule.next_deadline_ns() <= end_ns {
                let deadline_ns = schedule.next_deadline_ns();
                waiter.wait_until(deadline_ns);
                let now_ns = waiter.now_ns();
                lateness.record(now_ns.saturating_sub(deadline_ns));
                ticks += 1;
                let advance = schedule.advance(now_ns);
                if advance.overrun {
                    overruns += 1;
                    skipped_ticks += advance.skipped;
                }
            }
            Ok(EmptyScheduleRun {
                ticks,
                overruns,
                skipped_ticks,
                realtime: granted,
            })
        })
        .map_err(BaselineError::Thread)?;
    thread.join().map_err(|_| BaselineError::Panicked)?
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_empty_schedule_waits_for_every_deadline_it_does_not_skip() {
        let lateness = Arc::new(Histogram::new());
        let report =
            run_empty_schedule(1000.0, 50_000, RtMode::Off, None, 0.2, lateness.clone()).unwrap();
        // 200 deadlines in 0.2 s: none after the end is waited for, and each one before it was either waited
        // for or skipped by an overrun (a last overrun may also skip deadlines after the end).
        assert!(report.ticks <= 200, "{report:?}");
        assert!(report.ticks + report.skipped_ticks >= 200, "{report:?}");
        assert_eq!(lateness.count(), report.ticks);
        assert!(report.overruns <= report.skipped_ticks);
        assert!(!report.realtime.sched_fifo, "RtMode::Off asks for nothing");
        // A second window adds to the same histogram.
        let second =
            run_empty_schedule(1000.0, 50_000, RtMode::Off, None, 0.05, lateness.clone()).unwrap();
        assert_eq!(lateness.count(), report.ticks + second.ticks);
    }

    #[test]
    fn a_rate_or_duration_that_is_not_positive_is_refused_by_name() {
        for (rate, seconds, named) in [
            (0.0, 1.0, "the rate"),
            (f64::NAN, 1.0, "the rate"),
            (1000.0, -1.0, "the duration"),
            (1000.0, f64::INFINITY, "the duration"),
        ] {
            let histogram = Arc::new(Histogram::new());
            let error =
                run_empty_schedule(rate, 0, RtMode::Off, None, seconds, histogram).unwrap_err();
            assert!(error.to_string().contains(named), "{error}");
        }
    }
}
