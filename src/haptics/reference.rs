//! A slow, independent reference minimiser of the proxy energy, for tests and validation only.
//!
//! It shares no code with the exact solver: each non-smooth distance term is replaced by a smooth convex
//! surrogate that is within `eps` of it everywhere (`sqrt(d^2 + eps^2) - eps` for points and lines,
//! `(sqrt(sigma^2 + eps^2) - sigma - eps) / 2` for planes), and the smooth problem is minimised by damped Newton
//! with a continuation `eps = 1e-2 ... 1e-13` m. Since the surrogate energy differs from `E` by at most
//! `N s_max eps`, strong convexity bounds the answer's distance to the true minimiser by
//! `sqrt(2 N s_max eps / k)`, returned as `error_bound_m` (a worst case; the real error is usually far smaller).

use crate::haptics::primitive::{Primitive, PrimitiveKind};
use glam::{DMat3, DVec3};

/// The reference answer and the worst-case bound on its distance from the true minimiser.
#[derive(Debug, Clone, Copy)]
pub struct ReferenceSolution {
    pub proxy_m: DVec3,
    pub error_bound_m: f64,
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

fn smoothed(
    k: f64,
    probe: DVec3,
    primitives: &[Primitive],
    x: DVec3,
    eps: f64,
) -> (f64, DVec3, DMat3) {
    let mut e = 0.5 * k * (x - probe).length_squared();
    let mut g = k * (x - probe);
    let mut h = DMat3::from_diagonal(DVec3::splat(k));
    for p in primitives {
        let s = p.strength_n();
        let q = p.direction();
        let r = x - p.position_m();
        match p.kind() {
            PrimitiveKind::Directed => {
                e -= s * q.dot(x);
                g -= s * q;
            }
            PrimitiveKind::Point | PrimitiveKind::Line => {
                let (v, proj) = if p.kind() == PrimitiveKind::Line {
                    (r - q * q.dot(r), DMat3::IDENTITY - outer(q, q))
                } else {
                    (r, DMat3::IDENTITY)
                };
                let root = (v.length_squared() + eps * eps).sqrt();
                e += s * (root - eps);
                g += s * v / root;
                h += (proj * (1.0 / root) - outer(v, v) * (1.0 / (root * root * root))) * s;
            }
            PrimitiveKind::Plane => {
                let sigma = q.dot(r);
                let root = (sigma * sigma + eps * eps).sqrt();
                e += 0.5 * s * (root - sigma - eps);
                g += 0.5 * s * (sigma / root - 1.0) * q;
                h += outer(q, q) * (0.5 * s * eps * eps / (root * root * root));
            }
        }
    }
    (e, g, h)
}

/// Minimises `E` for the given scene (see the module docs). Slow: hundreds of Newton steps.
pub fn minimise(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    primitives: &[Primitive],
) -> ReferenceSolution {
    let k = stiffness_n_per_m;
    let mut x = probe_m;
    let mut eps = 1e-2;
    let final_eps = 1e-13;
    loop {
        for _ in 0..200 {
            let (e0, g, h) = smoothed(k, probe_m, primitives, x, eps);
            let d = -(h.inverse() * g);
            if !d.is_finite() || d.length() < 1e-18 {
                break;
            }
            let mut t = 1.0;
            while smoothed(k, probe_m, primitives, x + t * d, eps).0 > e0 + 1e-4 * t * g.dot(d)
                && t > 1e-20
            {
                t *= 0.5;
            }
            x += t * d;
            if (t * d).length() < 1e-18 {
                break;
            }
        }
        if eps <= final_eps {
            break;
        }
        eps = (eps * 0.1).max(final_eps);
    }
    let n = primitives
        .iter()
        .filter(|p| p.kind() != PrimitiveKind::Directed)
        .count() as f64;
    let s_max = primitives
        .iter()
        .map(|p| p.strength_n())
        .fold(0.0, f64::max);
    ReferenceSolution {
        proxy_m: x,
        error_bound_m: (2.0 * n * s_max * final_eps / k).sqrt(),
    }
}
