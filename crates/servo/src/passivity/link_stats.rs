//! The link delay's statistics ([`LinkDelayStats`]): what the passivity observer's pairing and the round trips
//! the driver timed were, for `/api/stats` and the run summary. Apart from [`super::link_delay`] so that the
//! servo's statistics do not depend on the device side.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use voxhap_api::LinkDelayReport;
use voxhap_device::latency::{LinkDelaySeen, LinkLatency};

/// The link delay's statistics: atomics the servo thread stores each tick (`super::link_delay::LinkFollower::follow`) and any
/// thread reports ([`LinkDelayStats::report`]).
#[derive(Debug)]
pub struct LinkDelayStats {
    observer_ticks: AtomicU64,
    observer_changes: AtomicU64,
    last_change_tick: AtomicU64,
    declared_ns: AtomicU64,
    round_trips: AtomicU64,
    typical_ns: AtomicU64,
    worst_ns: AtomicU64,
    worst_ticks: AtomicU64,
    period_ns: AtomicU64,
}

impl Default for LinkDelayStats {
    fn default() -> Self {
        LinkDelayStats {
            observer_ticks: AtomicU64::new(0),
            observer_changes: AtomicU64::new(0),
            last_change_tick: AtomicU64::new(0),
            declared_ns: AtomicU64::new(0),
            round_trips: AtomicU64::new(0),
            typical_ns: AtomicU64::new(0),
            worst_ns: AtomicU64::new(0),
            worst_ticks: AtomicU64::new(0),
            period_ns: AtomicU64::new(0),
        }
    }
}

fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl LinkDelayStats {
    /// The session's start: the pairing chosen, the driver's figure at open and the servo period.
    pub fn start(&self, ticks: usize, declared: Option<LinkLatency>, period_s: f64) {
        self.observer_ticks.store(ticks as u64, Ordering::Relaxed);
        self.declared(declared);
        self.period_ns
            .store((period_s * 1e9).round() as u64, Ordering::Relaxed);
    }

    pub(super) fn declared(&self, declared: Option<LinkLatency>) {
        let ns = declared.map_or(0, |l| nanos(l.worst));
        self.declared_ns.store(ns, Ordering::Relaxed);
    }

    /// The observer's pairing changed to `ticks` at `tick`.
    pub(super) fn changed(&self, tick: u64, ticks: usize) {
        self.observer_ticks.store(ticks as u64, Ordering::Relaxed);
        self.observer_changes.fetch_add(1, Ordering::Relaxed);
        self.last_change_tick.store(tick, Ordering::Relaxed);
    }

    pub(super) fn tick(&self, seen: Option<LinkDelaySeen>) {
        // Between connections the last one's figures stay (the next open's replace them).
        let Some(seen) = seen else {
            return;
        };
        self.round_trips.store(seen.round_trips, Ordering::Relaxed);
        self.typical_ns
            .store(nanos(seen.typical), Ordering::Relaxed);
        self.worst_ns
            .fetch_max(nanos(seen.worst), Ordering::Relaxed);
        self.worst_ticks
            .fetch_max(u64::from(seen.worst_ticks()), Ordering::Relaxed);
    }

    /// What `/api/stats` and the run summary show.
    pub fn report(&self) -> LinkDelayReport {
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let ms = |ns: u64| ns as f64 * 1e-6;
        let changes = load(&self.observer_changes);
        LinkDelayReport {
            observer_ticks: load(&self.observer_ticks),
            observer_changes: changes,
            last_change_t_s: if changes > 0 {
                load(&self.last_change_tick) as f64 * load(&self.period_ns) as f64 * 1e-9
            } else {
                0.0
            },
            declared_ms: ms(load(&self.declared_ns)),
            round_trips: load(&self.round_trips),
            typical_ms: ms(load(&self.typical_ns)),
            worst_ms: ms(load(&self.worst_ns)),
            worst_ticks: load(&self.worst_ticks),
        }
    }
}
