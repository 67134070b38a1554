//! The exact zero-order-hold stability boundary of a sampled virtual spring on a mass-damper arm, computed
//! from first principles (not from the arm's integrator nor from any cap function): the expected value that
//! the simulated arm's tests and the stiffness sweep check the arm against. Test support only.
//!
//! The loop: a released hand (no hand spring), the arm `m x'' + b x' = F`, and a virtual spring sampled each
//! tick `F_n = -K x(nT)`, held over the tick and acting `d` ticks after it was sampled (latency `d T`).
//! Discretising the plant `1 / (s (m s + b))` under a zero-order hold gives (Gillespie and Cutkosky, "Stable
//! user-specific haptic rendering of the virtual wall", Proc. ASME IMECE DSC-58, 1996, eq. for the ZOH
//! equivalent; derivation: `(1 - z^-1) Z{G(s)/s}` with partial fractions)
//!
//! ```text
//! G(z) = (c1 z + c0) / (b (z - 1)(z - a)),   a = exp(-T b / m),  tau = m / b,
//! c1 = T - tau (1 - a),  c0 = tau (1 - a) - a T,
//! ```
//!
//! and the closed loop's characteristic polynomial `z^d (z - 1)(z - a) + (K / b)(c1 z + c0)`. Without latency
//! the Jury conditions give the boundary in closed form, `K* = b (1 - a) / c0` (the constant coefficient
//! reaching 1); with latency the boundary is found by bisection on a Schur-Cohn stability test of the
//! polynomial (Jury, "Theory and Application of the z-Transform Method", 1964).
//!
//! The library's [`super::zoh_boundary`] derives the same boundary another way (the arm integrated in the
//! state space, any fraction of a period of latency); this transfer-function form, whole periods only, is
//! kept as an independent check of it and as the expected value of the sweeps.

use super::bisect::geometric_bisection;
use super::zoh_boundary::schur_stable;

/// The exact ZOH boundary without latency (closed form).
pub fn exact_boundary_no_delay(m: f64, b: f64, t: f64) -> f64 {
    let a = (-t * b / m).exp();
    let tau = m / b;
    let c0 = tau * (1.0 - a) - a * t;
    b * (1.0 - a) / c0
}

/// The exact ZOH boundary with `d` ticks of latency: bisection on the characteristic polynomial.
pub fn exact_boundary(m: f64, b: f64, t: f64, d: usize) -> f64 {
    let a = (-t * b / m).exp();
    let tau = m / b;
    let c1 = t - tau * (1.0 - a);
    let c0 = tau * (1.0 - a) - a * t;
    let stable = |k: f64| {
        // z^d (z^2 - (1 + a) z + a) + (k / b)(c1 z + c0), highest degree first.
        let mut p = vec![0.0; d + 3];
        p[0] = 1.0;
        p[1] = -(1.0 + a);
        p[2] = a;
        p[d + 1] += k / b * c1;
        p[d + 2] += k / b * c0;
        schur_stable(&p)
    };
    geometric_bisection(1e-3, 1e9, 0.0, stable)
}
