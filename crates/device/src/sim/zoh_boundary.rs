//! The exact stability boundary of a sampled virtual spring on a mass-damper arm under a zero-order hold
//! ([`zoh_boundary`]): the largest coupling stiffness `K` at which the loop is still asymptotically stable,
//! for a mass `m`, viscous damping `b`, servo period `T` and a transport latency `tau` that need not be a
//! whole number of periods. `voxhap stability` prints it next to the passivity bound `b / (T/2 + tau)` that
//! voxhap caps stiffness at (crate::physics), and the simulated arm's measured boundary is checked against it.
//!
//! The loop: the arm `m x'' + b x' = F` (a released hand), a spring sampled each period `F_n = -K x(nT)`,
//! held over one period and starting to act `tau = (d + theta) T` after its sample (`d` whole periods,
//! `0 <= theta < 1`). Over period `n` the arm feels `F_{n-d-1}` for the first `theta T` and `F_{n-d}` for the
//! rest. Integrating the arm exactly over a span `h` under a constant force (`x = h b / m`):
//!
//! ```text
//! v(h) = e^{-x} v0 + beta(h) F,    x(h) = x0 + phi(h) v0 + gamma(h) F,
//! phi(h) = h (1 - e^{-x}) / x,     beta(h) = phi(h) / m,     gamma(h) = h^2 (x - 1 + e^{-x}) / (m x^2),
//! ```
//!
//! so that one period is `x_{n+1} = x_n + phi_T v_n + g1 F_{n-d-1} + g2 F_{n-d}`, `v_{n+1} = a v_n + h1
//! F_{n-d-1} + h2 F_{n-d}` with `a = e^{-T b / m}`, `g2 = gamma((1 - theta) T)`, `h2 = beta((1 - theta) T)`
//! (the newer force, over the end of the period), `g1 = gamma(theta T) + phi((1 - theta) T) beta(theta T)` and
//! `h1 = e^{-(1 - theta) T b / m} beta(theta T)` (the older force, over the start, then carried). With
//! `N_i(z) = g_i z + (phi_T h_i - a g_i)` the closed loop's characteristic polynomial is
//!
//! ```text
//! P(z) = z^{d+1} (z - 1)(z - a) + K (z N2(z) + N1(z)),
//! ```
//!
//! of degree `d + 3`. Without latency it is `z` times the zero-order-hold equivalent's (Gillespie and
//! Cutkosky, "Stable user-specific haptic rendering of the virtual wall", ASME IMECE DSC-58, 1996:
//! `(z - 1)(z - a) + (K / b)(c1 z + c0)`), whose boundary in closed form is `K* = b (1 - a) / c0`,
//! `c0 = tau_m (1 - a) - a T`; as `T -> 0` it tends to Colgate and Schenkel's `2 b / T` ("Passivity of a
//! class of sampled-data systems", J. Robotic Systems 14(1), 1997). Stability is decided by the Schur-Cohn
//! test (all roots strictly inside the unit circle; Jury, "Theory and Application of the z-Transform
//! Method", 1964), and the boundary found by bisection on `K` to a relative 1e-12.
//!
//! The functions (`phi`, `beta`, `gamma`) are written through `expm1` and a series near `x = 0`, so the
//! coefficients keep their precision for a lightly damped arm and a short period, and `b = 0` is allowed (the
//! undamped arm: no positive stiffness is stable, the boundary is 0).

use super::bisect::geometric_bisection;

/// The most whole periods of latency [`zoh_boundary`] accepts (the polynomial has this degree plus 3).
pub const MAX_LATENCY_PERIODS: f64 = 1000.0;

/// Why a boundary could not be computed: the figure given and what it must be.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum ZohError {
    /// A figure is not finite or outside its range.
    #[error("zero-order-hold boundary: {name} = {value} must be {requirement}")]
    Invalid {
        /// The figure's name and unit.
        name: &'static str,
        /// What was given.
        value: f64,
        /// What it must be.
        requirement: &'static str,
    },
    /// The latency is longer than [`MAX_LATENCY_PERIODS`] periods.
    #[error(
        "zero-order-hold boundary: latency {latency_s} s is {periods} periods of {period_s} s; at most \
         {MAX_LATENCY_PERIODS} are analysed"
    )]
    LatencyTooLong {
        /// The latency given, s.
        latency_s: f64,
        /// The period given, s.
        period_s: f64,
        /// Their ratio.
        periods: f64,
    },
}

/// A sampled spring's loop: the arm, the period and the latency.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZohLoop {
    /// Moving mass, kg (> 0).
    pub mass_kg: f64,
    /// Viscous damping, N s/m (>= 0).
    pub damping_n_s_per_m: f64,
    /// Servo period, s (> 0).
    pub period_s: f64,
    /// Transport latency from the sample to the force acting, s (>= 0, any fraction of a period).
    pub latency_s: f64,
}

fn check(
    name: &'static str,
    value: f64,
    ok: bool,
    requirement: &'static str,
) -> Result<(), ZohError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(ZohError::Invalid {
            name,
            value,
            requirement,
        })
    }
}

/// `(1 - e^{-x}) / x`, 1 at `x = 0`.
fn e1(x: f64) -> f64 {
    if x < 1e-8 {
        1.0 - x / 2.0
    } else {
        -(-x).exp_m1() / x
    }
}

/// `(x - 1 + e^{-x}) / x^2`, 1/2 at `x = 0` (a series below 1e-3, where the direct form cancels).
fn e2(x: f64) -> f64 {
    if x < 1e-3 {
        0.5 - x / 6.0 + x * x / 24.0 - x * x * x / 120.0
    } else {
        (x + (-x).exp_m1()) / (x * x)
    }
}

impl ZohLoop {
    /// Checks the figures; the error names the one that is wrong.
    pub fn validate(&self) -> Result<(), ZohError> {
        check(
            "mass (kg)",
            self.mass_kg,
            self.mass_kg > 0.0,
            "a finite number > 0",
        )?;
        check(
            "damping (N s/m)",
            self.damping_n_s_per_m,
            self.damping_n_s_per_m >= 0.0,
            "a finite number >= 0",
        )?;
        check(
            "period (s)",
            self.period_s,
            self.period_s > 0.0,
            "a finite number > 0",
        )?;
        check(
            "latency (s)",
            self.latency_s,
            self.latency_s >= 0.0,
            "a finite number >= 0",
        )?;
        let periods = self.latency_s / self.period_s;
        if periods > MAX_LATENCY_PERIODS || !periods.is_finite() {
            return Err(ZohError::LatencyTooLong {
                latency_s: self.latency_s,
                period_s: self.period_s,
                periods,
            });
        }
        Ok(())
    }

    /// The latency as whole periods `d` and a fraction `theta` in `[0, 1)`; a ratio within 1e-9 of a whole
    /// number is that number (0.001 s / 0.001 s is one period, not 0.999...).
    pub fn latency_periods(&self) -> (usize, f64) {
        let ratio = self.latency_s / self.period_s;
        let nearest = ratio.round();
        if (ratio - nearest).abs() <= 1e-9 * nearest.max(1.0) {
            (nearest as usize, 0.0)
        } else {
            (ratio.floor() as usize, ratio - ratio.floor())
        }
    }

    /// `phi(h)`, `beta(h)`, `gamma(h)` and `e^{-h b / m}` of the module's documentation.
    fn span(&self, h: f64) -> (f64, f64, f64, f64) {
        let x = h * self.damping_n_s_per_m / self.mass_kg;
        let phi = h * e1(x);
        (
            phi,
            phi / self.mass_kg,
            h * h * e2(x) / self.mass_kg,
            (-x).exp(),
        )
    }

    /// The closed loop's characteristic polynomial at stiffness `k`, highest degree first (degree `d + 3`).
    /// Call [`Self::validate`] first.
    pub fn characteristic_polynomial(&self, k: f64) -> Vec<f64> {
        let t = self.period_s;
        let (d, theta) = self.latency_periods();
        let (phi_t, _, _, a) = self.span(t);
        let (phi_late, beta_late, gamma_late, a_late) = self.span((1.0 - theta) * t);
        let (_, beta_early, gamma_early, _) = self.span(theta * t);
        let (g2, h2) = (gamma_late, beta_late);
        let (g1, h1) = (gamma_early + phi_late * beta_early, a_late * beta_early);
        let mut p = vec![0.0; d + 4];
        p[0] = 1.0;
        p[1] = -(1.0 + a);
        p[2] = a;
        // K (z N2(z) + N1(z)) = K (g2 z^2 + (phi_T h2 - a g2 + g1) z + (phi_T h1 - a g1)).
        p[d + 1] += k * g2;
        p[d + 2] += k * (phi_t * h2 - a * g2 + g1);
        p[d + 3] += k * (phi_t * h1 - a * g1);
        p
    }

    /// Is the loop asymptotically stable at stiffness `k` (every root of the characteristic polynomial
    /// strictly inside the unit circle)? Call [`Self::validate`] first.
    pub fn is_stable(&self, k: f64) -> bool {
        schur_stable(&self.characteristic_polynomial(k))
    }

    /// The passivity bound `b / (T/2 + tau)` (Colgate and Schenkel; the delay term as in Hulin,
    /// Albu-Schäffer and Hirzinger, IEEE TCST 2014), N/m.
    pub fn passivity_bound_n_per_m(&self) -> f64 {
        self.damping_n_s_per_m / (self.period_s / 2.0 + self.latency_s)
    }

    /// The exact boundary, N/m: the loop is stable for every stiffness below it and not just above it.
    pub fn boundary_n_per_m(&self) -> Result<f64, ZohError> {
        self.validate()?;
        if self.damping_n_s_per_m == 0.0 {
            return Ok(0.0);
        }
        // Bracket from the passivity bound, which lies within a few per cent of the boundary for the arms
        // of interest (and within a factor of a few for any): stable at `lo`, not at `hi`.
        let bound = self.passivity_bound_n_per_m();
        let (mut lo, mut hi) = (bound / 2.0, bound * 2.0);
        while !self.is_stable(lo) && lo > f64::MIN_POSITIVE * 1e10 {
            hi = lo;
            lo /= 2.0;
        }
        while self.is_stable(hi) && hi < f64::MAX / 4.0 {
            lo = hi;
            hi *= 2.0;
        }
        Ok(geometric_bisection(lo, hi, 1e-12, |k| self.is_stable(k)))
    }
}

/// The exact zero-order-hold stability boundary (N/m) of a sampled spring on an arm of `mass_kg` and
/// `damping_n_s_per_m`, at servo period `period_s`, with `latency_s` from sample to force (any fraction of a
/// period). See the module's documentation.
pub fn zoh_boundary(
    mass_kg: f64,
    damping_n_s_per_m: f64,
    period_s: f64,
    latency_s: f64,
) -> Result<f64, ZohError> {
    ZohLoop {
        mass_kg,
        damping_n_s_per_m,
        period_s,
        latency_s,
    }
    .boundary_n_per_m()
}

/// Schur-Cohn: are all roots of `p` (coefficients, highest degree first, `p[0] != 0`) strictly inside the
/// unit circle? Each step replaces `p` by `(p_0 p(z) - p_n p*(z)) / z` (`p*` the reversed polynomial), of one
/// degree less and with the same number of roots inside the circle, while `|p_0| > |p_n|`.
pub fn schur_stable(p: &[f64]) -> bool {
    let mut p = p.to_vec();
    while p.len() > 1 {
        let n = p.len() - 1;
        let (lead, last) = (p[0], p[n]);
        // NaN coefficients compare as unordered: not stable.
        if lead.abs().partial_cmp(&last.abs()) != Some(std::cmp::Ordering::Greater) {
            return false;
        }
        p = (0..n).map(|i| lead * p[i] - last * p[n - i]).collect();
        // Scale to a largest coefficient of 1 (the roots do not change), so that a long latency's many
        // steps neither overflow nor underflow.
        let scale = p.iter().fold(0.0f64, |m, c| m.max(c.abs()));
        if !(scale > 0.0 && scale.is_finite()) {
            return false;
        }
        p.iter_mut().for_each(|c| *c /= scale);
    }
    true
}

#[cfg(test)]
#[path = "zoh_boundary_tests.rs"]
mod tests;
