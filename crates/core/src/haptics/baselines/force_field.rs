//! Plain force functions, the oldest volume-haptics method: the force is a function of the data at the probe,
//! with no proxy. Here the function is the primitives' own forces (paper eq. 8-13) evaluated at the probe,
//! which is what a mode would send if it skipped the proxy. It has no memory, so it cannot hold a surface: a
//! probe pushed through a plane feels a constant push however deep it goes, and nothing once it is through.

use super::BaselineSolution;
use crate::haptics::primitive::Primitive;
use glam::DVec3;

/// The sum of the primitives' forces at the probe.
pub fn solve(probe_m: DVec3, primitives: &[Primitive]) -> BaselineSolution {
    let force: DVec3 = primitives.iter().map(|p| p.force_n(probe_m)).sum();
    BaselineSolution {
        proxy_m: probe_m,
        force_n: force,
        iterations: 0,
        residual_n: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_pushes_a_constant_force_behind_it() {
        let prims = [Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).unwrap()];
        assert_eq!(
            solve(DVec3::new(0.0, 0.0, -0.001), &prims).force_n,
            DVec3::new(0.0, 0.0, 2.0)
        );
        assert_eq!(
            solve(DVec3::new(0.0, 0.0, -0.05), &prims).force_n,
            DVec3::new(0.0, 0.0, 2.0)
        );
        assert_eq!(
            solve(DVec3::new(0.0, 0.0, 0.001), &prims).force_n,
            DVec3::ZERO
        );
    }
}
