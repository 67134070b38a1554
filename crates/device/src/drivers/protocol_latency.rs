//! The protocol driver's link latency, measured on the link at open (protocol/SPEC.md section 7: each State
//! echoes the last SetForce the device received, "and the echo gives the round-trip time").
//!
//! **A round trip** is the time from just before the host writes a SetForce to the moment it has decoded the
//! first State echoing that SetForce's sequence. It holds everything between a force leaving the host and the
//! state that answers it being readable there: both frames' time on the wire at whatever rate the port really
//! runs (so the port's nominal baud is not added on top: a UART's wire time is inside the measurement, and a
//! USB CDC port ignores the baud), the device's wait for its next control cycle and its reply, and the host's
//! own wake-up. In lockstep the state the servo uses at tick `n` answers the force sent at tick `m`, with
//! `(n - m) T` at most the round trip (the host uses a State at the first tick that finds it), so a round trip
//! in whole ticks, rounded up, is never less than the number of ticks the observer must pair a force and the
//! motion it meets with (crate `voxhap-servo`, `passivity::controller`, "Latency").
//!
//! **The declared figure** ([`declared`]): `worst`, the 95th percentile of the round trips by nearest rank
//! (the `ceil(0.95 N)`-th smallest of `N`; for fewer than 20 that is the largest), rounded up to the next
//! 0.1 ms; `typical`, the median. A probe whose State never comes (a lost frame) gives no sample; a State
//! that comes after a later probe was sent still gives its own probe's round trip, from that probe's send.
//!
//! Nothing here allocates; [`RoundTrips`] is fixed-size and fed only while open runs.

use crate::latency::LinkLatency;
use std::time::{Duration, Instant};

/// The most round trips kept (the first State's, its resends' and the probes').
pub const CAPACITY: usize = 288;

/// Sends remembered, so a State that comes after later probes still finds its own send time.
const SENDS: usize = 16;

/// `worst` is rounded up to a multiple of this.
pub const ROUNDING: Duration = Duration::from_micros(100);

/// The percentile declared as `worst`.
pub const WORST_PERCENT: usize = 95;

/// [`LinkLatency::source`] of a measured figure.
pub const MEASURED: &str =
    "measured by the driver at open: the 95th percentile of the round trips from a zero \
     force to the State echoing it, rounded up to 0.1 ms";

/// The round trips of one open (module docs).
#[derive(Debug, Clone)]
pub struct RoundTrips {
    sends: [Option<(u32, Instant)>; SENDS],
    samples: [Duration; CAPACITY],
    len: usize,
}

impl Default for RoundTrips {
    fn default() -> Self {
        RoundTrips {
            sends: [None; SENDS],
            samples: [Duration::ZERO; CAPACITY],
            len: 0,
        }
    }
}

impl RoundTrips {
    /// Forgets every send and sample (a new open).
    pub fn clear(&mut self) {
        self.sends = [None; SENDS];
        self.len = 0;
    }

    /// The SetForce numbered `sequence` is about to be written.
    pub fn sent(&mut self, sequence: u32, at: Instant) {
        self.sends[sequence as usize % SENDS] = Some((sequence, at));
    }

    /// A State echoing `echo` was decoded at `at`: the round trip of that send, once (a later State echoing
    /// the same SetForce is not a new answer). Nothing for a send not remembered.
    pub fn answered(&mut self, echo: u32, at: Instant) {
        let slot = &mut self.sends[echo as usize % SENDS];
        let Some((sequence, sent_at)) = *slot else {
            return;
        };
        if sequence != echo {
            return;
        }
        *slot = None;
        if self.len < CAPACITY {
            self.samples[self.len] = at.saturating_duration_since(sent_at);
            self.len += 1;
        }
    }

    /// The round trips so far, in the order they came.
    pub fn samples(&self) -> &[Duration] {
        &self.samples[..self.len]
    }

    /// The declared figure from the round trips so far ([`declared`]).
    pub fn latency(&self) -> Option<LinkLatency> {
        declared(self.samples())
    }
}

/// The link latency declared from `round_trips` (module docs): `None` without any. At most [`CAPACITY`] are
/// read.
pub fn declared(round_trips: &[Duration]) -> Option<LinkLatency> {
    let n = round_trips.len().min(CAPACITY);
    if n == 0 {
        return None;
    }
    let mut sorted = [Duration::ZERO; CAPACITY];
    sorted[..n].copy_from_slice(&round_trips[..n]);
    let sorted = &mut sorted[..n];
    sorted.sort_unstable();
    // Nearest rank: the ceil(p N / 100)-th smallest.
    let rank = |percent: usize| sorted[(percent * n).div_ceil(100).max(1) - 1];
    Some(LinkLatency {
        typical: rank(50),
        worst: round_up(rank(WORST_PERCENT), ROUNDING),
        source: MEASURED,
        round_trips: u32::try_from(n).unwrap_or(u32::MAX),
    })
}

/// `value` rounded up to a multiple of `step` (a zero step leaves it).
fn round_up(value: Duration, step: Duration) -> Duration {
    let step_ns = step.as_nanos();
    if step_ns == 0 {
        return value;
    }
    let ns = value.as_nanos().div_ceil(step_ns) * step_ns;
    Duration::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    const US: Duration = Duration::from_micros(1);

    /// By hand: 64 round trips of 1 000, 1 010, ..., 1 630 µs. The 95th percentile by nearest rank is the
    /// ceil(60.8) = 61st smallest, 1 600 µs (already a multiple of 0.1 ms); the median the 32nd, 1 310 µs.
    #[test]
    fn the_95th_percentile_rounded_up_and_the_median() {
        let mut trips: Vec<Duration> = (0..64).map(|i| US * (1_000 + 10 * i)).collect();
        let latency = declared(&trips).unwrap();
        assert_eq!(latency.worst, US * 1_600);
        assert_eq!(latency.typical, US * 1_310);
        assert_eq!(latency.round_trips, 64);
        assert_eq!(latency.source, MEASURED);
        // Order does not matter, and a stall in place of the largest does not move the figure (it is one of
        // the three above the 61st).
        trips.reverse();
        trips[0] = Duration::from_millis(40);
        assert_eq!(declared(&trips).unwrap().worst, US * 1_600);
        // 20 round trips: ceil(19) = 19th, so one stall among 20 is left out; 1 001 µs is rounded up.
        let mut twenty = vec![US * 1_001; 19];
        twenty.push(Duration::from_millis(5));
        assert_eq!(declared(&twenty).unwrap().worst, US * 1_100);
    }

    /// Fewer than 20: ceil(0.95 N) = N, the largest; one round trip is its own figure, rounded up.
    #[test]
    fn a_few_round_trips_declare_the_largest() {
        let trips = [US * 900, US * 1_234, US * 1_000];
        assert_eq!(declared(&trips).unwrap().worst, US * 1_300);
        assert_eq!(declared(&trips).unwrap().typical, US * 1_000);
        assert_eq!(declared(&[US * 250]).unwrap().worst, US * 300);
        assert_eq!(declared(&[]), None);
    }

    /// Each send's own time: a State echoing an earlier probe after a later one was sent, a second State
    /// echoing the same force (not an answer again), an echo of a send not made.
    #[test]
    fn round_trips_pair_each_echo_with_its_own_send() {
        let t0 = Instant::now();
        let mut trips = RoundTrips::default();
        trips.sent(1, t0);
        trips.sent(2, t0 + US * 100);
        trips.answered(1, t0 + US * 1_500);
        trips.answered(1, t0 + US * 1_600);
        trips.answered(2, t0 + US * 1_700);
        trips.answered(9, t0 + US * 1_800);
        assert_eq!(trips.samples(), [US * 1_500, US * 1_600]);
        trips.clear();
        assert!(trips.samples().is_empty());
        assert_eq!(trips.latency(), None);
    }
}
