//! Energy per closed loop: a hand that moves a probe exactly around a circle, tick after tick, and the work
//! the force sent to it does over one loop.
//!
//! Place in the data flow: off the servo thread, for tests, `docs/stability.md`'s table of every mode, and
//! anyone checking a scene. The hand is an ideal position source (the probe is where the loop says, whatever
//! the force), so the work is the renderer's alone: under the zero-order hold the force `F_n` sent at tick
//! `n` acts over the probe's step to tick `n + 1`, and the loop's work is `W = Σ F_n . (p_{n+1} - p_n)` over
//! one loop, exactly. A passive scene has `W <= 0` (it takes energy from the hand or returns what it
//! stored); a conservative field has `W = 0`; an active mode's work is bounded by its power budget times
//! the loop's duration.
//!
//! The loop is a circle of `radius_m` about `centre_m` in the plane across `axis`, walked at
//! `speed_m_per_s` in `steps` equal angle steps (so it closes exactly), `forward` counter-clockwise about
//! `axis`. One loop is walked first so the proxy settles (friction sticks, viscosity reaches steady
//! motion); the next is measured.

use crate::haptics::modes::RenderScene;
use crate::haptics::tick::{tick, SolverKind, TickState, TickWorkspace};
use crate::haptics::SolverConfig;
use glam::DVec3;
use std::f64::consts::TAU;

/// A circle walked by an ideal hand (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosedLoop {
    pub centre_m: DVec3,
    pub axis: DVec3,
    pub radius_m: f64,
    pub speed_m_per_s: f64,
    pub rate_hz: f64,
}

/// Why a loop could not be walked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LoopError {
    #[error("loop: radius, speed and rate must be finite numbers > 0 (radius {radius_m} m, speed {speed_m_per_s} m/s, rate {rate_hz} Hz)")]
    BadLoop {
        radius_m: f64,
        speed_m_per_s: f64,
        rate_hz: f64,
    },
    #[error("loop: axis must be a finite non-zero vector, got {0:?}")]
    BadAxis([f64; 3]),
    #[error("loop: {steps} ticks per loop is outside 8 to {MAX_LOOP_TICKS} (radius {radius_m} m at {speed_m_per_s} m/s and {rate_hz} Hz)")]
    Steps {
        steps: f64,
        radius_m: f64,
        speed_m_per_s: f64,
        rate_hz: f64,
    },
}

/// Most ticks in one loop (ten minutes at 1 kHz).
pub const MAX_LOOP_TICKS: f64 = 600_000.0;

/// What one measured loop gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopEnergy {
    /// Work the sent force did on the hand over the loop (J).
    pub work_j: f64,
    /// The loop's duration (s).
    pub duration_s: f64,
    /// The largest force sent during the loop (N).
    pub max_force_n: f64,
    /// `k/2 Σ |p_{n+1} - p_n|²` over the loop (J): what a sampled spring of the coupling's stiffness held
    /// against this hand generates at most over a closed loop (for `F_n = -k p_n`, `Σ F_n . Δp_n` is exactly
    /// this), the zero-order hold's own share that a device's damping must take.
    pub hold_bound_j: f64,
}

impl ClosedLoop {
    /// Ticks per loop and the positions of the probe at tick `n` of it.
    fn path(&self, forward: bool) -> Result<(usize, impl Fn(usize) -> DVec3), LoopError> {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        if !(ok(self.radius_m) && ok(self.speed_m_per_s) && ok(self.rate_hz)) {
            return Err(LoopError::BadLoop {
                radius_m: self.radius_m,
                speed_m_per_s: self.speed_m_per_s,
                rate_hz: self.rate_hz,
            });
        }
        let length = self.axis.length();
        if !(length.is_finite() && length > 0.0 && self.centre_m.is_finite()) {
            return Err(LoopError::BadAxis(self.axis.to_array()));
        }
        let steps = (TAU * self.radius_m * self.rate_hz / self.speed_m_per_s).round();
        if !(8.0..=MAX_LOOP_TICKS).contains(&steps) {
            return Err(LoopError::Steps {
                steps,
                radius_m: self.radius_m,
                speed_m_per_s: self.speed_m_per_s,
                rate_hz: self.rate_hz,
            });
        }
        let (a, b) = (self.axis / length).any_orthonormal_pair();
        let sign = if forward { 1.0 } else { -1.0 };
        let (centre, radius) = (self.centre_m, self.radius_m);
        let count = steps as usize;
        let at = move |n: usize| {
            let angle = sign * TAU * (n % count) as f64 / count as f64;
            centre + radius * (angle.cos() * a + angle.sin() * b)
        };
        Ok((count, at))
    }

    /// Walks the loop twice over `scene` (exact solver) and returns the second loop's work (module docs).
    pub fn energy(&self, scene: &RenderScene, forward: bool) -> Result<LoopEnergy, LoopError> {
        let (steps, at) = self.path(forward)?;
        let dt_s = 1.0 / self.rate_hz;
        let mut state = TickState::new(at(0));
        let mut workspace = TickWorkspace::new(scene, SolverKind::Exact, SolverConfig::default());
        let mut work_j = 0.0;
        let mut max_force_n: f64 = 0.0;
        let mut squared_steps_m2 = 0.0;
        for n in 0..2 * steps {
            let probe_m = at(n);
            let out = tick(&mut state, scene, probe_m, dt_s, &mut workspace);
            if n >= steps {
                let step_m = at(n + 1) - probe_m;
                work_j += out.coupling_force_n.dot(step_m);
                squared_steps_m2 += step_m.length_squared();
                max_force_n = max_force_n.max(out.coupling_force_n.length());
            }
        }
        Ok(LoopEnergy {
            work_j,
            duration_s: steps as f64 * dt_s,
            max_force_n,
            hold_bound_j: 0.5 * scene.stiffness_n_per_m() * squared_steps_m2,
        })
    }
}
