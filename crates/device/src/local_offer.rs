//! What the servo loop offers a device with the local-model capability each tick (protocol/SPEC.md section 10):
//! the tick's primitives and coupling as a [`LocalOffer`], and what the device reported back as a
//! [`LocalReport`].
//!
//! Where it sits: the servo loop fills an offer from the tick's primitives and passes it in
//! [`TickInput::local`](crate::supervisor::TickInput::local); the supervisor hands it to a capable driver instead
//! of the set-force (`HapticDevice::write_local_model`) while the force it would send is valid; the voxhap
//! protocol driver turns it into a LocalModel message. Fixed-size and `Copy`: nothing here allocates.

use glam::DVec3;
use voxhap_protocol::{LocalKind, LocalModelParams, LocalStatus, SiPrimitive};

/// The most primitives an offer carries. The wire carries three (the summed directed forces and the nearest
/// others, SPEC 10.3); the offer keeps more so that the driver, not the loop, chooses them. A tick with more
/// than this keeps the first ones and says so ([`LocalOffer::truncated`]).
pub const MAX_OFFER_PRIMITIVES: usize = 16;

/// The recommended expiry (SPEC 10.3): five 1 kHz periods, microseconds.
pub const OFFER_EXPIRY_US: u16 = 5_000;

const EMPTY: SiPrimitive = SiPrimitive {
    kind: LocalKind::Directed,
    position_m: [0.0; 3],
    direction: [1.0, 0.0, 0.0],
    strength_n: 0.0,
};

/// One tick's local model before it is packed for the wire: coupling, anchor and primitives, device frame once
/// the workspace mapping has applied [`LocalOffer::mapped`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalOffer {
    /// Coupling stiffness, N/m.
    pub stiffness_n_per_m: f64,
    /// Coupling damping, N s/m.
    pub damping_n_s_per_m: f64,
    /// The host's proxy (the offsets' origin on the wire), metres.
    pub anchor_m: DVec3,
    primitives: [SiPrimitive; MAX_OFFER_PRIMITIVES],
    len: usize,
    truncated: bool,
}

impl LocalOffer {
    /// An offer with no primitives yet.
    pub fn new(stiffness_n_per_m: f64, damping_n_s_per_m: f64, anchor_m: DVec3) -> LocalOffer {
        LocalOffer {
            stiffness_n_per_m,
            damping_n_s_per_m,
            anchor_m,
            primitives: [EMPTY; MAX_OFFER_PRIMITIVES],
            len: 0,
            truncated: false,
        }
    }

    /// Adds a primitive; past [`MAX_OFFER_PRIMITIVES`] it is dropped and the offer is marked truncated.
    pub fn push(&mut self, primitive: SiPrimitive) {
        match self.primitives.get_mut(self.len) {
            Some(slot) => {
                *slot = primitive;
                self.len += 1;
            }
            None => self.truncated = true,
        }
    }

    /// The primitives offered.
    pub fn primitives(&self) -> &[SiPrimitive] {
        &self.primitives[..self.len]
    }

    /// True when the tick had more primitives than an offer holds.
    pub fn truncated(&self) -> bool {
        self.truncated
    }

    /// Scales every primitive's strength by `share` (clamped to [0, 1]; NaN counts as 0): at 0 the model
    /// holds the proxy nowhere and the device's coupling force is its damping alone.
    pub fn scale_strengths(&mut self, share: f64) {
        let share = if share.is_nan() {
            0.0
        } else {
            share.clamp(0.0, 1.0)
        };
        for p in &mut self.primitives[..self.len] {
            p.strength_n *= share;
        }
    }

    /// The LocalModel parameters for this offer (sequence 0: the host session numbers it), expiring after
    /// [`OFFER_EXPIRY_US`], with the force limit at most the device's own (SPEC 10.3).
    pub fn params(&self, force_limit_n: f64, device_max_force_n: f64) -> LocalModelParams {
        LocalModelParams {
            sequence: 0,
            expiry_us: OFFER_EXPIRY_US,
            stiffness_n_per_m: self.stiffness_n_per_m,
            damping_n_s_per_m: self.damping_n_s_per_m,
            force_limit_n: force_limit_n.min(device_max_force_n),
            anchor_m: self.anchor_m.to_array(),
        }
    }

    /// The offer through a map from scene to device frame: `position` maps points, `direction` maps vectors
    /// (a rotation: lengths kept), and `scale` is the scene length per device length (the mapping's `s` in
    /// `s R p + t`), so that the device renders the stiffness and damping the hand feels in the scene
    /// (`k_device = s k_scene`; a force is not scaled).
    pub fn mapped(
        &self,
        position: impl Fn(DVec3) -> DVec3,
        direction: impl Fn(DVec3) -> DVec3,
        scale: f64,
    ) -> LocalOffer {
        let mut out = *self;
        out.anchor_m = position(self.anchor_m);
        out.stiffness_n_per_m = self.stiffness_n_per_m * scale;
        out.damping_n_s_per_m = self.damping_n_s_per_m * scale;
        for p in &mut out.primitives[..self.len] {
            p.position_m = position(DVec3::from_array(p.position_m)).to_array();
            p.direction = direction(DVec3::from_array(p.direction)).to_array();
        }
        out
    }
}

/// How much of the model's strengths a capable device is sent while it engages.
///
/// The device engages only once its coupling force is below 0.1 N (SPEC 10.5, step 6). A directed force pushes
/// wherever the handle is, and a flow line holds the proxy to a line the moving handle keeps leaving, so a
/// scene with either above 0.1 N (the built-in scene's flow line: up to 0.4 N) would keep the device waiting
/// for ever. The host therefore sends the model's strengths at zero (the coupling alone, which holds the proxy
/// on the handle) until the device reports that it renders a model and its engage ramp has ended (`ACTIVE`,
/// neither `ENGAGING` nor `EXPIRED`), then ramps them in linearly over the host's own engage ramp, as the
/// host's own engage rule ramps its force in; a tick without a local model, or a report that the device is
/// engaging again, starts over.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EngageFade {
    /// When the device was first seen engaged in the current run of local ticks, host microseconds.
    engaged_since_us: Option<u64>,
}

impl EngageFade {
    /// The share of the strengths to send this tick, in [0, 1], from the device's last report.
    pub fn share(&mut self, report: Option<&LocalReport>, now_us: u64, ramp_us: u64) -> f64 {
        let engaged = report.is_some_and(|r| {
            let status = LocalStatus(r.status);
            status.contains(LocalStatus::ACTIVE)
                && !status.contains(LocalStatus::ENGAGING)
                && !status.contains(LocalStatus::EXPIRED)
        });
        if !engaged {
            self.engaged_since_us = None;
            return 0.0;
        }
        let since = *self.engaged_since_us.get_or_insert(now_us);
        if ramp_us == 0 {
            return 1.0;
        }
        (now_us.saturating_sub(since) as f64 / ramp_us as f64).min(1.0)
    }

    /// Starts over: the next local tick sends zero strengths until the device reports it engaged.
    pub fn reset(&mut self) {
        self.engaged_since_us = None;
    }
}

/// What a capable device last reported about its local loop (LocalState, SPEC 10.4), in the device frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalReport {
    /// The device's proxy, metres.
    pub proxy_m: DVec3,
    /// The force it applied, newtons.
    pub force_n: DVec3,
    /// The certified error bound of its last solve, metres.
    pub bound_m: f64,
    /// The largest force magnitude it applied since the report before, newtons.
    pub peak_force_n: f64,
    /// Sequence of the model in use (0: none).
    pub model_sequence: u32,
    /// How long ago that model arrived, device time, microseconds.
    pub model_age_us: u32,
    /// The local status bits (SPEC 10.4).
    pub status: u16,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(status: LocalStatus) -> LocalReport {
        LocalReport {
            proxy_m: DVec3::ZERO,
            force_n: DVec3::ZERO,
            bound_m: 0.0,
            peak_force_n: 0.0,
            model_sequence: 1,
            model_age_us: 0,
            status: status.0,
        }
    }

    /// Zero strengths before the device reports it engaged (SPEC 10.4's ACTIVE without ENGAGING
    /// or EXPIRED), then a linear ramp over the host's ramp time, and back to none when it engages again.
    #[test]
    fn directed_forces_wait_for_the_device_to_engage_then_ramp_in() {
        let ramp_us = 500_000;
        let mut fade = EngageFade::default();
        assert_eq!(fade.share(None, 0, ramp_us), 0.0);
        let engaging = report(LocalStatus(LocalStatus::ACTIVE.0 | LocalStatus::ENGAGING.0));
        assert_eq!(fade.share(Some(&engaging), 1_000, ramp_us), 0.0);
        let expired = report(LocalStatus(LocalStatus::ACTIVE.0 | LocalStatus::EXPIRED.0));
        assert_eq!(fade.share(Some(&expired), 2_000, ramp_us), 0.0);
        let engaged = report(LocalStatus::ACTIVE);
        assert_eq!(fade.share(Some(&engaged), 10_000, ramp_us), 0.0);
        assert_eq!(fade.share(Some(&engaged), 135_000, ramp_us), 0.25);
        assert_eq!(fade.share(Some(&engaged), 510_000, ramp_us), 1.0);
        assert_eq!(fade.share(Some(&engaged), 900_000, ramp_us), 1.0);
        assert_eq!(fade.share(Some(&engaging), 901_000, ramp_us), 0.0);
        assert_eq!(fade.share(Some(&engaged), 902_000, ramp_us), 0.0);
        fade.reset();
        assert_eq!(fade.share(Some(&engaged), 903_000, ramp_us), 0.0);
        assert_eq!(fade.share(Some(&engaged), 904_000, 0), 1.0);
    }

    /// Every strength is scaled, and nothing else.
    #[test]
    fn scaling_the_strengths_scales_every_primitive() {
        let mut offer = LocalOffer::new(500.0, 0.0, DVec3::ZERO);
        offer.push(SiPrimitive {
            kind: LocalKind::Directed,
            position_m: [0.0; 3],
            direction: [1.0, 0.0, 0.0],
            strength_n: 0.4,
        });
        offer.push(SiPrimitive {
            kind: LocalKind::Plane,
            position_m: [0.01, 0.0, 0.0],
            direction: [-1.0, 0.0, 0.0],
            strength_n: 30.0,
        });
        offer.scale_strengths(0.5);
        assert_eq!(offer.primitives()[0].strength_n, 0.2);
        assert_eq!(offer.primitives()[1].strength_n, 15.0);
        assert_eq!(offer.primitives()[1].position_m, [0.01, 0.0, 0.0]);
        offer.scale_strengths(f64::NAN);
        assert_eq!(offer.primitives()[0].strength_n, 0.0);
        assert_eq!(offer.primitives()[1].strength_n, 0.0);
    }
}
