//! The paper's proxy solver (Lundin et al. 2005, section 4.3): explicit Euler steps along the resultant force
//! `f_res(x) = -k (x - probe) + sum_i f_i(x)` with an adaptive step length, until `|f_res|` is small.
//!
//! The step `x += h f_res(x)` starts at `h = 1/k` (which solves the coupling alone in one step). A step that
//! does not reduce `|f_res|` is rejected and `h` halved; an accepted step lets `h` grow by 1.5 up to `1/k`.
//! The loop ends when `|f_res| <= force_tolerance_n`, when `h` falls below `1e-9/k`, or after
//! `max_iterations`. At a kink `f_res` has no zero in the paper's one-sided definition, so the loop stalls and
//! returns a point near, not at, the balance (docs/design.md and tests/paper.rs quantify this); that is why it
//! stays here as a baseline.

use super::BaselineSolution;
use crate::haptics::primitive::{resultant_force_n, Primitive};
use glam::DVec3;

/// Settings of the adaptive Euler solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EulerConfig {
    pub max_iterations: u32,
    pub force_tolerance_n: f64,
}

impl Default for EulerConfig {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            force_tolerance_n: 1e-3,
        }
    }
}

/// Runs the adaptive Euler solver from `start_m` (the previous proxy, or the probe).
pub fn solve(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    start_m: DVec3,
    primitives: &[Primitive],
    config: &EulerConfig,
) -> BaselineSolution {
    let k = stiffness_n_per_m;
    let h_max = 1.0 / k;
    let mut h = h_max;
    let mut x = start_m;
    let mut f = resultant_force_n(k, probe_m, primitives, x);
    let mut residual = f.length();
    let mut iterations = 0;
    while iterations < config.max_iterations
        && residual > config.force_tolerance_n
        && h > 1e-9 * h_max
    {
        iterations += 1;
        let candidate = x + h * f;
        let f_candidate = resultant_force_n(k, probe_m, primitives, candidate);
        let r_candidate = f_candidate.length();
        if r_candidate < residual {
            x = candidate;
            f = f_candidate;
            residual = r_candidate;
            h = (h * 1.5).min(h_max);
        } else {
            h *= 0.5;
        }
    }
    BaselineSolution {
        proxy_m: x,
        force_n: k * (x - probe_m),
        iterations,
        residual_n: residual,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_single_smooth_point_well() {
        let k = 500.0;
        let prims = [Primitive::point(DVec3::new(0.05, 0.0, 0.0), 1.0).unwrap()];
        let sol = solve(k, DVec3::ZERO, DVec3::ZERO, &prims, &EulerConfig::default());
        // The point pulls the proxy 1/k = 2 mm towards it.
        assert!((sol.proxy_m.x - 0.002).abs() < 1e-5, "{sol:?}");
        assert!(sol.residual_n <= 1e-3);
    }

    #[test]
    fn stalls_near_a_kink() {
        // The example of docs/design.md: a plane (2 N) and a point (0.5 N) at the proxy position, probe pushed in.
        let k = 500.0;
        let prims = [
            Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap(),
            Primitive::point(DVec3::new(0.0, 0.0, 0.0), 0.5).unwrap(),
        ];
        let probe = DVec3::new(0.003, 0.0, -0.002);
        let sol = solve(k, probe, DVec3::ZERO, &prims, &EulerConfig::default());
        // It never reaches its own force tolerance at the kink.
        assert!(sol.residual_n > 1e-3, "{sol:?}");
    }
}
