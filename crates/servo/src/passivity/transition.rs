//! Passive introduction of changes made while the probe is in contact: a new stiffness, a mode switched on,
//! a primitive that appears with the probe already past it.
//!
//! A change applied at once can put energy into the hand: raising the stiffness from `k0` to `k1` with the
//! spring stretched by `s` adds `(k1 - k0) s^2 / 2`, which the spring gives back to the hand as it leaves; a
//! plane that appears above a probe already below it stores `k d^2 / 2` at once. Instead, the spring pulls
//! towards an *anchor* (a virtual proxy):
//!
//! - At the change, with the probe at `x`, the old anchor `a0` and stiffness `k0`, and the new proxy `p` and
//!   stiffness `k1`: if the new spring holds no more energy than the old one (`k1 |p - x|^2 <= k0 |a0 - x|^2`:
//!   a softer spring, a mode switched off, a damping change) the change applies at once. Otherwise the anchor
//!   is set so that the force is unchanged, `a = x + (k0 / k1) (a0 - x)`, moved towards `x` if that would still
//!   hold more energy than the old spring (a softer spring with a larger stretch). Its energy,
//!   `k0^2 |a0 - x|^2 / (2 k1)`, is at most the old spring's: the change itself injects nothing.
//! - Every tick after it, the anchor moves to the point of the segment from the anchor to the proxy nearest
//!   the probe. That never raises the spring's energy at the probe's position, so the spring stays passive
//!   (it only gives back what the hand put in since). A probe pressing on feels the new stiffness at once for
//!   the further press; a probe leaving drags the anchor out with it (the force falls to zero, then the anchor
//!   follows the probe) until the proxy is no farther from the probe than the anchor: then the spring pulls
//!   towards the proxy again and the change is complete.
//! - A primitive that appears under the probe (the probe already past it) is the case `a0 = x`: the force
//!   starts at zero and the surface rises with the leaving probe, as the safety pipeline's engage rule does
//!   after an Enable (forces wait until the handle is out of the object).
//!
//! The anchor moves only in a closed segment ending at the proxy, so a finite anchor stays finite. Real-time:
//! a few vector operations per tick, no allocation.

use glam::DVec3;

/// The coupling's anchor while a change made in contact is being introduced (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CouplingTransition {
    active: bool,
    anchor_m: DVec3,
    previous_m: DVec3,
    /// Changes introduced gradually (not applied at once), for the summary.
    introduced: u64,
}

impl CouplingTransition {
    /// No transition under way.
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether a change is still being introduced.
    pub fn active(&self) -> bool {
        self.active
    }

    /// Changes introduced gradually so far.
    pub fn introduced(&self) -> u64 {
        self.introduced
    }

    /// A change was just applied: the probe is at `probe_m`; before the change the spring pulled towards
    /// `old_anchor_m` with `old_k`; now the proxy is `proxy_m` and the stiffness `new_k`.
    pub fn begin(
        &mut self,
        probe_m: DVec3,
        old_anchor_m: DVec3,
        old_k: f64,
        proxy_m: DVec3,
        new_k: f64,
    ) {
        let old_j = 0.5 * old_k * (old_anchor_m - probe_m).length_squared();
        let new_j = 0.5 * new_k * (proxy_m - probe_m).length_squared();
        let rises = new_j > old_j && new_k > 0.0;
        if !rises || !old_j.is_finite() || !probe_m.is_finite() {
            // No rise (or nothing sane to keep): the change applies at once.
            self.active = false;
            return;
        }
        let mut stretch_m = (old_k / new_k) * (old_anchor_m - probe_m);
        let kept_j = 0.5 * new_k * stretch_m.length_squared();
        if kept_j > old_j {
            stretch_m *= (old_j / kept_j).sqrt();
        }
        self.anchor_m = probe_m + stretch_m;
        self.previous_m = self.anchor_m;
        self.active = true;
        self.introduced += 1;
    }

    /// This tick's anchor, given the probe and the proxy the tick rendered, and the anchor's velocity (m/s)
    /// over `dt_s` (zero on the tick a transition begins; the proxy's own velocity otherwise is the caller's).
    /// Returns `None` when no transition is under way: the spring pulls towards the proxy.
    pub fn anchor(&mut self, probe_m: DVec3, proxy_m: DVec3, dt_s: f64) -> Option<(DVec3, DVec3)> {
        if !self.active {
            return None;
        }
        let reach = (self.anchor_m - probe_m).length();
        if (proxy_m - probe_m).length() <= reach || !proxy_m.is_finite() {
            self.active = false;
            return None;
        }
        let segment = proxy_m - self.anchor_m;
        let length2 = segment.length_squared();
        if length2 > 0.0 {
            let along = ((probe_m - self.anchor_m).dot(segment) / length2).clamp(0.0, 1.0);
            self.anchor_m += along * segment;
        }
        let velocity = if dt_s > 0.0 {
            (self.anchor_m - self.previous_m) / dt_s
        } else {
            DVec3::ZERO
        };
        self.previous_m = self.anchor_m;
        Some((self.anchor_m, velocity))
    }
}

#[cfg(test)]
#[path = "transition_tests.rs"]
mod tests;
