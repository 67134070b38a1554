//! The ramps and the slew limit of the local loop (protocol/SPEC.md section 10.5, steps 5 and 6): the engage ramp
//! after Enable, the ramp-down after a model's expiry, and the limit on how fast the force may grow.
//!
//! The engage threshold is the host's (its safety pipeline's default, docs/safety.md): a scene that engages on the
//! set-force path engages on the device too. A lower one never engaged a scene whose resting force is a few
//! tenths of a newton: a flow line (`vector_follow`) holds the proxy up to `s / k` off a moving handle, so a hand
//! moving through the flow feels its strength `s` (0.25 N in the built-in scene) for as long as it moves.
//!
//! Where it sits: [`crate::device_loop`] calls [`Ramp::update`] and [`slew_limit`] once per cycle; nothing here
//! knows about models or the solver.

use voxhap_protocol::local::RAMP_DOWN_US;

/// The engage ramp's length: the factor rises from 0 to 1 over this long, microseconds.
pub const ENGAGE_US: u32 = 500_000;
/// The engage ramp starts only once the clamped force is below this, newtons: the host's engage threshold.
pub const ENGAGE_BELOW_N: f64 = 1.0;
/// Fastest rise of the force magnitude, newtons per second (0.5 N per ms, the host's own limit).
pub const SLEW_N_PER_S: f64 = 500.0;

/// Distance from 0 or 1 within which the factor snaps to it.
const SNAP: f64 = 1e-9;

/// The ramp factor `r` in [0, 1] that scales the clamped force.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Ramp {
    factor: f64,
}

/// What a ramp update decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RampState {
    /// Full force.
    On,
    /// Rising, or waiting at zero for the force to fall below [`ENGAGE_BELOW_N`].
    Engaging,
    /// Falling to (or held at) zero: no model, an expired one, or one without a solution.
    Down,
}

impl Ramp {
    /// The factor now.
    pub fn factor(&self) -> f64 {
        self.factor
    }

    /// Back to zero (the drive left Enabled: Disable, a fault, the watchdog, a Hello).
    pub fn reset(&mut self) {
        self.factor = 0.0;
    }

    /// One cycle of `dt_us`: down while `live` is false, else up (from zero only once `clamped_force_n` is below
    /// [`ENGAGE_BELOW_N`]).
    pub fn update(&mut self, dt_us: u64, live: bool, clamped_force_n: f64) -> RampState {
        let dt = dt_us as f64;
        if !live {
            // Snapped at the ends, so that a sum of steps that should land on 0 or 1 does not miss it by a rounding.
            self.factor -= dt / f64::from(RAMP_DOWN_US);
            if self.factor < SNAP {
                self.factor = 0.0;
            }
            return RampState::Down;
        }
        if self.factor == 0.0 && clamped_force_n >= ENGAGE_BELOW_N {
            return RampState::Engaging;
        }
        self.factor += dt / f64::from(ENGAGE_US);
        if self.factor > 1.0 - SNAP {
            self.factor = 1.0;
        }
        if self.factor < 1.0 {
            RampState::Engaging
        } else {
            RampState::On
        }
    }
}

/// Scales `force` down so that its magnitude exceeds `previous_n` by at most the slew allowance of `dt_us`;
/// the flag says whether it did. A fall is never limited.
pub fn slew_limit(force: [f64; 3], previous_n: f64, dt_us: u64) -> ([f64; 3], bool) {
    let magnitude = norm(force);
    let allowed = previous_n + SLEW_N_PER_S * dt_us as f64 * 1e-6;
    if magnitude <= allowed || magnitude == 0.0 {
        return (force, false);
    }
    let scale = allowed / magnitude;
    (force.map(|f| f * scale), true)
}

/// Scales `force` down to magnitude `limit_n` if longer; the flag says whether it did.
pub fn clamp(force: [f64; 3], limit_n: f64) -> ([f64; 3], bool) {
    let magnitude = norm(force);
    if magnitude <= limit_n {
        return (force, false);
    }
    let scale = limit_n / magnitude;
    (force.map(|f| f * scale), true)
}

/// Euclidean length.
pub fn norm(v: [f64; 3]) -> f64 {
    glam::DVec3::from_array(v).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ramp_down_reaches_zero_in_the_spec_time() {
        // SPEC 10.5: from full force, zero at most 5 ms after the expiry.
        let mut ramp = Ramp { factor: 1.0 };
        let mut t = 0;
        while ramp.factor() > 0.0 {
            ramp.update(100, false, 0.0);
            t += 100;
            assert!(t <= 5_000, "still {} after {t} us", ramp.factor());
        }
        assert_eq!(t, 5_000);
    }

    #[test]
    fn engaging_waits_for_a_small_force_then_takes_half_a_second() {
        // SPEC 10.5 step 6: at r = 0 a clamped force of 1 N or more holds r at 0; below it r rises over 0.5 s.
        let mut ramp = Ramp::default();
        assert_eq!(ramp.update(100, true, 1.0), RampState::Engaging);
        assert_eq!(ramp.update(100, true, 2.5), RampState::Engaging);
        assert_eq!(ramp.factor(), 0.0);
        let mut t = 0;
        while ramp.update(100, true, 0.95) == RampState::Engaging {
            t += 100;
        }
        assert_eq!(t + 100, 500_000);
        // Once on, a large force does not stop it.
        assert_eq!(ramp.update(100, true, 5.0), RampState::On);
    }

    #[test]
    fn slew_and_clamp_keep_direction_and_bound_magnitude() {
        let (f, limited) = slew_limit([3.0, 4.0, 0.0], 1.0, 1000);
        assert!(limited);
        // 1 N + 0.5 N/ms x 1 ms = 1.5 N, along (0.6, 0.8).
        assert!((f[0] - 0.9).abs() < 1e-12 && (f[1] - 1.2).abs() < 1e-12);
        assert_eq!(
            slew_limit([0.0, 0.0, 0.1], 5.0, 100),
            ([0.0, 0.0, 0.1], false)
        );
        let (f, clamped) = clamp([0.0, 0.0, -10.0], 4.0);
        assert!(clamped);
        assert_eq!(f, [0.0, 0.0, -4.0]);
    }
}
