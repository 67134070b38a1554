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
//! **The declared figure** ([`declared`]): `typical`, the median of the round trips by nearest rank; `worst`,
//! their 95th percentile by nearest rank (the `ceil(0.95 N)`-th smallest of `N`; for fewer than 20 that is the
//! largest), but at most the median plus one servo period, rounded up to the next 0.1 ms. A probe whose State
//! never comes (a lost frame) gives no sample; a State that comes after a later probe was sent still gives its
//! own probe's round trip, from that probe's send.
//!
//! **Why the cap at the median plus one period.** The 95th percentile of 64 round trips is their fourth
//! largest, so four slow answers (the host descheduled while open runs, as `serve` starts its other threads)
//! decide it: on a 2-core machine running builds, a link of 1 ms whose median was 1.1 ms in both runs
//! declared 2.9 ms and 6.9 ms. The median is moved only by half the samples (its breakdown point is 50 %, the
//! 95th percentile's 5 %: P. J. Huber, E. M. Ronchetti, *Robust Statistics*, 2nd ed., Wiley 2009, section 1.4,
//! on the breakdown point of quantiles). The figure at open is no longer the only one: from the first servo
//! tick the driver times the round trip of every force it sends ([`LiveRoundTrips`], below), and the observer
//! pairs with their median plus one period, never below the figure at open until as many are timed as open
//! measured (crate `voxhap-servo`, `passivity::link_delay`), so a figure declared too long at open holds only
//! for the connection's first few dozen ticks.
//! So the declared figure is a robust starting point, a tick above the typical round trip, and the live
//! figure follows the delay the run really shows.
//!
//! **The live figure** ([`LiveRoundTrips`]): after open, every SetForce or LocalModel the servo writes is
//! remembered with its send time (the last [`LIVE_SENDS`], so a round trip of up to 255 ticks, the most the
//! observer pairs, still finds its send), and the first State echoing it (`last_force_sequence`, SPEC
//! section 7; in streaming mode, section 10.4, the first streamed State that echoes it) gives its round trip.
//! The round trips are counted in a fixed histogram of 0.1 ms bins ([`LIVE_BINS`] of them; longer ones in the
//! last) and the longest is kept exactly: [`LinkDelaySeen`] gives the median (its bin's upper edge: rounded up
//! to 0.1 ms; in the last bin, which holds every longer round trip too, the longest, so a slow link's median
//! is never said to be shorter than it is) and the longest, in seconds (the servo counts them in ticks of its
//! own period). A round trip
//! here runs from just before the write to the decoding of its answer, so a host that was descheduled in
//! between (a late tick, an overrun) lengthens it: that is the delay the observer's pairing must cover,
//! whatever its cause.
//!
//! Nothing here allocates and nothing locks: both trackers are fixed-size arrays, fed by the thread that owns
//! the driver (open's probes, then the servo thread's ticks).

use crate::latency::{LinkDelaySeen, LinkLatency};
use std::time::{Duration, Instant};

/// The most round trips kept (the first State's, its resends' and the probes').
pub const CAPACITY: usize = 288;

/// Sends remembered while open runs, so a State that comes after later probes still finds its own send time.
const SENDS: usize = 16;

/// Sends remembered while the servo runs: 256, so a State echoing a force sent 255 ticks before (the most the
/// passivity observer pairs) still finds its send time.
pub const LIVE_SENDS: usize = 256;

/// The live histogram's bins: 0.1 ms each ([`ROUNDING`]), 102.4 ms in all; longer round trips count in the
/// last bin (the longest is kept exactly besides).
pub const LIVE_BINS: usize = 1024;

/// `worst` is rounded up to a multiple of this.
pub const ROUNDING: Duration = Duration::from_micros(100);

/// The percentile declared as `worst`.
pub const WORST_PERCENT: usize = 95;

/// [`LinkLatency::source`] of a measured figure.
pub const MEASURED: &str =
    "measured by the driver at open: the 95th percentile of the round trips from a zero \
     force to the State echoing it, at most their median plus one servo period, rounded up to 0.1 ms";

/// Send times by sequence number, the last `N` (`N` a power of two): each answered once.
#[derive(Debug, Clone)]
struct Sends<const N: usize> {
    slots: [Option<(u32, Instant)>; N],
}

impl<const N: usize> Default for Sends<N> {
    fn default() -> Self {
        Sends { slots: [None; N] }
    }
}

impl<const N: usize> Sends<N> {
    fn sent(&mut self, sequence: u32, at: Instant) {
        self.slots[sequence as usize % N] = Some((sequence, at));
    }

    /// The round trip of the send numbered `echo`, answered at `at`; `None` when it was already answered or is
    /// no longer remembered (a later send took its slot).
    fn answered(&mut self, echo: u32, at: Instant) -> Option<Duration> {
        let slot = &mut self.slots[echo as usize % N];
        let (sequence, sent_at) = (*slot)?;
        if sequence != echo {
            return None;
        }
        *slot = None;
        Some(at.saturating_duration_since(sent_at))
    }
}

/// The round trips of one open (module docs).
#[derive(Debug, Clone)]
pub struct RoundTrips {
    sends: Sends<SENDS>,
    samples: [Duration; CAPACITY],
    len: usize,
}

impl Default for RoundTrips {
    fn default() -> Self {
        RoundTrips {
            sends: Sends::default(),
            samples: [Duration::ZERO; CAPACITY],
            len: 0,
        }
    }
}

impl RoundTrips {
    /// Forgets every send and sample (a new open).
    pub fn clear(&mut self) {
        self.sends = Sends::default();
        self.len = 0;
    }

    /// The SetForce numbered `sequence` is about to be written.
    pub fn sent(&mut self, sequence: u32, at: Instant) {
        self.sends.sent(sequence, at);
    }

    /// A State echoing `echo` was decoded at `at`: the round trip of that send, once (a later State echoing
    /// the same SetForce is not a new answer). Nothing for a send not remembered.
    pub fn answered(&mut self, echo: u32, at: Instant) {
        let Some(trip) = self.sends.answered(echo, at) else {
            return;
        };
        if self.len < CAPACITY {
            self.samples[self.len] = trip;
            self.len += 1;
        }
    }

    /// The round trips so far, in the order they came.
    pub fn samples(&self) -> &[Duration] {
        &self.samples[..self.len]
    }

    /// The declared figure from the round trips so far, for servo period `period` ([`declared`]).
    pub fn latency(&self, period: Duration) -> Option<LinkLatency> {
        declared(self.samples(), period)
    }
}

/// The link latency declared from `round_trips` for a servo period `period` (module docs): `None` without
/// any. At most [`CAPACITY`] are read.
pub fn declared(round_trips: &[Duration], period: Duration) -> Option<LinkLatency> {
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
    let typical = rank(50);
    Some(LinkLatency {
        typical,
        worst: round_up(rank(WORST_PERCENT).min(typical + period), ROUNDING),
        source: MEASURED,
        round_trips: u32::try_from(n).unwrap_or(u32::MAX),
    })
}

/// The round trips timed while the servo runs, since the last open (module docs, "The live figure").
#[derive(Debug, Clone)]
pub struct LiveRoundTrips {
    sends: Sends<LIVE_SENDS>,
    bins: [u32; LIVE_BINS],
    count: u64,
    longest: Duration,
}

impl Default for LiveRoundTrips {
    fn default() -> Self {
        LiveRoundTrips {
            sends: Sends::default(),
            bins: [0; LIVE_BINS],
            count: 0,
            longest: Duration::ZERO,
        }
    }
}

impl LiveRoundTrips {
    /// Forgets every send and round trip (a new open).
    pub fn clear(&mut self) {
        *self = LiveRoundTrips::default();
    }

    /// The SetForce or LocalModel numbered `sequence` is about to be written.
    pub fn sent(&mut self, sequence: u32, at: Instant) {
        self.sends.sent(sequence, at);
    }

    /// A State echoing `echo` was decoded at `at`: counts that send's round trip, once.
    pub fn answered(&mut self, echo: u32, at: Instant) {
        let Some(trip) = self.sends.answered(echo, at) else {
            return;
        };
        let bin = usize::try_from(trip.as_nanos().div_ceil(ROUNDING.as_nanos()))
            .unwrap_or(usize::MAX)
            .clamp(1, LIVE_BINS)
            - 1;
        self.bins[bin] = self.bins[bin].saturating_add(1);
        self.count += 1;
        self.longest = self.longest.max(trip);
    }

    /// The round trips counted so far: their median (rounded up to 0.1 ms, at most the longest; the longest
    /// when it is in the last bin) and the longest; `None` before the first.
    pub fn seen(&self) -> Option<LinkDelaySeen> {
        if self.count == 0 {
            return None;
        }
        // Nearest rank: the ceil(N / 2)-th smallest, as the upper edge of its bin; the last bin's is the
        // longest (it holds every longer round trip).
        let rank = self.count.div_ceil(2);
        let mut below = 0u64;
        let mut typical = self.longest;
        for (bin, &count) in self.bins.iter().enumerate() {
            below += u64::from(count);
            if below >= rank {
                if bin + 1 < LIVE_BINS {
                    typical = (ROUNDING * (bin as u32 + 1)).min(self.longest);
                }
                break;
            }
        }
        Some(LinkDelaySeen {
            typical,
            worst: self.longest,
            round_trips: self.count,
        })
    }
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
    const MS: Duration = Duration::from_millis(1);

    /// By hand: 64 round trips of 1 000, 1 010, ..., 1 630 µs. The 95th percentile by nearest rank is the
    /// ceil(60.8) = 61st smallest, 1 600 µs (already a multiple of 0.1 ms); the median the 32nd, 1 310 µs.
    #[test]
    fn the_95th_percentile_rounded_up_and_the_median() {
        let mut trips: Vec<Duration> = (0..64).map(|i| US * (1_000 + 10 * i)).collect();
        let latency = declared(&trips, MS).unwrap();
        assert_eq!(latency.worst, US * 1_600);
        assert_eq!(latency.typical, US * 1_310);
        assert_eq!(latency.round_trips, 64);
        assert_eq!(latency.source, MEASURED);
        // Order does not matter, and a stall in place of the largest does not move the figure (it is one of
        // the three above the 61st).
        trips.reverse();
        trips[0] = Duration::from_millis(40);
        assert_eq!(declared(&trips, MS).unwrap().worst, US * 1_600);
        // 20 round trips: ceil(19) = 19th, so one stall among 20 is left out; 1 001 µs is rounded up.
        let mut twenty = vec![US * 1_001; 19];
        twenty.push(Duration::from_millis(5));
        assert_eq!(declared(&twenty, MS).unwrap().worst, US * 1_100);
    }

    /// Fewer than 20: ceil(0.95 N) = N, the largest; one round trip is its own figure, rounded up.
    #[test]
    fn a_few_round_trips_declare_the_largest() {
        let trips = [US * 900, US * 1_234, US * 1_000];
        assert_eq!(declared(&trips, MS).unwrap().worst, US * 1_300);
        assert_eq!(declared(&trips, MS).unwrap().typical, US * 1_000);
        assert_eq!(declared(&[US * 250], MS).unwrap().worst, US * 300);
        assert_eq!(declared(&[], MS), None);
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
        assert_eq!(trips.latency(MS), None);
    }

    /// By hand, the loaded open of the module docs: 60 round trips of 1.1 ms and 4 of 6.9 ms. The 95th
    /// percentile is the 61st smallest, 6.9 ms; the median the 32nd, 1.1 ms. Declared: at most the median plus
    /// one period, 2.1 ms at 1 kHz and 1.35 ms, rounded up to 1.4 ms, at 4 kHz. A tight tail keeps its 95th
    /// percentile: 60 of 1.1 ms and 4 of 1.3 ms declare 1.3 ms at 1 kHz.
    #[test]
    fn a_slow_tail_at_open_is_capped_at_the_median_plus_one_period() {
        let mut trips = vec![US * 1_100; 60];
        trips.extend([US * 6_900; 4]);
        let at_1khz = declared(&trips, MS).unwrap();
        assert_eq!((at_1khz.typical, at_1khz.worst), (US * 1_100, US * 2_100));
        assert_eq!(declared(&trips, US * 250).unwrap().worst, US * 1_400);
        let mut tight = vec![US * 1_100; 60];
        tight.extend([US * 1_300; 4]);
        assert_eq!(declared(&tight, MS).unwrap().worst, US * 1_300);
    }

    /// A hand-worked run of ten forces, one a millisecond (sequence s sent at (s - 1) ms), answered after
    /// 1.05, 1.1, 1.2, 1.1, 4.3, 1.1, 0.95, 2.0, 1.1 and 1.15 ms; a second State echoing force 2 (a streamed
    /// one) and an echo of a force never sent add nothing. Sorted: 0.95, 1.05, 1.1, 1.1, 1.1, 1.1, 1.15, 1.2,
    /// 2.0, 4.3: the median by nearest rank is the 5th, 1.1 ms; the longest 4.3 ms, 5 ticks at 1 kHz
    /// (ceil 4.3) and 18 at 4 kHz (ceil 17.2); the median 2 ticks at 1 kHz (ceil 1.1).
    #[test]
    fn the_live_round_trips_give_the_median_and_the_longest() {
        let t0 = Instant::now();
        let mut live = LiveRoundTrips::default();
        assert_eq!(live.seen(), None);
        let delays_us = [
            1_050, 1_100, 1_200, 1_100, 4_300, 1_100, 950, 2_000, 1_100, 1_150,
        ];
        for (i, delay) in delays_us.iter().enumerate() {
            let sent = t0 + MS * i as u32;
            live.sent(i as u32 + 1, sent);
            live.answered(i as u32 + 1, sent + US * *delay);
            if i == 1 {
                live.answered(2, sent + US * 1_900);
            }
        }
        live.answered(99, t0 + MS * 20);
        let seen = live.seen().unwrap();
        assert_eq!(seen.round_trips, 10);
        assert_eq!((seen.typical, seen.worst), (US * 1_100, US * 4_300));
        assert_eq!((seen.typical_ticks(MS), seen.worst_ticks(MS)), (2, 5));
        assert_eq!(seen.worst_ticks(US * 250), 18);
        live.clear();
        assert_eq!(live.seen(), None);
    }

    /// A force answered 200 ms late (longer than the histogram) is the longest exactly and counts in the
    /// last bin, whose upper edge is then the longest: the median is 200 ms, not the histogram's 102.4 ms (a
    /// median said shorter than it is would pair the observer short). Three answered 120, 150 and 180 ms late
    /// and two 1 ms late: the median by nearest rank is the 3rd smallest, 120 ms, in the last bin: said as
    /// the longest, 180 ms (rounded up, the safe side). A send 256 sends back is forgotten (the 257th send
    /// took its slot), one 255 back is not.
    #[test]
    fn the_live_figure_keeps_long_round_trips_and_forgets_what_it_cannot_hold() {
        let t0 = Instant::now();
        let mut live = LiveRoundTrips::default();
        live.sent(1, t0);
        live.answered(1, t0 + MS * 200);
        let seen = live.seen().unwrap();
        assert_eq!((seen.worst, seen.typical), (MS * 200, MS * 200));
        assert_eq!(seen.worst_ticks(MS), 200);
        let mut mixed = LiveRoundTrips::default();
        for (sequence, delay) in (1..).zip([MS * 120, MS * 150, MS * 180, MS, MS]) {
            mixed.sent(sequence, t0);
            mixed.answered(sequence, t0 + delay);
        }
        let seen = mixed.seen().unwrap();
        assert_eq!((seen.typical, seen.worst), (MS * 180, MS * 180));
        for sequence in 2..=258 {
            live.sent(sequence, t0 + MS * sequence);
        }
        live.answered(2, t0 + MS * 300);
        live.answered(3, t0 + MS * 300);
        let seen = live.seen().unwrap();
        assert_eq!(
            seen.round_trips, 2,
            "force 3 (255 sends back) is answered, force 2 is not"
        );
        assert_eq!(seen.worst, MS * 297);
    }
}
