//! The device link's delay as the session saw it ([`LinkDelayReport`]): the figure the driver declared at
//! open, the round trips it timed on every tick, and the latency the passivity observer pairs with now
//! (crate `voxhap-servo`, `passivity::link_delay`).

use serde::Serialize;

/// The link's delay during the run, in `/api/stats` (`link_delay`) and the run summary.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct LinkDelayReport {
    /// Ticks the passivity observer pairs each force and the motion it meets with, now.
    pub observer_ticks: u64,
    /// Times that pairing changed while the session ran: following the median round trip the driver timed
    /// (plus one servo period, below the figure at open only once as many round trips were timed as it came
    /// from), or replaced by a reconnect's new measurement.
    pub observer_changes: u64,
    /// When it last changed (s after the session started); 0 while `observer_changes` is 0.
    pub last_change_t_s: f64,
    /// The worst case the connected device's driver declared at its last open (ms); 0: none declared.
    pub declared_ms: f64,
    /// Round trips the driver timed on every tick since its last open; 0: its driver times none.
    pub round_trips: u64,
    /// Their median (ms, rounded up to 0.1 ms).
    pub typical_ms: f64,
    /// The longest round trip timed on any connection of the session (ms).
    pub worst_ms: f64,
    /// That, in whole servo ticks (rounded up).
    pub worst_ticks: u64,
}

impl LinkDelayReport {
    /// The line of the run summary (`serve`'s exit table), with a newline.
    pub fn summary(&self) -> String {
        let observer = format!(
            "the passivity observer pairs {} ticks (changed {} time{}{})",
            self.observer_ticks,
            self.observer_changes,
            if self.observer_changes == 1 { "" } else { "s" },
            if self.observer_changes > 0 {
                format!(", last at {:.3} s", self.last_change_t_s)
            } else {
                String::new()
            }
        );
        if self.round_trips == 0 {
            return format!("link delay: not timed by the driver; {observer}\n");
        }
        format!(
            "link delay: worst round trip seen {:.3} ms ({} ticks), median {:.3} ms over {} round trips, \
             declared at open {:.3} ms; {observer}\n",
            self.worst_ms, self.worst_ticks, self.typical_ms, self.round_trips, self.declared_ms
        )
    }
}
