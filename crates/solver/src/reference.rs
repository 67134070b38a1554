//! A slow, independent reference minimiser of the proxy energy in double-double arithmetic (about 32 digits),
//! for tests and validation only: it checks the exact solver's certificate at the precision the certificate
//! reports (down to 1e-16 m), which an f64 reference cannot.
//!
//! It shares no code with the exact solver. Each non-smooth distance term is replaced by a smooth convex
//! surrogate within `eps` of it everywhere (`s (sqrt(d^2 + eps^2) - eps)` for points and lines,
//! `s (sqrt(sigma^2 + eps^2) - sigma - eps) / 2` for planes), and the smooth problem is minimised by damped Newton
//! in double-double ([`twofloat`]) with a continuation `eps = 1e-2 ... 1e-32` m. The surrogate energy lies
//! within `N s_max eps` below `E`, so its minimiser is within `sqrt(2 N s_max eps / k)` of the true one (a
//! proof); the distance to the smoothed minimiser adds the smaller of `|g| / k` (a proof, from strong convexity)
//! and the length of the Newton step at the answer (an estimate: Newton converges quadratically there, and at a
//! kink the gradient of a surrogate 1e-32 m wide cannot be resolved, while the step can). Their sum is
//! `error_bound_m`, about 1e-16 m for most test scenes. A proxy held on a kink is the hard case: the Hessian's
//! condition number there nears 1e30. So the line's direction is projected out twice (with one projection, a
//! proxy on a line was left up to 4e-8 m off along it while the estimate said 2e-8 m; found by
//! `solver_props::primal_newton_agrees_with_the_dual_method`, kept in its regression file), and the answer is
//! finished by Newton steps along the face of the kinks it sits on, with those terms left out
//! ([`polish_on_face`]; without it a proxy on a tilted plane was left 2.8e-16 m off along it, and one on a line
//! 1.35e-13 m, while the estimate said about 1e-17 m; both kept in the regression file). Quotients go through
//! [`div`], one Newton step past `twofloat`'s division, which is only about f64-accurate: with it, a unit
//! direction was unit only to 1e-17, and a face basis built by Gram-Schmidt was off by 3.5e-13, which left a
//! proxy on a line 1.1e-15 m off along it.
//!
//! The inputs (probe, positions, directions, strengths) are taken as exact: they are the f64 values the solver
//! sees, so the reference answers the same problem.

use crate::primitive::{Primitive, PrimitiveKind};
use glam::DVec3;
use twofloat::TwoFloat;

type D = TwoFloat;

/// The reference answer and the worst-case bound on its distance from the true minimiser.
#[derive(Debug, Clone, Copy)]
pub struct ReferenceSolution {
    /// The answer rounded to f64 (the nearest f64 to the double-double answer, per coordinate).
    pub proxy_m: DVec3,
    /// The answer in double-double.
    pub proxy_dd_m: [TwoFloat; 3],
    pub error_bound_m: f64,
}

impl ReferenceSolution {
    /// The distance from `x` to the reference answer, computed in double-double (so an f64 answer's error is
    /// measured, not the rounding of the reference).
    pub fn distance_m(&self, x: DVec3) -> f64 {
        let d = sub(from_vec(x), self.proxy_dd_m);
        f64::from(dot(d, d).sqrt())
    }
}

type V = [D; 3];

fn d(x: f64) -> D {
    D::from(x)
}

/// `a / b` to double-double precision: `twofloat`'s quotient is only about f64-accurate (1 / sqrt(2) was off by
/// 2e-17), so one Newton step refines it (the residual `a - q b` is exact enough in double-double).
fn div(a: D, b: D) -> D {
    let q = a / b;
    q + (a - q * b) / b
}

fn from_vec(v: DVec3) -> V {
    [d(v.x), d(v.y), d(v.z)]
}

fn add(a: V, b: V) -> V {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: V, s: D) -> V {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn dot(a: V, b: V) -> D {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

type M = [[D; 3]; 3];

fn zero3() -> M {
    [[d(0.0); 3]; 3]
}

/// `m += c (P - w w^T / |w|^2-ish)` helpers: adds `c * a b^T`.
fn add_outer(m: &mut M, a: V, b: V, c: D) {
    for (row, ai) in m.iter_mut().zip(a) {
        for (entry, bj) in row.iter_mut().zip(b) {
            *entry += c * ai * bj;
        }
    }
}

/// Solves `m x = b` by Gaussian elimination with partial pivoting; `None` if singular.
fn solve3(mut m: M, mut b: V) -> Option<V> {
    for col in 0..3 {
        let pivot = (col..3).max_by(|&i, &j| {
            f64::from(m[i][col].abs())
                .partial_cmp(&f64::from(m[j][col].abs()))
                .unwrap_or(std::cmp::Ordering::Equal)
        })?;
        if f64::from(m[pivot][col]) == 0.0 {
            return None;
        }
        m.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..3 {
            let factor = div(m[row][col], m[col][col]);
            let pivot_row = m[col];
            for (entry, v) in m[row].iter_mut().zip(pivot_row).skip(col) {
                *entry -= factor * v;
            }
            let v = b[col];
            b[row] -= factor * v;
        }
    }
    let mut x = [d(0.0); 3];
    for row in (0..3).rev() {
        let mut acc = b[row];
        for c in row + 1..3 {
            acc -= m[row][c] * x[c];
        }
        x[row] = div(acc, m[row][row]);
    }
    Some(x)
}

/// One primitive in double-double.
struct Term {
    kind: PrimitiveKind,
    position: V,
    direction: V,
    strength: D,
}

/// The smoothed energy, its gradient and (when asked) its Hessian at `x`.
fn smoothed(k: D, y: V, terms: &[Term], x: V, eps: D, hessian: bool) -> (D, V, M) {
    smoothed_without(k, y, terms, x, eps, hessian, &[])
}

/// [`smoothed`] with the terms whose index `skip` marks `true` left out.
fn smoothed_without(
    k: D,
    y: V,
    terms: &[Term],
    x: V,
    eps: D,
    hessian: bool,
    skip: &[bool],
) -> (D, V, M) {
    let r0 = sub(x, y);
    let mut e = k * dot(r0, r0) / 2.0;
    let mut g = scale(r0, k);
    let mut h = zero3();
    if hessian {
        for (i, row) in h.iter_mut().enumerate() {
            row[i] = k;
        }
    }
    let eps2 = eps * eps;
    for (i, t) in terms.iter().enumerate() {
        if skip.get(i).copied().unwrap_or(false) {
            continue;
        }
        let s = t.strength;
        let q = t.direction;
        let r = sub(x, t.position);
        match t.kind {
            PrimitiveKind::Directed => {}
            PrimitiveKind::Point | PrimitiveKind::Line => {
                let v = if t.kind == PrimitiveKind::Line {
                    // Projected twice: one projection leaves a component along the line of about 1e-32 |r|,
                    // which the s / eps gain of a proxy held on the line turns into a force along it of about
                    // 1e-4 N and an error along the line of about 1e-13 m; the second removes it to u^2.
                    let v = sub(r, scale(q, dot(q, r)));
                    sub(v, scale(q, dot(q, v)))
                } else {
                    r
                };
                let root = (dot(v, v) + eps2).sqrt();
                e += s * (root - eps);
                g = add(g, scale(v, div(s, root)));
                if hessian {
                    // s (P / root - v v^T / root^3), P = I (point) or I - q q^T (line).
                    let c = div(s, root);
                    for (i, row) in h.iter_mut().enumerate() {
                        row[i] += c;
                    }
                    if t.kind == PrimitiveKind::Line {
                        add_outer(&mut h, q, q, -c);
                    }
                    add_outer(&mut h, v, v, -(s / (root * root * root)));
                }
            }
            PrimitiveKind::Plane => {
                let sigma = dot(q, r);
                let root = (sigma * sigma + eps2).sqrt();
                e += s * (root - sigma - eps) / 2.0;
                g = add(g, scale(q, s * (div(sigma, root) - 1.0) / 2.0));
                if hessian {
                    add_outer(&mut h, q, q, s * eps2 / (root * root * root * 2.0));
                }
            }
        }
    }
    (e, g, h)
}

/// Minimises `E` for the given scene (see the module docs). Slow: hundreds of double-double Newton steps.
pub fn minimise(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    primitives: &[Primitive],
) -> ReferenceSolution {
    let k = d(stiffness_n_per_m);
    // y = probe + (sum of directed forces) / k, exactly enough.
    let mut y = from_vec(probe_m);
    let mut terms = Vec::with_capacity(primitives.len());
    for p in primitives {
        // The stored direction is unit only to an ulp; normalised in double-double, so that `I - q q^T` is a
        // projector to 32 digits (else the s/eps curvature across a line leaks into the direction along it).
        let q = from_vec(p.direction());
        let length = dot(q, q).sqrt();
        let q = if f64::from(length) > 0.0 {
            scale(q, div(d(1.0), length))
        } else {
            q
        };
        let s = d(p.strength_n());
        if p.kind() == PrimitiveKind::Directed {
            y = add(y, scale(q, div(s, k)));
        } else {
            terms.push(Term {
                kind: p.kind(),
                position: from_vec(p.position_m()),
                direction: q,
                strength: s,
            });
        }
    }
    let mut x = y;
    let final_eps = 1e-32;
    let mut eps = 1e-2;
    loop {
        let eps_d = d(eps);
        for _ in 0..200 {
            let (e0, g, h) = smoothed(k, y, &terms, x, eps_d, true);
            let Some(step) = solve3(h, scale(g, d(-1.0))) else {
                break;
            };
            let slope = dot(g, step);
            if f64::from(slope) >= 0.0 {
                break;
            }
            let mut t = d(1.0);
            let mut accepted = false;
            for _ in 0..80 {
                let candidate = add(x, scale(step, t));
                let (e1, _, _) = smoothed(k, y, &terms, candidate, eps_d, false);
                if e1 <= e0 + slope * t * 1e-4 {
                    x = candidate;
                    accepted = true;
                    break;
                }
                t /= 2.0;
            }
            let full_step = f64::from(dot(step, step).sqrt());
            let moved = full_step * f64::from(t);
            // Intermediate levels only need a start for the next one (judged by the full Newton step, not by a
            // step the line search shortened); the last goes to double-double precision.
            let enough = if eps > final_eps { 1e-3 * eps } else { 1e-36 };
            if !accepted || full_step < enough || moved < 1e-36 {
                break;
            }
        }
        if eps <= final_eps {
            break;
        }
        eps = (eps * 0.01).max(final_eps);
    }
    let (x, face_step_m) = polish_on_face(k, y, &terms, x, d(final_eps));
    // The distance to the smoothed minimiser, estimated by the Newton step at the answer (Newton converges
    // quadratically there). `|g| / k` would be a proof, but at a kink the gradient of a surrogate 1e-32 m wide
    // cannot be resolved from a position known to 1e-34 m, while the step (the gradient over a Hessian of
    // s / eps) can.
    let (_, g, h) = smoothed(k, y, &terms, x, d(final_eps), true);
    let newton_m = solve3(h, scale(g, d(-1.0)))
        .map_or(f64::INFINITY, |step| f64::from(dot(step, step).sqrt()));
    let gradient_norm = (f64::from(dot(g, g).sqrt()) / stiffness_n_per_m).min(newton_m);
    let n = terms.len() as f64;
    let s_max = terms
        .iter()
        .map(|t| f64::from(t.strength))
        .fold(0.0, f64::max);
    ReferenceSolution {
        proxy_m: DVec3::new(
            x[0].hi() + x[0].lo(),
            x[1].hi() + x[1].lo(),
            x[2].hi() + x[2].lo(),
        ),
        proxy_dd_m: x,
        error_bound_m: (2.0 * n * s_max * final_eps / stiffness_n_per_m).sqrt()
            + gradient_norm
            + face_step_m,
    }
}

/// Within this distance of its kink set (m) a term counts as on it when the answer is polished.
const ON_KINK_M: f64 = 1e-24;

/// Polishes the answer along the face of the kinks it sits on: Newton steps restricted to the directions along
/// every kink set within [`ON_KINK_M`] of `x`, with those terms left out (they are constant along the face).
///
/// Why: at a kink the full Hessian has a curvature of `s / eps` (1e31 for `eps = 1e-32`) across the kink and
/// about `k` along it, and double-double (32 digits) cannot solve that system to better than about one part in
/// ten along the face, so the line search stalls short of the minimiser along the face. Found by
/// `solver_props::the_bound_holds_on_a_plane_with_friction_tick_after_tick`: a proxy held on a tilted plane with a
/// friction point pulling at full strength was left 2.8e-16 m off along the plane while the estimate said
/// 9e-18 m (a 60-digit minimisation on the plane agreed with the exact solver to 3.7e-19 m). On the face the
/// system is as well conditioned as `k`. Returns the polished point and the length of its last Newton step,
/// which the caller adds to the bound.
fn polish_on_face(k: D, y: V, terms: &[Term], x: V, eps: D) -> (V, f64) {
    let mut on_kink = vec![false; terms.len()];
    let mut normals: Vec<V> = Vec::new();
    let unit = |j: usize| {
        let mut e = [d(0.0); 3];
        e[j] = d(1.0);
        e
    };
    for (i, t) in terms.iter().enumerate() {
        let r = sub(x, t.position);
        let q = t.direction;
        match t.kind {
            PrimitiveKind::Plane => {
                if f64::from(dot(q, r).abs()) <= ON_KINK_M {
                    on_kink[i] = true;
                    normals.push(q);
                }
            }
            PrimitiveKind::Line => {
                let v = sub(r, scale(q, dot(q, r)));
                let v = sub(v, scale(q, dot(q, v)));
                if f64::from(dot(v, v).sqrt()) <= ON_KINK_M {
                    on_kink[i] = true;
                    for j in 0..3 {
                        normals.push(sub(unit(j), scale(q, q[j])));
                    }
                }
            }
            PrimitiveKind::Point => {
                if f64::from(dot(r, r).sqrt()) <= ON_KINK_M {
                    // Held on a point: there is no face to move along.
                    return (x, 0.0);
                }
            }
            PrimitiveKind::Directed => {}
        }
    }
    if normals.is_empty() {
        return (x, 0.0);
    }
    // Orthonormal bases of the kinks' normal space and of the face (Gram-Schmidt in double-double, twice).
    let orthonormalise = |candidates: &[V], against: &[V]| {
        let mut basis: Vec<V> = Vec::new();
        for &c in candidates {
            let mut w = c;
            for _ in 0..2 {
                for &b in against.iter().chain(basis.iter()) {
                    w = sub(w, scale(b, dot(b, w)));
                }
            }
            let length = dot(w, w).sqrt();
            if f64::from(length) > 1e-6 {
                basis.push(scale(w, div(d(1.0), length)));
            }
        }
        basis
    };
    let normal_basis = orthonormalise(&normals, &[]);
    let face = orthonormalise(&[unit(0), unit(1), unit(2)], &normal_basis);
    if face.is_empty() {
        return (x, 0.0);
    }
    let mut x = x;
    let mut last_step_m = 0.0;
    for _ in 0..100 {
        let (e0, g, h) = smoothed_without(k, y, terms, x, eps, true, &on_kink);
        // The reduced system on the face, padded to 3x3 with the identity.
        let mut reduced = zero3();
        let mut rhs = [d(0.0); 3];
        for (a, row) in reduced.iter_mut().enumerate() {
            if a >= face.len() {
                row[a] = d(1.0);
                continue;
            }
            rhs[a] = -dot(face[a], g);
            let h_face_a = [dot(h[0], face[a]), dot(h[1], face[a]), dot(h[2], face[a])];
            for (b, entry) in row.iter_mut().enumerate().take(face.len()) {
                *entry = dot(face[b], h_face_a);
            }
        }
        let Some(coefficients) = solve3(reduced, rhs) else {
            break;
        };
        let mut step = [d(0.0); 3];
        for (a, &f) in face.iter().enumerate() {
            step = add(step, scale(f, coefficients[a]));
        }
        let slope = dot(g, step);
        last_step_m = f64::from(dot(step, step).sqrt());
        if last_step_m < 1e-36 || f64::from(slope) >= 0.0 {
            break;
        }
        let mut t = d(1.0);
        let mut accepted = false;
        for _ in 0..60 {
            let candidate = add(x, scale(step, t));
            let (e1, _, _) = smoothed_without(k, y, terms, candidate, eps, false, &on_kink);
            if e1 <= e0 + slope * t * 1e-4 {
                x = candidate;
                accepted = true;
                break;
            }
            t /= 2.0;
        }
        if !accepted {
            break;
        }
    }
    (x, last_step_m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_pull_is_exact_to_double_double() {
        // k |probe - point| = 5 N > 2 N: the proxy sits s/k = 4 mm back from the probe, at 6 mm.
        let prims = [Primitive::point(DVec3::ZERO, 2.0).unwrap()];
        let r = minimise(500.0, DVec3::new(0.01, 0.0, 0.0), &prims);
        assert!(r.distance_m(DVec3::new(0.006, 0.0, 0.0)) < 1e-18, "{r:?}");
        assert!(r.error_bound_m < 1e-15, "{r:?}");
    }

    #[test]
    fn a_plane_holds_the_proxy_on_it() {
        let prims = [Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap()];
        let r = minimise(500.0, DVec3::new(0.001, 0.0, -0.001), &prims);
        assert!(r.distance_m(DVec3::new(0.001, 0.0, 0.0)) < 1e-18, "{r:?}");
    }
}

#[cfg(test)]
mod line_tests {
    use super::*;

    /// The proptest case that showed the limit of the reference on lines (see the assertion).
    #[test]
    fn a_line_holds_the_proxy_on_it() {
        let c = DVec3::new(
            0.0047615812250803285,
            0.009609350950524873,
            -0.0036396194766135713,
        );
        let q = DVec3::new(0.01749732092783369, 0.0, 0.999846910161925);
        let line = Primitive::line(c, q, 0.7879670196213837).unwrap();
        let probe = DVec3::new(0.00978283177796656, 0.009772311952979033, 0.0);
        let r = minimise(130.55073930990358, probe, &[line]);
        let qd = from_vec(line.direction());
        let qd = scale(qd, d(1.0) / dot(qd, qd).sqrt());
        let rel = sub(from_vec(probe), from_vec(c));
        let expected = add(from_vec(c), scale(qd, dot(qd, rel)));
        let e = sub(r.proxy_dd_m, expected);
        let error = f64::from(dot(e, e).sqrt());
        // Across a line the Hessian's condition number nears 1e30, which leaves the position along the line
        // converged to about 1e-14 m only; the reference's bound says so.
        assert!(
            error <= r.error_bound_m && r.error_bound_m < 1e-12,
            "{error:e} {r:?}"
        );
    }
}
