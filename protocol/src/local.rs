//! The local-model capability (SPEC.md section 10): one tick's haptic primitives sent to the device, which solves
//! the proxy against them at its own rate, and the device's report of what it rendered.
//!
//! Where it sits: [`LocalModel`] is a host-to-device message (type 0x08) and [`LocalState`] a device-to-host one
//! (type 0x86); [`crate::message`] frames them like every other message, with the layouts written here. The wire
//! form is fixed-point where that buys room (a whole model fills one 62-byte payload, one full-speed HID report);
//! [`LocalModel::primitive`] turns a slot back into SI units, and [`crate::local_build`] builds a model from SI
//! primitives on the host (nearest first, the rest dropped and flagged).

use crate::cursor::{finite, in_range, Reader, Writer};
use crate::error::PayloadError;
use crate::num::sqrt;

/// Type byte of [`LocalModel`] (host to device).
pub const LOCAL_MODEL_TYPE: u8 = 0x08;
/// Type byte of [`LocalState`] (device to host).
pub const LOCAL_STATE_TYPE: u8 = 0x86;
/// Payload size of [`LocalModel`]: 26 header bytes and [`MAX_LOCAL_PRIMITIVES`] slots of 12 bytes.
pub const LOCAL_MODEL_LEN: usize = 62;
/// Payload size of [`LocalState`].
pub const LOCAL_STATE_LEN: usize = 52;
/// Primitive slots in one model: the most that fit one 64-byte HID report (62 payload bytes) after the header.
pub const MAX_LOCAL_PRIMITIVES: usize = 3;
/// Metres per unit of a slot's offset from the anchor (1 µm; an offset spans ±32.767 mm).
pub const OFFSET_UNIT_M: f64 = 1e-6;
/// Newtons per unit of a slot's strength and of the model's force limit (1 mN; at most 65.535 N).
pub const FORCE_UNIT_N: f64 = 1e-3;
/// N·s/m per unit of the model's coupling damping (at most 65.535 N·s/m).
pub const DAMPING_UNIT_N_S_PER_M: f64 = 1e-3;
/// Largest magnitude of an octahedral direction component (the unit of the encoding).
pub const OCT_SCALE: i16 = 32_767;
/// Shortest expiry a device accepts, microseconds.
pub const MIN_EXPIRY_US: u16 = 1_000;
/// Longest expiry a device accepts, microseconds.
pub const MAX_EXPIRY_US: u16 = 50_000;
/// After its expiry, a model's force limit falls linearly to zero over this long, microseconds.
pub const RAMP_DOWN_US: u32 = 5_000;
/// A solve whose certified bound exceeds this (m) is not rendered: the device ramps down as on expiry.
pub const MAX_BOUND_M: f64 = 1e-5;
/// The device's passivity controller's most damping at code 0 (N·s/m); code `c` is `2^c` times this.
pub const PASSIVITY_DAMPING_UNIT_N_S_PER_M: f64 = 1.25;
/// Largest passivity damping code (3 bits): 160 N·s/m.
pub const MAX_PASSIVITY_DAMPING_CODE: u8 = 7;
/// Excess energy the device's passivity controller lets pass before it acts, J (SPEC 10.5 step 4b).
pub const PASSIVITY_THRESHOLD_J: f64 = 1e-6;

/// What the device's passivity observer and controller do (`kinds_flags` bits 9-10, SPEC 10.2 and 10.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LocalPassivityMode {
    /// Neither: the force is the coupling's (code 0).
    #[default]
    Off,
    /// The observer books the coupling's energy; no force is added (code 1).
    Observe,
    /// The observer books it and the controller dissipates the excess (code 2).
    Control,
}

/// The passivity request a model carries: the mode and the controller's most damping
/// (`kinds_flags` bits 9-13, SPEC 10.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LocalPassivity {
    /// What the device runs.
    pub mode: LocalPassivityMode,
    /// The controller's most damping as a code `c` (0..=7): `1.25 × 2^c` N·s/m.
    pub damping_code: u8,
}

impl LocalPassivity {
    /// Off (the device's observer and controller do nothing), damping code 0.
    pub const OFF: LocalPassivity = LocalPassivity {
        mode: LocalPassivityMode::Off,
        damping_code: 0,
    };

    /// `mode` with the largest code whose damping does not exceed `max_damping_n_s_per_m` (code 0, 1.25 N·s/m,
    /// for anything smaller or not a number; code 7, 160 N·s/m, for anything larger).
    pub fn new(mode: LocalPassivityMode, max_damping_n_s_per_m: f64) -> Self {
        let mut damping_code = 0;
        while damping_code < MAX_PASSIVITY_DAMPING_CODE
            && passivity_damping(damping_code + 1) <= max_damping_n_s_per_m
        {
            damping_code += 1;
        }
        LocalPassivity { mode, damping_code }
    }

    /// The controller's most damping, N·s/m.
    pub fn max_damping_n_s_per_m(&self) -> f64 {
        passivity_damping(self.damping_code.min(MAX_PASSIVITY_DAMPING_CODE))
    }

    /// Bits 9-13 of `kinds_flags`.
    fn bits(self) -> u16 {
        let mode = match self.mode {
            LocalPassivityMode::Off => 0,
            LocalPassivityMode::Observe => 1,
            LocalPassivityMode::Control => 2,
        };
        (mode << PASSIVITY_MODE_SHIFT)
            | (u16::from(self.damping_code.min(MAX_PASSIVITY_DAMPING_CODE))
                << PASSIVITY_DAMPING_SHIFT)
    }

    /// From bits 9-13 of `kinds_flags`; `None` for mode code 3.
    fn from_bits(packed: u16) -> Option<Self> {
        let mode = match (packed >> PASSIVITY_MODE_SHIFT) & 0b11 {
            0 => LocalPassivityMode::Off,
            1 => LocalPassivityMode::Observe,
            2 => LocalPassivityMode::Control,
            _ => return None,
        };
        let damping_code = ((packed >> PASSIVITY_DAMPING_SHIFT) & 0b111) as u8;
        Some(LocalPassivity { mode, damping_code })
    }
}

/// `1.25 × 2^code` N·s/m.
fn passivity_damping(code: u8) -> f64 {
    PASSIVITY_DAMPING_UNIT_N_S_PER_M * f64::from(1u16 << code)
}

const PASSIVITY_MODE_SHIFT: u16 = 9;
const PASSIVITY_DAMPING_SHIFT: u16 = 11;
/// Bits 9-13 of `kinds_flags`: the passivity request.
const PASSIVITY_FIELD: u16 = 0b11111 << PASSIVITY_MODE_SHIFT;

/// What a primitive slot holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LocalKind {
    /// A constant force `s q`.
    Directed,
    /// A point pulling the proxy with at most `s`.
    Point,
    /// A line pulling the proxy onto it with at most `s`.
    Line,
    /// A half-space boundary pushing a proxy behind it out with at most `s`.
    Plane,
}

impl LocalKind {
    /// The 3-bit code on the wire (0 is an empty slot).
    pub const fn code(self) -> u16 {
        match self {
            LocalKind::Directed => 1,
            LocalKind::Point => 2,
            LocalKind::Line => 3,
            LocalKind::Plane => 4,
        }
    }

    /// The kind of a wire code; `None` for 0 (empty) and for 5..=7 (malformed).
    pub const fn from_code(code: u16) -> Option<Self> {
        match code {
            1 => Some(LocalKind::Directed),
            2 => Some(LocalKind::Point),
            3 => Some(LocalKind::Line),
            4 => Some(LocalKind::Plane),
            _ => None,
        }
    }
}

/// One primitive slot as it travels: fixed point, relative to the model's anchor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LocalPrimitive {
    /// Which primitive.
    pub kind: LocalKind,
    /// Position minus the anchor, micrometres (zero for a directed force).
    pub offset_um: [i16; 3],
    /// Unit direction, octahedral encoding in units of 1/32767, each in -32767..=32767 (zero for a point).
    pub direction_oct: [i16; 2],
    /// Strength, millinewtons.
    pub strength_mn: u16,
}

/// A slot decoded to SI units (what the device's solver takes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SiPrimitive {
    /// Which primitive.
    pub kind: LocalKind,
    /// A point of the primitive, metres, device frame (ignored for a directed force).
    pub position_m: [f64; 3],
    /// Unit direction (ignored for a point).
    pub direction: [f64; 3],
    /// Strength, newtons, >= 0.
    pub strength_n: f64,
}

crate::fields::bit_set! {
    /// Flags of a [`LocalModel`], with the slot kinds packed beside them in the same u16.
    ModelFlags(u16) {
        /// The host had more primitives than fit (or some out of the offset range) and sent the nearest.
        TRUNCATED = 1 << 15;
        /// A strength or the force limit was above 65.535 N and was sent as 65.535 N.
        SATURATED = 1 << 14;
    }
}

/// Host to device, type 0x08, 62 bytes: one tick's local model (SPEC section 10.2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalModel {
    /// Host counter shared with set-force (+1 per set-force or local model, wrapping); echoed in
    /// [`crate::State::last_force_sequence`] and [`LocalState::model_sequence`].
    pub sequence: u32,
    /// The model is rendered for this long after it is received, then ramped down, microseconds, 1000..=50000.
    pub expiry_us: u16,
    /// [`ModelFlags::TRUNCATED`] and [`ModelFlags::SATURATED`]; the kinds live in `primitives`, the
    /// passivity request in `passivity`.
    pub flags: ModelFlags,
    /// What the device's passivity observer and controller do (bits 9-13 of `kinds_flags`).
    pub passivity: LocalPassivity,
    /// Coupling stiffness, N/m, >= 1.
    pub stiffness_n_per_m: u16,
    /// Coupling damping, units of 0.001 N·s/m.
    pub damping_mn_s_per_m: u16,
    /// Force limit, millinewtons (the device also clamps to its own `max_force_n`).
    pub force_limit_mn: u16,
    /// Origin of the slots' offsets, metres, device frame; finite.
    pub anchor_m: [f32; 3],
    /// The slots, filled from the first; `None` is an empty slot (all zero bytes on the wire).
    pub primitives: [Option<LocalPrimitive>; MAX_LOCAL_PRIMITIVES],
}

/// Device to host, type 0x86, 52 bytes: what the device's local loop rendered (SPEC section 10.4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalState {
    /// `sequence` of the State this report follows (the same sample).
    pub state_sequence: u32,
    /// Sequence of the local model in use (0: none since Enable).
    pub model_sequence: u32,
    /// Device time since that model was received, microseconds (saturating).
    pub model_age_us: u32,
    /// The device-side proxy at the sample, metres, device frame.
    pub proxy_m: [f32; 3],
    /// The force applied at the sample (after clamp, slew limit and ramps), newtons.
    pub force_n: [f32; 3],
    /// Certified bound of the sample's solve, metres, >= 0.
    pub bound_m: f32,
    /// Largest certified bound of the solves since the previous report, metres, >= 0.
    pub worst_bound_m: f32,
    /// Largest applied force magnitude since the previous report, newtons, >= 0.
    pub peak_force_n: f32,
    /// [`LocalStatus`] bits.
    pub status: LocalStatus,
    /// Local solves since the previous report (saturating).
    pub solves: u16,
}

crate::fields::bit_set! {
    /// Status of the device's local loop in [`LocalState`].
    LocalStatus(u16) {
        /// The loop renders a local model (enabled, a model received since Enable, not ramped out).
        ACTIVE = 1 << 0;
        /// The model in use passed its expiry: the force is ramping down or zero.
        EXPIRED = 1 << 1;
        /// A solve since the previous report ended with a bound above the limit and was not rendered.
        NO_SOLUTION = 1 << 2;
        /// A force since the previous report was scaled down to the force limit.
        CLAMPED = 1 << 3;
        /// A force since the previous report was held back by the slew limit.
        SLEW_LIMITED = 1 << 4;
        /// The engage ramp is running (or waits for the rendered force to fall below 1 N).
        ENGAGING = 1 << 5;
        /// The model in use carries [`ModelFlags::TRUNCATED`].
        TRUNCATED = 1 << 6;
        /// The passivity controller added a force in a cycle since the previous report.
        DISSIPATING = 1 << 7;
    }
}

const KIND_BITS: u16 = 3;
const KIND_MASK: u16 = 0b111;

impl LocalModel {
    /// The model's slots in SI units, in order, skipping empty ones.
    pub fn si_primitives(&self) -> impl Iterator<Item = SiPrimitive> + '_ {
        self.primitives.iter().flatten().map(|p| self.slot_in_si(p))
    }

    /// Number of filled slots.
    pub fn primitive_count(&self) -> usize {
        self.primitives.iter().flatten().count()
    }

    /// Coupling damping, N·s/m.
    pub fn damping_n_s_per_m(&self) -> f64 {
        f64::from(self.damping_mn_s_per_m) * DAMPING_UNIT_N_S_PER_M
    }

    /// Force limit, N.
    pub fn force_limit_n(&self) -> f64 {
        f64::from(self.force_limit_mn) * FORCE_UNIT_N
    }

    fn slot_in_si(&self, p: &LocalPrimitive) -> SiPrimitive {
        let anchor = self.anchor_m.map(f64::from);
        let position_m =
            core::array::from_fn(|i| anchor[i] + f64::from(p.offset_um[i]) * OFFSET_UNIT_M);
        SiPrimitive {
            kind: p.kind,
            position_m,
            direction: oct_decode(p.direction_oct),
            strength_n: f64::from(p.strength_mn) * FORCE_UNIT_N,
        }
    }

    pub(crate) fn validate(&self) -> Result<(), PayloadError> {
        let t = LOCAL_MODEL_TYPE;
        in_range(
            t,
            "expiry_us",
            (MIN_EXPIRY_US..=MAX_EXPIRY_US).contains(&self.expiry_us),
        )?;
        in_range(t, "stiffness_n_per_m", self.stiffness_n_per_m >= 1)?;
        finite(t, "anchor_m", &self.anchor_m)?;
        let filled = self.primitive_count();
        let contiguous = self.primitives[..filled].iter().all(Option::is_some);
        in_range(t, "primitives", contiguous)?;
        let oct_ok = self
            .primitives
            .iter()
            .flatten()
            .all(|p| p.direction_oct.iter().all(|&c| c >= -OCT_SCALE));
        in_range(t, "direction_oct", oct_ok)
    }

    pub(crate) fn write(&self, w: &mut Writer) {
        let kinds = self
            .primitives
            .iter()
            .enumerate()
            .fold(0u16, |acc, (i, p)| {
                acc | (p.map_or(0, |p| p.kind.code()) << (KIND_BITS * i as u16))
            });
        w.u32(self.sequence);
        w.u16(self.expiry_us);
        w.u16((self.flags.0 & !(KIND_FIELD | PASSIVITY_FIELD)) | kinds | self.passivity.bits());
        w.u16(self.stiffness_n_per_m);
        w.u16(self.damping_mn_s_per_m);
        w.u16(self.force_limit_mn);
        w.vec3(self.anchor_m);
        for slot in &self.primitives {
            let p = slot.unwrap_or(EMPTY_SLOT);
            p.offset_um.iter().for_each(|&o| w.u16(o as u16));
            p.direction_oct.iter().for_each(|&o| w.u16(o as u16));
            w.u16(p.strength_mn);
        }
    }

    pub(crate) fn read(r: &mut Reader) -> Result<Self, PayloadError> {
        let t = LOCAL_MODEL_TYPE;
        let sequence = r.u32();
        let expiry_us = r.u16();
        let packed = r.u16();
        let stiffness_n_per_m = r.u16();
        let damping_mn_s_per_m = r.u16();
        let force_limit_mn = r.u16();
        let anchor_m = r.vec3();
        let passivity = LocalPassivity::from_bits(packed);
        in_range(t, "passivity", passivity.is_some())?;
        let mut primitives = [None; MAX_LOCAL_PRIMITIVES];
        for (i, slot) in primitives.iter_mut().enumerate() {
            let offset_um = [r.u16() as i16, r.u16() as i16, r.u16() as i16];
            let direction_oct = [r.u16() as i16, r.u16() as i16];
            let strength_mn = r.u16();
            let code = (packed >> (KIND_BITS * i as u16)) & KIND_MASK;
            *slot = match LocalKind::from_code(code) {
                Some(kind) => Some(LocalPrimitive {
                    kind,
                    offset_um,
                    direction_oct,
                    strength_mn,
                }),
                None => {
                    in_range(t, "kind", code == 0)?;
                    let empty = offset_um == [0; 3] && direction_oct == [0; 2] && strength_mn == 0;
                    in_range(t, "primitives", empty)?;
                    None
                }
            };
        }
        Ok(LocalModel {
            sequence,
            expiry_us,
            flags: ModelFlags(packed & !(KIND_FIELD | PASSIVITY_FIELD)),
            passivity: passivity.unwrap_or(LocalPassivity::OFF),
            stiffness_n_per_m,
            damping_mn_s_per_m,
            force_limit_mn,
            anchor_m,
            primitives,
        })
    }
}

/// The bits of the packed u16 that hold the three 3-bit kind codes.
const KIND_FIELD: u16 = (1 << (KIND_BITS * MAX_LOCAL_PRIMITIVES as u16)) - 1;

const EMPTY_SLOT: LocalPrimitive = LocalPrimitive {
    kind: LocalKind::Directed,
    offset_um: [0; 3],
    direction_oct: [0; 2],
    strength_mn: 0,
};

impl LocalState {
    pub(crate) fn validate(&self) -> Result<(), PayloadError> {
        let t = LOCAL_STATE_TYPE;
        finite(t, "proxy_m", &self.proxy_m)?;
        finite(t, "force_n", &self.force_n)?;
        for (field, value) in [
            ("bound_m", self.bound_m),
            ("worst_bound_m", self.worst_bound_m),
            ("peak_force_n", self.peak_force_n),
        ] {
            finite(t, field, &[value])?;
            in_range(t, field, value >= 0.0)?;
        }
        Ok(())
    }

    pub(crate) fn write(&self, w: &mut Writer) {
        w.u32(self.state_sequence);
        w.u32(self.model_sequence);
        w.u32(self.model_age_us);
        w.vec3(self.proxy_m);
        w.vec3(self.force_n);
        w.f32(self.bound_m);
        w.f32(self.worst_bound_m);
        w.f32(self.peak_force_n);
        w.u16(self.status.0);
        w.u16(self.solves);
    }

    pub(crate) fn read(r: &mut Reader) -> Self {
        LocalState {
            state_sequence: r.u32(),
            model_sequence: r.u32(),
            model_age_us: r.u32(),
            proxy_m: r.vec3(),
            force_n: r.vec3(),
            bound_m: r.f32(),
            worst_bound_m: r.f32(),
            peak_force_n: r.f32(),
            status: LocalStatus(r.u16()),
            solves: r.u16(),
        }
    }
}

/// Decodes an octahedral direction (SPEC section 10.3) to a unit vector.
pub fn oct_decode(oct: [i16; 2]) -> [f64; 3] {
    let scale = f64::from(OCT_SCALE);
    let (u, v) = (f64::from(oct[0]) / scale, f64::from(oct[1]) / scale);
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 {
        ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v))
    } else {
        (u, v)
    };
    let norm = sqrt(x * x + y * y + z * z);
    [x / norm, y / norm, z / norm]
}

/// Encodes a non-zero finite direction (any length) in the octahedral form; `None` for zero or non-finite.
pub fn oct_encode(direction: [f64; 3]) -> Option<[i16; 2]> {
    let l1 = direction.iter().map(|c| c.abs()).sum::<f64>();
    if !l1.is_finite() || l1 <= 0.0 {
        return None;
    }
    let [x, y, z] = direction.map(|c| c / l1);
    let (u, v) = if z < 0.0 {
        ((1.0 - y.abs()) * sign(x), (1.0 - x.abs()) * sign(y))
    } else {
        (x, y)
    };
    let q = |c: f64| round(c * f64::from(OCT_SCALE)).clamp(-32767.0, 32767.0) as i16;
    Some([q(u), q(v)])
}

/// +1 for zero and positive, -1 for negative (the octahedral fold's convention).
fn sign(x: f64) -> f64 {
    if x < 0.0 {
        -1.0
    } else {
        1.0
    }
}

/// Round half away from zero without `std`.
pub(crate) fn round(x: f64) -> f64 {
    let t = x.abs() + 0.5;
    let i = if t < 4_503_599_627_370_496.0 {
        (t as u64) as f64
    } else {
        t
    };
    if x < 0.0 {
        -i
    } else {
        i
    }
}
