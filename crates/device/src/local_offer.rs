//! What the servo loop offers a device with the local-model capability each tick (protocol/SPEC.md section 10):
//! the tick's primitives and coupling as a [`LocalOffer`], and what the device reported back as a
//! [`LocalReport`].
//!
//! Where it sits: the servo loop fills an offer from the tick's primitives and passes it in
//! [`TickInput::local`](crate::supervisor::TickInput::local); the supervisor hands it to a capable driver instead
//! of the set-force (`HapticDevice::write_local_model`) while the force it would send is valid; the voxhap
//! protocol driver turns it into a LocalModel message. Fixed-size and `Copy`: nothing here allocates.

use glam::DVec3;
use voxhap_protocol::{
    LocalKind, LocalModelParams, LocalPassivity, LocalPassivityMode, SiPrimitive,
};

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

/// What a capable device's own passivity observer and controller run (SPEC 10.5 step 4b), before the most
/// damping is coded for the wire (the largest step `1.25 × 2^c` N s/m not above it).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PassivityOffer {
    /// Off, observe or control.
    pub mode: LocalPassivityMode,
    /// The controller's most damping, N s/m (the scene's `[passivity] max_damping_n_s_per_m`).
    pub max_damping_n_s_per_m: f64,
}

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
    /// What the device's passivity observer and controller do (SPEC 10.5 step 4b); off unless set.
    pub passivity: PassivityOffer,
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
            passivity: PassivityOffer::default(),
            primitives: [EMPTY; MAX_OFFER_PRIMITIVES],
            len: 0,
            truncated: false,
        }
    }

    /// The offer with the device's passivity request (the scene's `[passivity]` mode and most damping).
    pub fn with_passivity(mut self, passivity: PassivityOffer) -> LocalOffer {
        self.passivity = passivity;
        self
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
            passivity: LocalPassivity::new(
                self.passivity.mode,
                self.passivity.max_damping_n_s_per_m,
            ),
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
        out.passivity.max_damping_n_s_per_m = self.passivity.max_damping_n_s_per_m * scale;
        for p in &mut out.primitives[..self.len] {
            p.position_m = position(DVec3::from_array(p.position_m)).to_array();
            p.direction = direction(DVec3::from_array(p.direction)).to_array();
        }
        out
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
