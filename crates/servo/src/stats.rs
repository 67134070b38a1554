//! The servo loop's statistics: lock-free histograms and counters that the servo thread updates every tick
//! and any other thread reads at any time.
//!
//! Where it sits: the servo thread owns an `Arc<ServoStats>` and only does relaxed atomic adds and maxes
//! on it (no allocation, no lock); the server, `voxhap serve`'s exit summary and `voxhap bench-loop` call
//! [`ServoStats::report`].
//!
//! Histogram layout (log-linear, like HdrHistogram with 3 significant bits): values in nanoseconds below
//! 16 ns get a bucket each; above, every power-of-two octave `[2^e, 2^(e+1))` is split into 16 equal
//! sub-buckets, so a bucket's width is at most 1/16 of its lower edge. A percentile is reported as the
//! upper edge of the bucket it falls in, so it over-states the true value by at most 6.25 % (and the
//! maximum is kept exactly). Values up to 2^40 ns (18 minutes) are resolved; larger ones land in the last
//! bucket.

use std::sync::atomic::{AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::sync::Mutex;
use voxhap_api::{HistogramReport, RealtimeReport, SafetyReport, StatsReport};
use voxhap_device::supervisor::OutputState;

const SUB_BUCKETS: usize = 16;
const SUB_BITS: u32 = 4;
const MAX_OCTAVE: usize = 40;
const BUCKETS: usize = SUB_BUCKETS + (MAX_OCTAVE - SUB_BITS as usize) * SUB_BUCKETS;

/// A fixed-size, lock-free histogram of nanosecond values.
#[derive(Debug)]
pub struct Histogram {
    buckets: Box<[AtomicU64]>,
    count: AtomicU64,
    max_ns: AtomicU64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

fn bucket_of(value_ns: u64) -> usize {
    if value_ns < SUB_BUCKETS as u64 {
        return value_ns as usize;
    }
    let octave = 63 - value_ns.leading_zeros(); // >= SUB_BITS
    let sub = ((value_ns >> (octave - SUB_BITS)) & (SUB_BUCKETS as u64 - 1)) as usize;
    let index = SUB_BUCKETS + (octave - SUB_BITS) as usize * SUB_BUCKETS + sub;
    index.min(BUCKETS - 1)
}

/// The largest value that falls in `bucket` (ns).
fn upper_edge(bucket: usize) -> u64 {
    if bucket < SUB_BUCKETS {
        return bucket as u64;
    }
    let octave = (bucket - SUB_BUCKETS) / SUB_BUCKETS + SUB_BITS as usize;
    let sub = ((bucket - SUB_BUCKETS) % SUB_BUCKETS) as u64;
    let width = 1u64 << (octave - SUB_BITS as usize);
    (1u64 << octave) + (sub + 1) * width - 1
}

impl Histogram {
    /// An empty histogram (allocates its buckets once, here).
    pub fn new() -> Self {
        Histogram {
            buckets: (0..BUCKETS).map(|_| AtomicU64::new(0)).collect(),
            count: AtomicU64::new(0),
            max_ns: AtomicU64::new(0),
        }
    }

    /// Records one value. Lock-free, allocation-free.
    pub fn record(&self, value_ns: u64) {
        self.buckets[bucket_of(value_ns)].fetch_add(1, Ordering::Relaxed);
        self.count.fetch_add(1, Ordering::Relaxed);
        self.max_ns.fetch_max(value_ns, Ordering::Relaxed);
    }

    /// Values recorded.
    pub fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    /// The largest value recorded (ns); 0 when empty.
    pub fn max_ns(&self) -> u64 {
        self.max_ns.load(Ordering::Relaxed)
    }

    /// The value at quantile `q` (0..=1), as its bucket's upper edge (ns), capped at the exact maximum;
    /// 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        self.counts()
            .quantile_ns(q)
            .min(self.max_ns.load(Ordering::Relaxed))
    }

    /// A copy of the bucket counts (allocates; not for the servo thread). Two copies taken apart in time
    /// give the histogram of what was recorded in between ([`HistogramCounts::since`]), so a benchmark can
    /// compare windows of one session.
    pub fn counts(&self) -> HistogramCounts {
        HistogramCounts {
            buckets: self
                .buckets
                .iter()
                .map(|b| b.load(Ordering::Relaxed))
                .collect(),
        }
    }

    /// p50, p99, p99.9 and maximum in microseconds.
    pub fn report(&self) -> HistogramReport {
        // One copy of the buckets for all three percentiles.
        self.counts().report(self.max_ns())
    }

    /// Forgets everything recorded.
    pub fn reset(&self) {
        for bucket in self.buckets.iter() {
            bucket.store(0, Ordering::Relaxed);
        }
        self.count.store(0, Ordering::Relaxed);
        self.max_ns.store(0, Ordering::Relaxed);
    }
}

/// Bucket counts copied out of a [`Histogram`]: a window of it ([`since`](Self::since)) or several windows
/// pooled ([`add`](Self::add)). Quantiles are bucket upper edges, as for the histogram; the exact maximum is
/// not kept, so the top quantile of a window is its highest bucket's upper edge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HistogramCounts {
    buckets: Vec<u64>,
}

impl Default for HistogramCounts {
    fn default() -> Self {
        HistogramCounts {
            buckets: vec![0; BUCKETS],
        }
    }
}

/// The upper edges (ns) of [`HistogramCounts::by_decade`]'s first five decades: 1 µs to 10 ms.
pub const DECADE_EDGES_NS: [u64; 5] = [1_000, 10_000, 100_000, 1_000_000, 10_000_000];

/// The column heads of a [`HistogramCounts::by_decade`] row.
pub const DECADE_HEADS: [&str; 6] = ["<=1us", "1-10us", "10-100us", "0.1-1ms", "1-10ms", ">10ms"];

impl HistogramCounts {
    /// What was recorded after `earlier` was taken (counts are only ever added, so this never underflows
    /// for copies of one histogram taken in order; saturates otherwise).
    pub fn since(&self, earlier: &HistogramCounts) -> HistogramCounts {
        HistogramCounts {
            buckets: self
                .buckets
                .iter()
                .zip(&earlier.buckets)
                .map(|(now, before)| now.saturating_sub(*before))
                .collect(),
        }
    }

    /// Pools `other` into `self`.
    pub fn add(&mut self, other: &HistogramCounts) {
        for (mine, theirs) in self.buckets.iter_mut().zip(&other.buckets) {
            *mine += theirs;
        }
    }

    /// Values counted.
    pub fn count(&self) -> u64 {
        self.buckets.iter().sum()
    }

    /// Values above `threshold_ns`, counting a whole bucket when its lower edge lies above the threshold
    /// (so up to one bucket, 1/16 of an octave, of values just above it may be missed).
    pub fn count_above_ns(&self, threshold_ns: u64) -> u64 {
        let first = (bucket_of(threshold_ns) + 1).min(self.buckets.len());
        self.buckets[first..].iter().sum()
    }

    /// p50, p99, p99.9 (capped at `max_ns`) and `max_ns` in microseconds: the exact maximum is not in the
    /// counts, so the caller gives it.
    pub fn report(&self, max_ns: u64) -> HistogramReport {
        let us = |ns: u64| ns as f64 / 1000.0;
        let at = |q: f64| us(self.quantile_ns(q).min(max_ns));
        HistogramReport {
            count: self.count(),
            p50_us: at(0.50),
            p99_us: at(0.99),
            p999_us: at(0.999),
            max_us: us(max_ns),
        }
    }

    /// Counts by decade (the lateness histogram `voxhap bench-loop` prints): values up to 1 µs, then up to
    /// 10 µs, 100 µs, 1 ms, 10 ms, and above 10 ms. A bucket counts in the decade of its upper edge, so a value
    /// up to one bucket (1/16 of an octave, 6.25 %) below a decade's edge may count in the decade above it:
    /// the histogram can overstate lateness, never understate it.
    pub fn by_decade(&self) -> [u64; 6] {
        let mut decades = [0u64; 6];
        for (bucket, &count) in self.buckets.iter().enumerate() {
            let edge = upper_edge(bucket);
            let decade = DECADE_EDGES_NS
                .iter()
                .position(|&limit| edge <= limit)
                .unwrap_or(DECADE_EDGES_NS.len());
            decades[decade] += count;
        }
        decades
    }

    /// The value at quantile `q` (0..=1) as its bucket's upper edge (ns); 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        let total = self.count();
        if total == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * total as f64).ceil() as u64).clamp(1, total);
        let mut seen = 0;
        for (bucket, count) in self.buckets.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return upper_edge(bucket);
            }
        }
        upper_edge(BUCKETS - 1)
    }
}

/// Everything the servo loop counts. Shared (`Arc`) between the servo thread and readers.
#[derive(Debug, Default)]
pub struct ServoStats {
    /// Loop rate, fixed at start (Hz, as f64 bits).
    rate_hz_bits: AtomicU64,
    pub ticks: AtomicU64,
    pub lateness: Histogram,
    pub compute: Histogram,
    pub device: Histogram,
    pub overruns: AtomicU64,
    pub skipped_ticks: AtomicU64,
    pub budget_overruns: AtomicU64,
    pub max_sweeps: AtomicU32,
    /// Worst certificate bound (m) as f64 bits; for non-negative floats (and +inf) the bit order is the
    /// numeric order, so `fetch_max` on the bits is a max on the values.
    worst_bound_bits: AtomicU64,
    pub device_errors: AtomicU64,
    pub disconnects: AtomicU64,
    pub recorder_drops: AtomicU64,
    /// Trace writer errors (set by the recorder thread).
    pub recorder_errors: AtomicU64,
    pub commands_applied: AtomicU64,
    /// Stops by the stall monitor.
    pub monitor_stops: AtomicU64,
    /// Outcome of the last ClearFault command (`runner::CLEAR_FAULT_*`).
    pub clear_fault_outcome: AtomicU8,
    /// The safety side, copied from the device's counters every tick by the servo thread.
    pub safety: SafetyStats,
    /// The energy ledger's totals, stored every tick by the servo thread (crate::energy).
    pub energy: crate::energy::EnergyStats,
    /// The device link's delay and the passivity observer's pairing (crate::passivity::link_stats).
    pub link_delay: crate::passivity::link_stats::LinkDelayStats,
    realtime: Mutex<RealtimeReport>,
}

/// Defines [`SafetyStats`] from the list of its counters, so that a counter is loaded into the
/// [`SafetyReport`] field of the same name as soon as it is declared.
macro_rules! safety_stats {
    ($($counter:ident,)*) => {
        /// The safety counters and state, as atomics the servo thread stores each tick.
        #[derive(Debug, Default)]
        pub struct SafetyStats {
            pub output_state: AtomicU8,
            pub active_faults: AtomicU32,
            $(pub $counter: AtomicU64,)*
        }

        impl SafetyStats {
            /// What was stored last, with the stall monitor's stops (which it counts itself).
            fn report(&self, monitor_stops: u64) -> SafetyReport {
                let output_state = OutputState::from_code(self.output_state.load(Ordering::Relaxed));
                SafetyReport {
                    output_state,
                    output_state_explanation: output_state.explanation(),
                    active_faults: self.active_faults.load(Ordering::Relaxed) as u16,
                    monitor_stops,
                    $($counter: self.$counter.load(Ordering::Relaxed),)*
                }
            }
        }
    };
}

safety_stats! {
    device_faults,
    device_watchdog_trips,
    device_rejections,
    enables,
    not_enabled_ticks,
    stale_ticks,
    positions_rejected,
    velocities_replaced,
    slew_limited_ticks,
    forces_clamped,
    events_dropped,
    device_surplus,
}

impl ServoStats {
    /// Statistics for a loop at `rate_hz`.
    pub fn new(rate_hz: f64) -> Self {
        let stats = ServoStats::default();
        stats
            .rate_hz_bits
            .store(rate_hz.to_bits(), Ordering::Relaxed);
        stats
    }

    /// Notes a tick's certificate bound (m); NaN and negative values are ignored.
    pub fn note_bound(&self, bound_m: f64) {
        if bound_m >= 0.0 {
            self.worst_bound_bits
                .fetch_max(bound_m.to_bits(), Ordering::Relaxed);
        }
    }

    /// Records what real-time features the thread got (once, at start, off the tick path).
    pub fn set_realtime(&self, report: RealtimeReport) {
        if let Ok(mut slot) = self.realtime.lock() {
            *slot = report;
        }
    }

    /// A consistent-enough copy of everything (each field is read atomically on its own).
    pub fn report(&self) -> StatsReport {
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        StatsReport {
            rate_hz: f64::from_bits(load(&self.rate_hz_bits)),
            ticks: load(&self.ticks),
            lateness: self.lateness.report(),
            compute: self.compute.report(),
            device: self.device.report(),
            overruns: load(&self.overruns),
            skipped_ticks: load(&self.skipped_ticks),
            budget_overruns: load(&self.budget_overruns),
            max_sweeps: self.max_sweeps.load(Ordering::Relaxed),
            worst_error_bound_m: f64::from_bits(load(&self.worst_bound_bits)),
            device_errors: load(&self.device_errors),
            disconnects: load(&self.disconnects),
            recorder_drops: load(&self.recorder_drops),
            recorder_errors: load(&self.recorder_errors),
            commands_applied: load(&self.commands_applied),
            realtime: self.realtime.lock().map(|r| *r).unwrap_or_default(),
            safety: self.safety.report(load(&self.monitor_stops)),
            energy: self.energy.load().report(),
            link_delay: self.link_delay.report(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_monotonic_and_tight() {
        let mut previous = 0;
        for value in (0..100_000u64).chain([1 << 20, 1 << 30, (1 << 40) - 1]) {
            let bucket = bucket_of(value);
            assert!(bucket >= previous, "bucket order at {value}");
            previous = bucket;
            let edge = upper_edge(bucket);
            assert!(edge >= value, "upper edge {edge} below value {value}");
            assert!(
                (edge - value) as f64 <= value as f64 / 16.0 + 1.0,
                "bucket of {value} too wide: edge {edge}"
            );
        }
    }

    #[test]
    fn decades_count_each_value_once_in_its_decade() {
        let h = Histogram::new();
        // Values well inside each decade (away from the 6.25 % edge allowance), and their counts: 3 at
        // 0.5 us, 5 at 5 us, 7 at 50 us, 11 at 500 us, 13 at 5 ms, 17 at 50 ms.
        for (value_ns, times) in [
            (500, 3),
            (5_000, 5),
            (50_000, 7),
            (500_000, 11),
            (5_000_000, 13),
            (50_000_000, 17),
        ] {
            for _ in 0..times {
                h.record(value_ns);
            }
        }
        assert_eq!(h.counts().by_decade(), [3, 5, 7, 11, 13, 17]);
        // Near an edge: more than a bucket below it counts below; the edge's own bucket (992 to 1 023 ns)
        // counts above, so 1 000 ns is never reported as at most 1 us; past it counts above.
        let edges = Histogram::new();
        edges.record(900);
        edges.record(1_000);
        edges.record(1_100);
        assert_eq!(edges.counts().by_decade(), [1, 2, 0, 0, 0, 0]);
    }

    #[test]
    fn quantiles_of_a_known_distribution() {
        let h = Histogram::new();
        for value in 1..=1000u64 {
            h.record(value * 1000); // 1 us .. 1 ms
        }
        let p50 = h.quantile_ns(0.5) as f64;
        let p99 = h.quantile_ns(0.99) as f64;
        assert!((500_000.0..=500_000.0 * 1.0625).contains(&p50), "p50 {p50}");
        assert!((990_000.0..=1_000_000.0).contains(&p99), "p99 {p99}");
        assert_eq!(h.report().max_us, 1000.0);
        assert_eq!(h.count(), 1000);
        h.reset();
        assert_eq!(h.quantile_ns(0.5), 0);
    }

    #[test]
    fn windows_of_a_histogram_pool_to_the_whole() {
        let h = Histogram::new();
        let start = h.counts();
        for value in 1..=100u64 {
            h.record(value * 1000); // 1..100 us
        }
        let middle = h.counts();
        for value in 1..=100u64 {
            h.record(value * 100_000); // 0.1..10 ms
        }
        let first = middle.since(&start);
        let second = h.counts().since(&middle);
        assert_eq!((first.count(), second.count()), (100, 100));
        assert!((99_000..=100_000 * 17 / 16).contains(&first.quantile_ns(0.99)));
        assert!((9_900_000..=10_000_000 * 17 / 16).contains(&second.quantile_ns(0.99)));
        assert_eq!(first.count_above_ns(200_000), 0);
        // 0.3 ms .. 10 ms are above 0.2 ms; 0.2 ms itself shares its bucket with the threshold.
        assert_eq!(second.count_above_ns(200_000), 98);
        let mut pooled = first.clone();
        pooled.add(&second);
        assert_eq!(pooled, h.counts().since(&start));
        assert_eq!(pooled.quantile_ns(0.5), h.quantile_ns(0.5));
        assert_eq!(HistogramCounts::default().quantile_ns(0.99), 0);
        // Copies taken out of order saturate instead of wrapping.
        assert_eq!(start.since(&h.counts()).count(), 0);
    }

    #[test]
    fn worst_bound_keeps_the_maximum_including_infinity() {
        let stats = ServoStats::new(1000.0);
        stats.note_bound(1e-12);
        stats.note_bound(3e-9);
        stats.note_bound(1e-10);
        stats.note_bound(f64::NAN);
        assert_eq!(stats.report().worst_error_bound_m, 3e-9);
        stats.note_bound(f64::INFINITY);
        assert_eq!(stats.report().worst_error_bound_m, f64::INFINITY);
    }
}
