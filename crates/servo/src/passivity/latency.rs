//! Which latency the passivity observer pairs with ([`ObserverLatency`]), where it came from, and the notice
//! `voxhap serve` prints naming it.
//!
//! The order ([`super::controller`], "Latency"): `[passivity] latency_s` when the scene writes it; else, on
//! the simulated arm, its `[arm] latency_s`; else the link latency the device's driver declares, its worst
//! case (a vendor driver's documented figure, or what voxhap's protocol driver measured on the link at open);
//! else 0. The observer pairs at most [`MAX_LATENCY_TICKS`]: a longer latency is booked as that many ticks,
//! and the notice says the controller cannot then be relied on. This is the pairing at start: while the
//! servo runs, a pairing from the driver follows the round trips the driver times on every tick and a
//! reconnect's new measurement ([`super::link_delay`]); the notice says so.

use super::settings::{ticks_of, PassivityMode, PassivitySettings, MAX_LATENCY_TICKS};
use voxhap_device::latency::{ticks_rounded_up, LinkLatency};

/// Where the observer's latency came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LatencyOrigin {
    /// The scene's `[passivity] latency_s`.
    Scene,
    /// The simulated arm's `[arm] latency_s`.
    SimulatedArm,
    /// The link latency the device's driver declares (its worst case is used).
    Driver(LinkLatency),
    /// Nothing declares one: 0.
    Unknown,
}

/// The latency the observer pairs with (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverLatency {
    /// The latency (s).
    pub latency_s: f64,
    /// In whole ticks of the servo period, rounded up, at most [`MAX_LATENCY_TICKS`].
    pub ticks: usize,
    /// More whole ticks than the observer pairs (it pairs [`MAX_LATENCY_TICKS`] instead).
    pub beyond_observer: bool,
    /// Where it came from.
    pub origin: LatencyOrigin,
}

impl ObserverLatency {
    /// The observer's latency at servo period `period_s`, from the scene's settings, the simulated arm's
    /// latency when the device is the simulated arm, and the connected driver's declared link latency.
    pub fn choose(
        settings: &PassivitySettings,
        simulated_arm_latency_s: Option<f64>,
        link: Option<LinkLatency>,
        period_s: f64,
    ) -> ObserverLatency {
        let (latency_s, origin) = match (settings.latency_s, simulated_arm_latency_s, link) {
            (Some(s), _, _) => (s, LatencyOrigin::Scene),
            (None, Some(s), _) => (s, LatencyOrigin::SimulatedArm),
            (None, None, Some(link)) => (link.worst.as_secs_f64(), LatencyOrigin::Driver(link)),
            (None, None, None) => (0.0, LatencyOrigin::Unknown),
        };
        let ticks = ticks_of(latency_s, period_s);
        // ticks_of stops at MAX_LATENCY_TICKS; the same rule, unbounded, says when the latency is beyond it.
        let beyond_observer = ticks_rounded_up(latency_s, period_s) as usize > MAX_LATENCY_TICKS;
        ObserverLatency {
            latency_s,
            ticks,
            beyond_observer,
            origin,
        }
    }

    /// What `serve` prints about it: the ticks, the seconds, and where they came from; `None` when the
    /// observer is off, and for the simulated arm's own `[arm] latency_s` (the user wrote it there; the
    /// simulated arm's defaults print nothing).
    pub fn notice(&self, mode: PassivityMode, device: &str, rate_hz: f64) -> Option<String> {
        if mode == PassivityMode::Off || self.origin == LatencyOrigin::SimulatedArm {
            return None;
        }
        let ticks = self.ticks;
        let plural = if ticks == 1 { "" } else { "s" };
        let from = match self.origin {
            LatencyOrigin::Scene => "the scene's [passivity] latency_s".to_owned(),
            LatencyOrigin::SimulatedArm => return None,
            LatencyOrigin::Driver(link) if link.round_trips > 0 => format!(
                "the link latency device {device}'s driver measured at open: the 95th percentile of {} round \
                 trips from a zero force to the State echoing it, at most their median plus one servo period, \
                 rounded up to 0.1 ms (median {:.3} ms)",
                link.round_trips,
                link.typical.as_secs_f64() * 1e3
            ),
            LatencyOrigin::Driver(link) => format!(
                "the link latency device {device}'s driver declares ({})",
                link.source
            ),
            LatencyOrigin::Unknown => format!(
                "nothing: device {device}'s driver declares no link latency (write [passivity] latency_s if its \
                 link has one)"
            ),
        };
        let mut notice = format!(
            "passivity {}: the observer pairs each force with the motion {ticks} tick{plural} later \
             ({:.3} ms at {rate_hz} Hz), from {from}",
            mode.name(),
            self.latency_s * 1e3
        );
        if matches!(
            self.origin,
            LatencyOrigin::Driver(_) | LatencyOrigin::Unknown
        ) {
            notice.push_str(
                "; while serve runs it follows the median round trip the driver times plus one period, below this \
                 figure only once it has timed as many round trips as this figure came from (the run summary's link \
                 delay line and /api/stats say when)",
            );
        }
        if self.beyond_observer {
            notice.push_str(&format!(
                "; that is more than the {MAX_LATENCY_TICKS} ticks the observer pairs, so it books the energy \
                 {MAX_LATENCY_TICKS} ticks late and the passivity controller cannot be relied on to keep this \
                 coupling passive: keep the stiffness under the caps"
            ));
        }
        Some(notice)
    }
}

#[cfg(test)]
#[path = "latency_tests.rs"]
mod tests;
