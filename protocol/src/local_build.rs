//! The host's side of the local-model capability: one [`LocalModel`] from SI primitives (SPEC section 10.3).
//!
//! Where it sits: the host's device driver calls [`build_local_model`] with the tick's primitives; the result is
//! encoded like any other [`crate::HostToDevice`] message. No allocation: the nearest primitives are kept in a
//! fixed array while the input is scanned once.
//!
//! The rules, each a SPEC requirement: directed forces are summed into one slot (the solver only ever uses their
//! sum); a line or plane travels as its point closest to the anchor (the same set, so nothing is lost but the 1 µm
//! rounding); the slots are filled nearest to the anchor first; a primitive that does not fit (no slot left, or its
//! point beyond the ±32.767 mm offset range) is dropped and the model carries [`ModelFlags::TRUNCATED`]; a value
//! above its field's range is sent as the largest one and the model carries [`ModelFlags::SATURATED`].

use crate::local::{
    oct_encode, round, LocalKind, LocalModel, LocalPassivity, LocalPrimitive, ModelFlags,
    SiPrimitive, DAMPING_UNIT_N_S_PER_M, FORCE_UNIT_N, MAX_EXPIRY_US, MAX_LOCAL_PRIMITIVES,
    MIN_EXPIRY_US, OFFSET_UNIT_M,
};
use crate::num::sqrt;

/// The coupling and timing of a model, SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalModelParams {
    /// The message's sequence number (shared with set-force).
    pub sequence: u32,
    /// Render for this long after receipt, microseconds, 1000..=50000.
    pub expiry_us: u16,
    /// Coupling stiffness, N/m, >= 1 (sent rounded to 1 N/m, at most 65535).
    pub stiffness_n_per_m: f64,
    /// Coupling damping, N·s/m, >= 0.
    pub damping_n_s_per_m: f64,
    /// Force limit, N, >= 0.
    pub force_limit_n: f64,
    /// The offsets' origin (usually the host's proxy), metres, device frame.
    pub anchor_m: [f64; 3],
    /// What the device's passivity observer and controller do (SPEC 10.5 step 4b).
    pub passivity: LocalPassivity,
}

/// Why a model could not be built: a value no model can carry.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum LocalBuildError {
    /// A parameter is not finite or out of its range.
    #[error("local model: {field} = {value} is out of range ({range})")]
    Parameter {
        /// The parameter's name.
        field: &'static str,
        /// What was given.
        value: f64,
        /// The accepted range.
        range: &'static str,
    },
    /// A primitive has a non-finite field, a negative strength or a zero direction.
    #[error("local model: primitive {index} has a non-finite value, a negative strength or a zero direction")]
    Primitive {
        /// Its index in the input.
        index: usize,
    },
}

fn check(
    field: &'static str,
    value: f64,
    ok: bool,
    range: &'static str,
) -> Result<(), LocalBuildError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(LocalBuildError::Parameter {
            field,
            value,
            range,
        })
    }
}

/// Rounds `value / unit` to a u16, saturating; the flag says whether it saturated.
fn fixed_u16(value: f64, unit: f64) -> (u16, bool) {
    let units = round(value / unit);
    if units > f64::from(u16::MAX) {
        (u16::MAX, true)
    } else {
        (units.max(0.0) as u16, false)
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = sqrt(dot(v, v));
    (n.is_finite() && n > 0.0).then(|| v.map(|c| c / n))
}

/// A candidate slot with its distance to the anchor.
#[derive(Clone, Copy)]
struct Candidate {
    distance_m: f64,
    slot: LocalPrimitive,
}

/// Builds the model: parameters checked, directed forces summed, the rest nearest first (SPEC section 10.3).
pub fn build_local_model(
    params: &LocalModelParams,
    primitives: &[SiPrimitive],
) -> Result<LocalModel, LocalBuildError> {
    check(
        "expiry_us",
        f64::from(params.expiry_us),
        (MIN_EXPIRY_US..=MAX_EXPIRY_US).contains(&params.expiry_us),
        "1000..=50000 us",
    )?;
    let k = params.stiffness_n_per_m;
    check("stiffness_n_per_m", k, k >= 1.0, ">= 1 N/m")?;
    let b = params.damping_n_s_per_m;
    check("damping_n_s_per_m", b, b >= 0.0, ">= 0 N s/m")?;
    let limit = params.force_limit_n;
    check("force_limit_n", limit, limit >= 0.0, ">= 0 N")?;
    for (i, c) in params.anchor_m.iter().enumerate() {
        // Sent as f32: finite there too.
        let name = ["anchor_m.x", "anchor_m.y", "anchor_m.z"][i];
        check(name, *c, (*c as f32).is_finite(), "finite as an f32")?;
    }
    let mut saturated = false;
    let mut fixed = |value, unit| {
        let (v, s) = fixed_u16(value, unit);
        saturated |= s;
        v
    };
    let stiffness_n_per_m = fixed(k, 1.0);
    let damping_mn_s_per_m = fixed(b, DAMPING_UNIT_N_S_PER_M);
    let force_limit_mn = fixed(limit, FORCE_UNIT_N);
    let anchor_f32 = params.anchor_m.map(|c| c as f32);
    let anchor = anchor_f32.map(f64::from);

    let mut directed = [0.0f64; 3];
    let mut has_directed = false;
    let mut kept = [None::<Candidate>; MAX_LOCAL_PRIMITIVES];
    let mut truncated = false;
    for (index, p) in primitives.iter().enumerate() {
        let finite = p
            .position_m
            .iter()
            .chain(&p.direction)
            .all(|c| c.is_finite());
        if !finite || !p.strength_n.is_finite() || p.strength_n < 0.0 {
            return Err(LocalBuildError::Primitive { index });
        }
        let q = match p.kind {
            LocalKind::Point => [0.0; 3],
            _ => unit(p.direction).ok_or(LocalBuildError::Primitive { index })?,
        };
        let r = core::array::from_fn::<f64, 3, _>(|i| anchor[i] - p.position_m[i]);
        let (point, distance_m) = match p.kind {
            LocalKind::Directed => {
                has_directed = true;
                (0..3).for_each(|i| directed[i] += p.strength_n * q[i]);
                continue;
            }
            LocalKind::Point => (p.position_m, sqrt(dot(r, r))),
            LocalKind::Line => {
                let t = dot(r, q);
                let c = core::array::from_fn(|i| p.position_m[i] + t * q[i]);
                let d = core::array::from_fn::<f64, 3, _>(|i| anchor[i] - c[i]);
                (c, sqrt(dot(d, d)))
            }
            LocalKind::Plane => {
                let t = dot(r, q);
                (core::array::from_fn(|i| anchor[i] - t * q[i]), t.abs())
            }
        };
        let mut offset_um = [0i16; 3];
        let mut in_range = true;
        for i in 0..3 {
            let units = round((point[i] - anchor[i]) / OFFSET_UNIT_M);
            in_range &= units.abs() <= 32_767.0;
            offset_um[i] = units.clamp(-32_767.0, 32_767.0) as i16;
        }
        if !in_range {
            truncated = true;
            continue;
        }
        let slot = LocalPrimitive {
            kind: p.kind,
            offset_um,
            direction_oct: if p.kind == LocalKind::Point {
                [0; 2]
            } else {
                oct_encode(q).unwrap_or([0; 2])
            },
            strength_mn: fixed(p.strength_n, FORCE_UNIT_N),
        };
        truncated |= insert_nearest(&mut kept, Candidate { distance_m, slot });
    }

    let mut slots = [None; MAX_LOCAL_PRIMITIVES];
    let mut next = 0;
    let directed_strength = sqrt(dot(directed, directed));
    if has_directed && directed_strength > 0.0 {
        let (strength_mn, s) = fixed_u16(directed_strength, FORCE_UNIT_N);
        saturated |= s;
        slots[0] = oct_encode(directed).map(|direction_oct| LocalPrimitive {
            kind: LocalKind::Directed,
            offset_um: [0; 3],
            direction_oct,
            strength_mn,
        });
        next = 1;
        // The directed slot took the last place: the farthest kept primitive is dropped.
        truncated |= kept[MAX_LOCAL_PRIMITIVES - 1].is_some();
    }
    for candidate in kept.iter().flatten().take(MAX_LOCAL_PRIMITIVES - next) {
        slots[next] = Some(candidate.slot);
        next += 1;
    }
    let flags = ModelFlags::EMPTY
        .with(ModelFlags::TRUNCATED, truncated)
        .with(ModelFlags::SATURATED, saturated);
    Ok(LocalModel {
        sequence: params.sequence,
        expiry_us: params.expiry_us,
        flags,
        passivity: params.passivity,
        stiffness_n_per_m,
        damping_mn_s_per_m,
        force_limit_mn,
        anchor_m: anchor_f32,
        primitives: slots,
    })
}

/// Inserts `candidate` into `kept` (sorted nearest first, ties keep input order); true if one was dropped.
fn insert_nearest(
    kept: &mut [Option<Candidate>; MAX_LOCAL_PRIMITIVES],
    candidate: Candidate,
) -> bool {
    let position = kept
        .iter()
        .position(|k| k.is_none_or(|k| candidate.distance_m < k.distance_m));
    let Some(position) = position else {
        return true;
    };
    let dropped = kept[MAX_LOCAL_PRIMITIVES - 1].is_some();
    for i in (position + 1..MAX_LOCAL_PRIMITIVES).rev() {
        kept[i] = kept[i - 1];
    }
    kept[position] = Some(candidate);
    dropped
}
