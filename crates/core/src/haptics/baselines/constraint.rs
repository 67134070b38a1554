//! The constraint approach (Lundin et al. 2005, section 2, eq. 1-2), kept to show the artifact the haptic
//! primitives remove.
//!
//! Each constraint moves the proxy separately, and the movements are added. With `d = probe - proxy` the
//! displacement the coupling asks for, constraint `i` looks only at the part of `d` in its own constrained
//! subspace `S_i` (the normal of a plane, the plane orthogonal to a line, all of space for a point) and lets the
//! proxy move that part minus what its strength holds back:
//!
//! ```text
//!     dx_i = P_i d - clamp(|P_i d|, 0, s_i/k) P_i d/|P_i d|      (a plane only resists motion into it)
//!     dx   = (I - P_span) d + sum_i dx_i + sum_directed s q / k
//! ```
//!
//! where `P_span` projects onto the span of all constrained subspaces, so free directions are moved once.
//! When the constrained directions are mutually orthogonal, `sum_i P_i d = P_span d` and this is the proxy
//! method exactly. When they are not, `sum_i P_i` is not a projector (paper eq. 7): two zero-strength planes
//! at an angle, which should not constrain anything, leave the proxy short of the probe (or past it). The
//! tests reproduce this (Figure 2).

use super::BaselineSolution;
use crate::haptics::primitive::{resultant_force_n, Primitive, PrimitiveKind};
use glam::{DMat3, DVec3};
use voxhap_solver::linalg::{outer, psd_pseudo_inverse};

fn constrained_projector(p: &Primitive) -> DMat3 {
    let q = p.direction();
    match p.kind() {
        PrimitiveKind::Point => DMat3::IDENTITY,
        PrimitiveKind::Line => DMat3::IDENTITY - outer(q, q),
        PrimitiveKind::Plane => outer(q, q),
        PrimitiveKind::Directed => DMat3::ZERO,
    }
}

/// One update of the constraint approach from the previous proxy position.
pub fn solve(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    previous_proxy_m: DVec3,
    primitives: &[Primitive],
) -> BaselineSolution {
    let k = stiffness_n_per_m;
    let d = probe_m - previous_proxy_m;
    let mut span = DMat3::ZERO;
    let mut moved = DVec3::ZERO;
    for p in primitives {
        if p.kind() == PrimitiveKind::Directed {
            moved += p.strength_n() * p.direction() / k;
            continue;
        }
        let projector = constrained_projector(p);
        span += projector;
        let part = projector * d;
        let length = part.length();
        let resisting = p.kind() != PrimitiveKind::Plane || part.dot(p.direction()) < 0.0;
        moved += if resisting && length > 0.0 {
            part * ((length - p.strength_n() / k).max(0.0) / length)
        } else {
            part
        };
    }
    let (_, free, _) = psd_pseudo_inverse(span, 1e-12);
    let proxy = previous_proxy_m + free * d + moved;
    BaselineSolution {
        proxy_m: proxy,
        force_n: k * (proxy - probe_m),
        iterations: 1,
        residual_n: resultant_force_n(k, probe_m, primitives, proxy).length(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orthogonal_constraints_match_the_proxy_method() {
        let k = 500.0;
        // A plane (2 N) and a perpendicular plane (1 N): probe pushed 1 mm into the first, 4 mm into the second.
        let prims = [
            Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap(),
            Primitive::plane(DVec3::ZERO, DVec3::X, 1.0).unwrap(),
        ];
        let probe = DVec3::new(-0.004, 0.01, -0.001);
        let sol = solve(k, probe, DVec3::ZERO, &prims);
        // z: 0.5 N < 2 N holds (proxy stays at 0); x: 2 N > 1 N yields to -0.004 + 1/k = -0.002; y free.
        assert!(
            (sol.proxy_m - DVec3::new(-0.002, 0.01, 0.0)).length() < 1e-15,
            "{sol:?}"
        );
    }

    #[test]
    fn moving_away_from_a_plane_is_free() {
        let prims = [Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap()];
        let probe = DVec3::new(0.0, 0.0, 0.01);
        let sol = solve(500.0, probe, DVec3::ZERO, &prims);
        assert!((sol.proxy_m - probe).length() < 1e-15);
    }
}
