//! The link delay's statistics ([`LinkDelayStats`]): what the passivity observer's pairing and the round trips
//! the driver timed were, for `/api/stats` and the run summary. Apart from [`super::link_delay`] so that the
//! servo's statistics do not depend on the device side.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use voxhap_api::LinkDelayReport;
use voxhap_device::latency::{LinkDelaySeen, LinkLatency};

/// The link delay's statistics: atomics the servo thread stores each tick (`super::link_delay::LinkFollower::follow`) and any
/// thread reports ([`LinkDelayStats::report`]).
#[derive(Debug, Default)]
pub struct LinkDelayStats {
    observer_ticks: AtomicU64,
    observer_changes: AtomicU64,
    /// The time of the last change, seconds into the run (`f64` bits: 0 is 0.0 s).
    last_change_s: AtomicU64,
    declared_ns: AtomicU64,
    round_trips: AtomicU64,
    typical_ns: AtomicU64,
    worst_ns: AtomicU64,
    worst_ticks: AtomicU64,
}

fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl LinkDelayStats {
    /// The session's start: the pairing chosen and the driver's figure at open.
    pub fn start(&self, ticks: usize, declared: Option<LinkLatency>) {
        self.observer_ticks.store(ticks as u64, Ordering::Relaxed);
        self.declared(declared);
    }

    pub(super) fn declared(&self, declared: Option<LinkLatency>) {
        let ns = declared.map_or(0, |l| nanos(l.worst));
        self.declared_ns.store(ns, Ordering::Relaxed);
    }

    /// The observer's pairing changed to `ticks` at `t_s` seconds into the run.
    pub(super) fn changed(&self, t_s: f64, ticks: usize) {
        self.observer_ticks.store(ticks as u64, Ordering::Relaxed);
        self.observer_changes.fetch_add(1, Ordering::Relaxed);
        self.last_change_s.store(t_s.to_bits(), Ordering::Relaxed);
    }

    /// This tick's round trips timed since the connection opened, counted in ticks of the servo period
    /// `period` by the rule and on the period the observer's pairing uses (`super::link_delay`).
    pub(super) fn tick(&self, seen: Option<LinkDelaySeen>, period: Duration) {
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
            .fetch_max(u64::from(seen.worst_ticks(period)), Ordering::Relaxed);
    }

    /// What `/api/stats` and the run summary show.
    pub fn report(&self) -> LinkDelayReport {
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let ms = |ns: u64| ns as f64 * 1e-6;
        LinkDelayReport {
            observer_ticks: load(&self.observer_ticks),
            observer_changes: load(&self.observer_changes),
            last_change_t_s: f64::from_bits(load(&self.last_change_s)),
            declared_ms: ms(load(&self.declared_ns)),
            round_trips: load(&self.round_trips),
            typical_ms: ms(load(&self.typical_ns)),
            worst_ms: ms(load(&self.worst_ns)),
            worst_ticks: load(&self.worst_ticks),
        }
    }
}
