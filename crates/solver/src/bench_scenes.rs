//! Deterministic scenes shared by the solver's tests and benchmarks (benches/solver.rs): random primitive sets,
//! thin wedges, and a 1 kHz exploration path over a surface with friction.
//!
//! Everything is generated from a seed with SplitMix64, so the same inputs appear on every machine.

use crate::primitive::Primitive;
use glam::DVec3;

/// SplitMix64: a tiny, well-mixed deterministic generator (no dependency, same numbers everywhere).
#[derive(Debug, Clone)]
pub struct SplitMix(pub u64);

impl SplitMix {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }

    /// A vector with each coordinate uniform in [-half, half).
    pub fn vec(&mut self, half: f64) -> DVec3 {
        DVec3::new(
            self.range(-half, half),
            self.range(-half, half),
            self.range(-half, half),
        )
    }
}

/// `n` random primitives within 1 cm of the origin, cycling point, line, plane, directed; strengths up to 2 N
/// (directed forces up to 0.4 N).
pub fn random_primitives(rng: &mut SplitMix, n: usize) -> Vec<Primitive> {
    (0..n)
        .map(|i| {
            let position = rng.vec(0.01);
            let direction = rng.vec(1.0) + DVec3::new(0.0, 0.0, 0.01);
            let strength = rng.range(0.0, 2.0);
            match i % 4 {
                0 => Primitive::point(position, strength),
                1 => Primitive::line(position, direction, strength),
                2 => Primitive::plane(position, direction, strength),
                _ => Primitive::directed(direction, strength * 0.2),
            }
            .expect("generated values are finite and non-negative")
        })
        .collect()
}

/// The benchmark's random scene of `n` primitives from `seed`: a probe within 2 cm of the origin and
/// [`random_primitives`] (drawn first, from the same generator). The benchmark's own scene of `n` uses seed `n`;
/// the "other scenes" of `solver_instructions seeds` and the pass-count tests use `k * 1 000 003 + n`.
pub fn random_scene(seed: u64, n: usize) -> (DVec3, Vec<Primitive>) {
    let mut rng = SplitMix(seed);
    let primitives = random_primitives(&mut rng, n);
    (rng.vec(0.02), primitives)
}

/// A thin wedge: the region `|z| <= x tan(angle/2)` between two 50 N planes at `angle_deg` to each other, edge
/// along y. A probe at `(-0.2 mm, y, 0.01 mm)` belongs exactly on the edge, at `(0, y, 0)`.
pub fn thin_wedge(angle_deg: f64) -> [Primitive; 2] {
    let half = angle_deg.to_radians() / 2.0;
    let upper = DVec3::new(half.sin(), 0.0, -half.cos());
    let lower = DVec3::new(half.sin(), 0.0, half.cos());
    [
        Primitive::plane(DVec3::ZERO, upper, 50.0).expect("valid plane"),
        Primitive::plane(DVec3::ZERO, lower, 50.0).expect("valid plane"),
    ]
}

/// The probe position of a 1 kHz exploration path at tick `i`: a hand stroking a surface at z = 0 with a
/// wandering circular motion, pressing 0.5 to 3.5 mm in (about 0.25 to 1.75 N at 500 N/m), 5 to 10 cm/s.
pub fn exploration_probe(tick: usize) -> DVec3 {
    let t = tick as f64 * 1e-3;
    DVec3::new(
        0.02 * (1.3 * t).sin() + 0.004 * (7.1 * t).sin(),
        0.02 * (0.9 * t).cos() + 0.003 * (5.3 * t).cos(),
        -0.002 - 0.0015 * (2.3 * t).sin(),
    )
}

/// The primitives of the exploration path at one tick: the surface plane (2 N) and friction, a point at the
/// previous proxy with strength `mu` times the plane's normal force last tick (docs/modes.md).
pub fn exploration_primitives(previous_proxy_m: DVec3, friction_strength_n: f64) -> [Primitive; 2] {
    [
        Primitive::plane(DVec3::ZERO, DVec3::Z, 2.0).expect("valid plane"),
        Primitive::point(previous_proxy_m, friction_strength_n.max(0.0)).expect("valid point"),
    ]
}
