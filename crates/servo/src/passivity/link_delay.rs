//! The observer's pairing while the servo runs ([`LinkFollower`]): it follows the link's delay as the
//! device's driver times it on every tick, into the statistics that report it ([`LinkDelayStats`]).
//!
//! **Why follow.** The pairing chosen at start ([`super::latency::ObserverLatency`]) is the driver's figure
//! at open: for voxhap's protocol driver, a few dozen round trips timed before the servo ran. The delay a
//! loaded host really gives can exceed it, and an observer that pairs each step with a force sent `d` ticks
//! before, while the force that acted was sent earlier, books less than the delayed loop generated
//! ([`super::controller`], "Latency": `sin(w (d + 1/2) T)` falls as the pairing falls short of the delay).
//! So while the observer's latency comes from the driver, each tick reads the round trips the driver timed
//! since it opened (`ServoDevice::link_delay_seen`, crate `voxhap-device`'s `LinkDelaySeen`) and pairs with
//! their median plus one servo period in whole ticks (rounded up), at most
//! [`super::settings::MAX_LATENCY_TICKS`], and never less than the figure at open until the round trips timed
//! live are at least as many as the figure at open was measured from. From then on the live figure alone
//! decides, below the figure at open too: a figure measured at open on a loaded host (once 555 ms) would
//! otherwise keep the pairing that wide for the whole connection, the mispairing of a stall (below) for good.
//! A documented figure (no round trips) stays the floor. A reconnect opens a new driver, whose open measures
//! the link again: that figure replaces the pairing (it may be shorter), and the new connection's round trips
//! are followed from there.
//!
//! **Why the median plus a period, and not the longest** (docs/stability.md, "While the servo runs"): the
//! pairing is how many ticks each step is late. A stall lengthens the round trip of the force on the wire,
//! not the steps after it (neither side catches up missed ticks), and an observer paired that much too long
//! books a stiff delayed contact's generation as absorbed. The period covers the answers a tick after the
//! median, since a pairing a tick short books less than the loop generates. The longest round trip bounds
//! the energy the controller cannot have answered yet, not the pairing (`tests/device_passivity_pty.rs`).
//!
//! The pairing has one owner, the controller ([`PassivityController::latency_ticks_now`]): the follower
//! reads it there and sets it there, and the statistics ([`LinkDelayStats`]) are told the pairing at start
//! and at each change. The servo period the delays are counted in has one owner too, the follower: it hands
//! it to the statistics each tick, so the run summary's round trips in ticks and the pairing the observer
//! follows are one rule ([`ticks_of`], the uncapped `voxhap_device::latency::ticks_rounded_up`) on one period.
//!
//! A scene that writes `[passivity] latency_s`, and the simulated arm's `[arm] latency_s`, fix the pairing:
//! the user said what it is, and a test that tells the observer a wrong latency must get what it asked for.
//!
//! The figure at open is a worst case of its round trips (at most their median plus one servo period) and
//! both are rounded up to whole ticks, so the pairing errs long by at most about a tick, the safe side for
//! oscillations slower than a quarter period per delay ([`super::controller`], "Latency").
//!
//! Real-time: a few comparisons and relaxed atomic stores per tick; no allocation, no lock.

use super::controller::PassivityController;
use super::latency::{LatencyOrigin, ObserverLatency};
use super::link_stats::LinkDelayStats;
use super::settings::ticks_of;
use crate::device::ServoDevice;
use std::time::Duration;
use voxhap_device::latency::{LinkDelaySeen, LinkLatency};

/// What changed the observer's pairing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairingChange {
    /// The median round trip timed since open plus one period, in whole ticks, changed (below the figure at
    /// open only once as many round trips are timed as open's): the pairing followed it.
    Followed { from: usize, to: usize },
    /// A device (re)connected: its driver's figure at open replaced the pairing.
    Reconnected { from: usize, to: usize },
}

/// Follows the link for the observer's pairing (module docs). The pairing itself is the controller's
/// ([`PassivityController::latency_ticks_now`]): this reads it there and sets it there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkFollower {
    follows_driver: bool,
    /// The servo period: the pairing's ticks and the statistics' (module docs).
    period: Duration,
    /// The driver's figure at the last open, in ticks: the least the pairing follows down to while fewer than
    /// `open_round_trips` round trips were timed live.
    at_open: usize,
    /// How many round trips the figure at open was measured from (`u64::MAX` for a documented figure, or
    /// none: the floor then holds for the connection).
    open_round_trips: u64,
}

/// How many live round trips stand in for `link`'s figure at open (module docs): as many as it was measured
/// from; never, for a documented figure or none.
fn round_trips_behind(link: Option<LinkLatency>) -> u64 {
    match link {
        Some(link) if link.round_trips > 0 => u64::from(link.round_trips),
        _ => u64::MAX,
    }
}

impl LinkFollower {
    /// Follows the driver's figures when `latency` came from the driver (or nothing declared one); else
    /// leaves the pairing alone. `period` is the servo period.
    pub fn new(latency: &ObserverLatency, period: Duration) -> Self {
        LinkFollower {
            follows_driver: matches!(
                latency.origin,
                LatencyOrigin::Driver(_) | LatencyOrigin::Unknown
            ),
            period,
            at_open: latency.ticks,
            open_round_trips: round_trips_behind(match latency.origin {
                LatencyOrigin::Driver(link) => Some(link),
                _ => None,
            }),
        }
    }

    /// A follower that never changes the pairing (the default loop: no passivity); with no period, the
    /// statistics count the round trips in no ticks.
    pub fn fixed() -> Self {
        LinkFollower {
            follows_driver: false,
            period: Duration::ZERO,
            at_open: 0,
            open_round_trips: u64::MAX,
        }
    }

    /// `controller`'s pairing now and the delay `delay` in whole ticks, `(from, to)`; `None` when the pairing
    /// does not follow the driver.
    fn pairing(&self, delay: Duration, controller: &PassivityController) -> Option<(usize, usize)> {
        self.follows_driver.then(|| {
            (
                controller.latency_ticks_now(),
                ticks_of(delay.as_secs_f64(), self.period.as_secs_f64()),
            )
        })
    }

    /// A device connected (again): its driver's figure at open (`link`, its worst case) replaces
    /// `controller`'s pairing. `None` when nothing changed.
    pub fn connected(
        &mut self,
        link: Option<LinkLatency>,
        controller: &mut PassivityController,
    ) -> Option<PairingChange> {
        let (from, to) = self.pairing(link.map_or(Duration::ZERO, |l| l.worst), controller)?;
        self.at_open = to;
        self.open_round_trips = round_trips_behind(link);
        controller.set_latency_ticks(to);
        (from != to).then_some(PairingChange::Reconnected { from, to })
    }

    /// This tick's round trips timed since the connection opened: `controller` pairs with their median plus
    /// one servo period, or with the figure at open when that is longer and the round trips are fewer than
    /// open's (module docs). `None` when nothing changed.
    pub fn observe(
        &self,
        seen: Option<LinkDelaySeen>,
        controller: &mut PassivityController,
    ) -> Option<PairingChange> {
        let seen = seen?;
        let (from, median) = self.pairing(seen.typical + self.period, controller)?;
        let to = if seen.round_trips >= self.open_round_trips {
            median
        } else {
            median.max(self.at_open)
        };
        if to == from {
            return None;
        }
        controller.set_latency_ticks(to);
        Some(PairingChange::Followed { from, to })
    }

    /// One servo tick (`tick`): a connection this tick (`connected`) replaces `controller`'s pairing with the
    /// driver's figure at open, then the pairing follows the round trips timed; `stats` are told what changed
    /// and the round trips, in ticks of this follower's period.
    pub fn follow(
        &mut self,
        device: &dyn ServoDevice,
        connected: bool,
        controller: &mut PassivityController,
        stats: &LinkDelayStats,
        tick: u64,
    ) {
        let declared = connected.then(|| device.link_latency()).flatten();
        if connected {
            stats.declared(declared);
        }
        let seen = device.link_delay_seen();
        let mut changed = if connected {
            self.connected(declared, controller)
        } else {
            None
        };
        changed = self.observe(seen, controller).or(changed);
        if changed.is_some() {
            let t_s = tick as f64 * self.period.as_secs_f64();
            stats.changed(t_s, controller.latency_ticks_now());
        }
        stats.tick(seen, self.period);
    }
}

#[cfg(test)]
#[path = "link_delay_tests.rs"]
mod tests;
