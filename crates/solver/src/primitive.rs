//! Haptic primitives (Lundin et al. 2005, section 4.1, eq. 8-13): directed force, point, line and plane.
//!
//! Every haptic mode turns local volume data into a handful of these each tick; the solver
//! ([`crate`]) then finds the proxy position where their forces balance the virtual coupling.
//!
//! Primitive i has a strength `s_i >= 0` in newtons and, where it has them, a position `x_i` (m) and a unit
//! direction `q_i`. Its force on a proxy at `x` (paper eq. 8-13) and its energy term (docs/design.md, "The
//! proxy"), with `f_i = -grad E_i` wherever `E_i` is differentiable:
//!
//! | primitive | force `f_i(x)` | energy `E_i(x)` |
//! |---|---|---|
//! | directed | `s q` | `-s q.x` |
//! | point | `s (x_i - x)/|x_i - x|`, 0 at `x = x_i` | `s |x - x_i|` |
//! | line | `s m/|m|`, `m = q[q.(x - x_i)] - (x - x_i)`, 0 at `m = 0` | `s dist(x, line)` |
//! | plane | `s q` where `(x - x_i).q < 0`, else 0 | `s max(0, -(x - x_i).q)` |
//!
//! The forces use the paper's one-sided definitions, which are zero exactly on a kink; the solver works with
//! the energies instead, whose subgradient there is the whole set of balancing forces.
//!
//! Fields are private: a `Primitive` can only be built through constructors that reject non-finite values,
//! negative strengths and zero directions, so the solver never sees a NaN.

use glam::DVec3;
use serde::Serialize;

/// Why a primitive could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PrimitiveError {
    #[error("strength must be a finite number >= 0 N, got {0}")]
    BadStrength(f64),
    #[error("position must be three finite numbers (m), got {0:?}")]
    BadPosition([f64; 3]),
    #[error("direction must be three finite numbers, got {0:?}")]
    BadDirection([f64; 3]),
    #[error("direction must not be zero (its length is {0:e})")]
    ZeroDirection(f64),
}

/// The kind of a primitive, without its data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PrimitiveKind {
    Directed,
    Point,
    Line,
    Plane,
}

impl PrimitiveKind {
    /// The lowercase name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            PrimitiveKind::Directed => "directed",
            PrimitiveKind::Point => "point",
            PrimitiveKind::Line => "line",
            PrimitiveKind::Plane => "plane",
        }
    }
}

/// One haptic primitive. `Copy` and heap-free, so the servo thread can keep them in a preallocated buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Primitive {
    kind: PrimitiveKind,
    position_m: DVec3,
    direction: DVec3,
    strength_n: f64,
}

/// Smallest direction length accepted before normalising.
const MIN_DIRECTION_LENGTH: f64 = 1e-12;

fn check_strength(strength_n: f64) -> Result<f64, PrimitiveError> {
    if strength_n.is_finite() && strength_n >= 0.0 {
        Ok(strength_n)
    } else {
        Err(PrimitiveError::BadStrength(strength_n))
    }
}

fn check_position(position_m: DVec3) -> Result<DVec3, PrimitiveError> {
    if position_m.is_finite() {
        Ok(position_m)
    } else {
        Err(PrimitiveError::BadPosition(position_m.to_array()))
    }
}

fn check_direction(direction: DVec3) -> Result<DVec3, PrimitiveError> {
    if !direction.is_finite() {
        return Err(PrimitiveError::BadDirection(direction.to_array()));
    }
    let length = direction.length();
    if length.is_infinite() {
        // Finite components whose squares overflow (1e200): scaled down first, the direction is the same.
        return check_direction(direction / direction.abs().max_element());
    }
    if length.is_nan() || length < MIN_DIRECTION_LENGTH {
        return Err(PrimitiveError::ZeroDirection(length));
    }
    Ok(direction / length)
}

impl Primitive {
    /// A constant force `s q` (paper eq. 8). `direction` is normalised.
    pub fn directed(direction: DVec3, strength_n: f64) -> Result<Self, PrimitiveError> {
        Self::oriented(PrimitiveKind::Directed, DVec3::ZERO, direction, strength_n)
    }

    /// A point that pulls the proxy towards `position_m` with at most `strength_n` (paper eq. 9-10).
    pub fn point(position_m: DVec3, strength_n: f64) -> Result<Self, PrimitiveError> {
        Ok(Self {
            kind: PrimitiveKind::Point,
            position_m: check_position(position_m)?,
            direction: DVec3::ZERO,
            strength_n: check_strength(strength_n)?,
        })
    }

    /// A line through `position_m` along `direction` that pulls the proxy onto it (paper eq. 11-12).
    pub fn line(
        position_m: DVec3,
        direction: DVec3,
        strength_n: f64,
    ) -> Result<Self, PrimitiveError> {
        Self::oriented(PrimitiveKind::Line, position_m, direction, strength_n)
    }

    /// A plane through `position_m` with normal `normal`; it pushes a proxy that is behind it
    /// (`(x - x_i).q < 0`) along `q` with `strength_n` (paper eq. 13).
    pub fn plane(
        position_m: DVec3,
        normal: DVec3,
        strength_n: f64,
    ) -> Result<Self, PrimitiveError> {
        Self::oriented(PrimitiveKind::Plane, position_m, normal, strength_n)
    }

    /// A primitive with a position and a direction (a directed force's position is zero), each checked in
    /// that order, then its strength.
    fn oriented(
        kind: PrimitiveKind,
        position_m: DVec3,
        direction: DVec3,
        strength_n: f64,
    ) -> Result<Self, PrimitiveError> {
        Ok(Self {
            kind,
            position_m: check_position(position_m)?,
            direction: check_direction(direction)?,
            strength_n: check_strength(strength_n)?,
        })
    }

    pub fn kind(&self) -> PrimitiveKind {
        self.kind
    }

    /// Position `x_i` in metres (zero for a directed force, which has none).
    pub fn position_m(&self) -> DVec3 {
        self.position_m
    }

    /// Unit direction `q_i` (zero for a point, which has none).
    pub fn direction(&self) -> DVec3 {
        self.direction
    }

    pub fn strength_n(&self) -> f64 {
        self.strength_n
    }

    /// The primitive's force on a proxy at `x` (paper eq. 8-13, one-sided at kinks).
    pub fn force_n(&self, x: DVec3) -> DVec3 {
        let s = self.strength_n;
        let r = x - self.position_m;
        match self.kind {
            PrimitiveKind::Directed => s * self.direction,
            PrimitiveKind::Point => {
                let d = r.length();
                if d > 0.0 {
                    -s * r / d
                } else {
                    DVec3::ZERO
                }
            }
            PrimitiveKind::Line => {
                let q = self.direction;
                let m = q * q.dot(r) - r;
                let d = m.length();
                if d > 0.0 {
                    s * m / d
                } else {
                    DVec3::ZERO
                }
            }
            PrimitiveKind::Plane => {
                if r.dot(self.direction) < 0.0 {
                    s * self.direction
                } else {
                    DVec3::ZERO
                }
            }
        }
    }

    /// The primitive's energy term at `x` in joules (docs/design.md, "The proxy").
    pub fn energy_j(&self, x: DVec3) -> f64 {
        let s = self.strength_n;
        match self.kind {
            PrimitiveKind::Directed => -s * self.direction.dot(x),
            _ => s * self.distance_m(x),
        }
    }

    /// Distance from `x` to the primitive's set: the point, the line, or the half-space in front of the plane.
    /// Zero for a directed force.
    pub fn distance_m(&self, x: DVec3) -> f64 {
        let r = x - self.position_m;
        match self.kind {
            PrimitiveKind::Directed => 0.0,
            PrimitiveKind::Point => r.length(),
            PrimitiveKind::Line => (r - self.direction * self.direction.dot(r)).length(),
            PrimitiveKind::Plane => (-r.dot(self.direction)).max(0.0),
        }
    }
}

/// Total energy `E(x) = k/2 |x - probe|^2 + sum_i E_i(x)` (the energy of docs/design.md), in joules.
pub fn total_energy_j(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    primitives: &[Primitive],
    x: DVec3,
) -> f64 {
    0.5 * stiffness_n_per_m * (x - probe_m).length_squared()
        + primitives.iter().map(|p| p.energy_j(x)).sum::<f64>()
}

/// Resultant force on the proxy, `f_res(x) = -k (x - probe) + sum_i f_i(x)` (paper eq. 14).
pub fn resultant_force_n(
    stiffness_n_per_m: f64,
    probe_m: DVec3,
    primitives: &[Primitive],
    x: DVec3,
) -> DVec3 {
    -stiffness_n_per_m * (x - probe_m) + primitives.iter().map(|p| p.force_n(x)).sum::<DVec3>()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numeric_gradient(p: &Primitive, x: DVec3) -> DVec3 {
        let h = 1e-7;
        let e = |dx: DVec3| p.energy_j(x + dx);
        DVec3::new(
            (e(DVec3::X * h) - e(-DVec3::X * h)) / (2.0 * h),
            (e(DVec3::Y * h) - e(-DVec3::Y * h)) / (2.0 * h),
            (e(DVec3::Z * h) - e(-DVec3::Z * h)) / (2.0 * h),
        )
    }

    #[test]
    fn constructors_reject_bad_values() {
        assert_eq!(
            Primitive::point(DVec3::ZERO, -1.0),
            Err(PrimitiveError::BadStrength(-1.0))
        );
        assert!(matches!(
            Primitive::point(DVec3::ZERO, f64::NAN),
            Err(PrimitiveError::BadStrength(_))
        ));
        assert!(matches!(
            Primitive::point(DVec3::ZERO, f64::INFINITY),
            Err(PrimitiveError::BadStrength(_))
        ));
        assert!(matches!(
            Primitive::point(DVec3::new(f64::NAN, 0.0, 0.0), 1.0),
            Err(PrimitiveError::BadPosition(_))
        ));
        assert!(matches!(
            Primitive::plane(DVec3::ZERO, DVec3::ZERO, 1.0),
            Err(PrimitiveError::ZeroDirection(_))
        ));
        assert!(matches!(
            Primitive::line(DVec3::ZERO, DVec3::new(0.0, f64::INFINITY, 0.0), 1.0),
            Err(PrimitiveError::BadDirection(_))
        ));
        assert!(matches!(
            Primitive::directed(DVec3::splat(1e-300), 1.0),
            Err(PrimitiveError::ZeroDirection(_))
        ));
        // Zero strength is allowed: a primitive that exerts no force.
        assert!(Primitive::plane(DVec3::ZERO, DVec3::Z, 0.0).is_ok());
    }

    #[test]
    fn directions_are_normalised() {
        let p = Primitive::line(DVec3::ZERO, DVec3::new(0.0, 3.0, 4.0), 1.0).unwrap();
        assert!((p.direction().length() - 1.0).abs() < 1e-15);
        // Finite but so long that the squared length overflows: the same direction, 3-4-5.
        let p = Primitive::plane(DVec3::ZERO, DVec3::new(0.0, 3e200, 4e200), 1.0).unwrap();
        assert!((p.direction() - DVec3::new(0.0, 0.6, 0.8)).length() < 1e-15);
    }

    #[test]
    fn forces_match_the_paper() {
        let point = Primitive::point(DVec3::new(1.0, 0.0, 0.0), 2.0).unwrap();
        assert_eq!(point.force_n(DVec3::ZERO), DVec3::new(2.0, 0.0, 0.0));
        assert_eq!(point.force_n(DVec3::new(1.0, 0.0, 0.0)), DVec3::ZERO);

        let line = Primitive::line(DVec3::ZERO, DVec3::Z, 3.0).unwrap();
        let f = line.force_n(DVec3::new(0.0, 0.5, 7.0));
        assert!((f - DVec3::new(0.0, -3.0, 0.0)).length() < 1e-15);
        assert_eq!(line.force_n(DVec3::new(0.0, 0.0, 4.0)), DVec3::ZERO);

        let plane = Primitive::plane(DVec3::ZERO, DVec3::Z, 1.5).unwrap();
        assert_eq!(
            plane.force_n(DVec3::new(0.3, 0.2, -0.01)),
            DVec3::new(0.0, 0.0, 1.5)
        );
        assert_eq!(plane.force_n(DVec3::new(0.3, 0.2, 0.01)), DVec3::ZERO);
        assert_eq!(plane.force_n(DVec3::new(0.3, 0.2, 0.0)), DVec3::ZERO);

        let directed = Primitive::directed(DVec3::new(0.0, 2.0, 0.0), 0.7).unwrap();
        assert!((directed.force_n(DVec3::splat(9.0)) - DVec3::new(0.0, 0.7, 0.0)).length() < 1e-15);
    }

    #[test]
    fn force_is_minus_energy_gradient_away_from_kinks() {
        let x = DVec3::new(0.013, -0.021, 0.007);
        let prims = [
            Primitive::point(DVec3::new(0.02, 0.01, -0.03), 1.3).unwrap(),
            Primitive::line(DVec3::new(-0.01, 0.0, 0.0), DVec3::new(1.0, 2.0, -0.5), 0.8).unwrap(),
            Primitive::plane(DVec3::new(0.0, 0.0, 0.01), DVec3::new(0.1, 0.2, 1.0), 2.0).unwrap(),
            Primitive::directed(DVec3::new(1.0, -1.0, 0.0), 0.4).unwrap(),
        ];
        for p in &prims {
            let g = numeric_gradient(p, x);
            assert!(
                (p.force_n(x) + g).length() < 1e-6,
                "{:?}: force {} vs -grad {}",
                p.kind(),
                p.force_n(x),
                -g
            );
        }
    }
}
