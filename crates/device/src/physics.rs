//! A device's physical figures ([`DevicePhysics`]: damping, latency, position resolution, Coulomb friction)
//! and the coupling caps that follow from them at a servo rate.
//!
//! Where it sits: beside `safety::CouplingCaps`, which caps a device by the stiffness it declares at 1 kHz.
//! Where the physics is known (the simulated arm's `[arm]` table, or a driver's measured figures) the caps
//! come from it instead:
//!
//! - **Stiffness.** A sampled virtual spring `K` with transport latency `tau` on a device with viscous damping
//!   `b`, held over the period `T`, is passive when `b > K (T/2 + tau)` (Colgate and Schenkel, "Passivity of
//!   a class of sampled-data systems", J. Robotic Systems 14(1), 1997, for `tau = 0`; the delay term as in
//!   Hulin, Albu-Schäffer and Hirzinger, IEEE TCST 2014), so `K_max = b / (T/2 + tau)`. With Coulomb friction
//!   `f_c` and position resolution `Delta`, Abbott and Okamura (IEEE T-RO 21(5), 2005) add `K <= 2 f_c / Delta`
//!   (limit cycles from quantisation); the cap is the smaller of the two. A faster loop raises the first.
//! - **Damping.** What the spring leaves of the device's damping: `B_max = b - K (T/2 + tau)`.
//!
//! For the released simulated arm these bounds sit just inside the exact zero-order-hold boundary (at 1 kHz,
//! 0.1 kg, 1 N s/m: 2 000 N/m against 2 003; with 1 ms latency 667 against 668), which
//! `sim::boundary_tests` checks against its own analysis.

/// What a device is physically, as far as it is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DevicePhysics {
    /// Viscous damping at the handle (N s/m).
    pub damping_n_s_per_m: f64,
    /// Time from a force being computed to it acting (s).
    pub latency_s: f64,
    /// Position resolution (m); 0 when unknown or continuous.
    pub position_resolution_m: f64,
    /// Coulomb friction at the handle (N); 0 when unknown (then the quantisation bound is not applied).
    pub coulomb_friction_n: f64,
    /// Where the figures come from, for notices ("the simulated arm's [arm] table").
    pub source: &'static str,
}

impl DevicePhysics {
    /// The largest passive coupling stiffness at servo period `period_s` (N/m): `b / (T/2 + tau)`, and at
    /// most `2 f_c / Delta` where both are known.
    pub fn max_stiffness_n_per_m(&self, period_s: f64) -> f64 {
        let delay_s = period_s / 2.0 + self.latency_s;
        let mut cap = if delay_s > 0.0 {
            self.damping_n_s_per_m / delay_s
        } else {
            f64::INFINITY
        };
        if self.coulomb_friction_n > 0.0 && self.position_resolution_m > 0.0 {
            cap = cap.min(2.0 * self.coulomb_friction_n / self.position_resolution_m);
        }
        cap
    }

    /// The largest passive coupling damping with stiffness `stiffness_n_per_m` (N s/m).
    pub fn max_damping_n_s_per_m(&self, stiffness_n_per_m: f64, period_s: f64) -> f64 {
        (self.damping_n_s_per_m - stiffness_n_per_m * (period_s / 2.0 + self.latency_s)).max(0.0)
    }

    /// The stiffness to declare at 1 kHz (`DeviceInfo::max_stiffness_n_per_m`) so that
    /// `CouplingCaps::new(declared, period_s)` caps at exactly [`Self::max_stiffness_n_per_m`] at that period.
    pub fn declared_at_1khz_n_per_m(&self, period_s: f64) -> f64 {
        self.max_stiffness_n_per_m(period_s) / (1e-3 / period_s).min(1.0)
    }

    /// One line for the operator naming the figures the stiffness cap came from.
    pub fn notice(&self, period_s: f64) -> String {
        let mut line = format!(
            "stiffness cap {:.0} N/m from {}: damping {} N s/m, period {} ms, latency {} ms (passive when \
             b > K (T/2 + tau))",
            self.max_stiffness_n_per_m(period_s),
            self.source,
            self.damping_n_s_per_m,
            period_s * 1e3,
            self.latency_s * 1e3
        );
        if self.coulomb_friction_n > 0.0 && self.position_resolution_m > 0.0 {
            line.push_str(&format!(
                ", and quantisation: friction {} N over resolution {} m (K <= 2 f_c / Delta)",
                self.coulomb_friction_n, self.position_resolution_m
            ));
        }
        line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm(b: f64, latency_s: f64) -> DevicePhysics {
        DevicePhysics {
            damping_n_s_per_m: b,
            latency_s,
            position_resolution_m: 0.0,
            coulomb_friction_n: 0.0,
            source: "test",
        }
    }

    /// The figures of the issue that asked for these caps: 1 kHz, b = 1 N s/m released: 2 000 N/m with no
    /// delay (b / (T/2)), 667 with 1 ms, 400 with 2 ms; a 4 kHz loop raises the first to 8 000.
    #[test]
    fn the_stiffness_cap_is_b_over_half_the_period_plus_the_latency() {
        assert!((arm(1.0, 0.0).max_stiffness_n_per_m(1e-3) - 2000.0).abs() < 1e-9);
        assert!((arm(1.0, 1e-3).max_stiffness_n_per_m(1e-3) - 1000.0 / 1.5).abs() < 1e-9);
        assert!((arm(1.0, 2e-3).max_stiffness_n_per_m(1e-3) - 400.0).abs() < 1e-9);
        assert!((arm(1.0, 0.0).max_stiffness_n_per_m(0.25e-3) - 8000.0).abs() < 1e-9);
        // No damping, no stiffness: an undamped arm gets a zero cap, not a constant.
        assert_eq!(arm(0.0, 0.0).max_stiffness_n_per_m(1e-3), 0.0);
    }

    /// Abbott and Okamura's quantisation bound: f_c = 0.1 N, Delta = 0.1 mm gives 2 f_c / Delta = 2 000 N/m,
    /// below the damping bound of b = 5 N s/m (10 000 N/m at 1 kHz).
    #[test]
    fn quantisation_and_friction_cap_the_stiffness() {
        let physics = DevicePhysics {
            position_resolution_m: 1e-4,
            coulomb_friction_n: 0.1,
            ..arm(5.0, 0.0)
        };
        assert!((physics.max_stiffness_n_per_m(1e-3) - 2000.0).abs() < 1e-9);
        assert!(physics.notice(1e-3).contains("2 f_c / Delta"));
    }

    #[test]
    fn the_damping_cap_is_what_the_spring_leaves() {
        // b = 1, K = 1000, T/2 + tau = 0.5 ms: B_max = 1 - 0.5 = 0.5 N s/m.
        assert!((arm(1.0, 0.0).max_damping_n_s_per_m(1000.0, 1e-3) - 0.5).abs() < 1e-12);
        assert_eq!(arm(1.0, 0.0).max_damping_n_s_per_m(5000.0, 1e-3), 0.0);
    }

    #[test]
    fn the_declared_equivalent_reproduces_the_cap_through_coupling_caps() {
        for period_s in [0.25e-3, 1e-3, 4e-3] {
            let physics = arm(1.0, 1e-3);
            let caps = crate::safety::CouplingCaps::new(
                physics.declared_at_1khz_n_per_m(period_s),
                period_s,
            );
            let expected = 1.0 / (period_s / 2.0 + 1e-3);
            assert!((caps.max_stiffness_n_per_m / expected - 1.0).abs() < 1e-12);
        }
    }
}
