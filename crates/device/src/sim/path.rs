//! The virtual hand's script: where the hand wants the arm to be (or what force it pushes with) at time t.
//!
//! A [`HandPath`] is a pure function of time, evaluated inside every physics substep of
//! [`SimArm::step`](super::SimArm::step), so it never allocates and never fails: the parameters are checked
//! once by [`HandPath::validate`] (which [`SimArm::new`](super::SimArm::new) calls). Every position path
//! returns both the target position and its exact time derivative, so the hand's damper acts on the
//! velocity error rather than fighting the motion.
//!
//! Limits: every parameter is finite, and within a range where a run means something (positions within a
//! kilometre, speeds up to 100 m/s, times from a millisecond, forces up to 1 kN: the constants of
//! [`super::keys`], each key's named in the `tagged_table!` declarations below); a value outside is refused
//! with its key, its value and the range, since far outside it the path's arithmetic overflows (a speed of
//! 1e300 m/s made every sample NaN) or asks for what no hand can do.
//!
//! Conventions: time before 0 (or non-finite) is treated as 0; paths that end (line, waypoints, raster) hold
//! their last point afterwards; the circle repeats forever. Polylines (waypoints, raster) are walked at a
//! constant speed along their arc length, with a velocity jump at each corner.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

use super::keys::{
    KeyCheck, OwnTable, CIRCLE_NORMAL, FREQUENCY, HAND_FORCE, PATH_SPEED, PATH_TIME, POSITION,
    RADIUS, RASTER_LINES, WAYPOINTS,
};
use super::tagged::tagged_table;
use super::SimError;

/// What the virtual hand does at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HandDrive {
    /// Pull the arm with the hand spring-damper towards this moving target.
    Target {
        /// Target position (m).
        position_m: DVec3,
        /// Target velocity, the time derivative of `position_m` (m/s).
        velocity_m_per_s: DVec3,
    },
    /// Push the arm with this force directly (no spring).
    Force {
        /// Applied force (N).
        force_n: DVec3,
    },
}

/// A scripted hand motion. In a scenario TOML it is a table with a `kind` key, e.g.
/// `{ kind = "line", from_m = [0, 0, 0], to_m = [0.05, 0, 0], duration_s = 2.0 }`, read through
/// `HandPathTable` so that every error names its key (super::tagged).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", try_from = "HandPathTable")]
pub enum HandPath {
    /// Hold still at one point.
    Hold {
        /// The point (m).
        at_m: DVec3,
    },
    /// Move from `from_m` to `to_m` at constant velocity over `duration_s`, then hold at `to_m`.
    Line {
        /// Start point (m), held before t = 0.
        from_m: DVec3,
        /// End point (m), held after `duration_s`.
        to_m: DVec3,
        /// Travel time (s), > 0.
        duration_s: f64,
    },
    /// Visit the points in order at a constant speed, then hold at the last one.
    Waypoints {
        /// At least one point (m).
        points_m: Vec<DVec3>,
        /// Speed along the polyline (m/s), > 0.
        speed_m_per_s: f64,
    },
    /// Go round a circle forever. The start point and sense are fixed by the normal: with
    /// `(u, w) = normal.any_orthonormal_pair()` the target is `center + r (cos a u + sin a w)` with
    /// `a = 2 pi t / period_s`, so for a normal along +z it starts on +x and turns towards +y.
    Circle {
        /// Centre (m).
        center_m: DVec3,
        /// Radius (m), > 0.
        radius_m: f64,
        /// Axis of the circle (any non-zero length; normalised on use).
        normal: DVec3,
        /// Time for one turn (s), > 0.
        period_s: f64,
    },
    /// A boustrophedon (lawn-mower) sweep: `lines` passes along `sweep_m`, stepping across by
    /// `step_m / (lines - 1)` between passes, alternating direction, at constant speed; then hold.
    Raster {
        /// Start corner (m).
        origin_m: DVec3,
        /// One pass: direction and length (m).
        sweep_m: DVec3,
        /// Total offset from the first pass to the last (m); unused when `lines` is 1.
        step_m: DVec3,
        /// Number of passes, >= 1.
        lines: u32,
        /// Speed along the path (m/s), > 0.
        speed_m_per_s: f64,
    },
    /// Apply a force profile instead of following a target (the hand spring is not used).
    Force {
        /// The force over time.
        profile: ForceProfile,
    },
}

/// A force over time, for [`HandPath::Force`]. A table with a `shape` key, read through
/// `ForceProfileTable` (super::tagged).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    tag = "shape",
    rename_all = "snake_case",
    try_from = "ForceProfileTable"
)]
pub enum ForceProfile {
    /// The same force at all times.
    Constant {
        /// Force (N).
        force_n: DVec3,
    },
    /// Linear from `from_n` at t = 0 to `to_n` at `duration_s`, then constant.
    Ramp {
        /// Force at t = 0 (N).
        from_n: DVec3,
        /// Force from `duration_s` on (N).
        to_n: DVec3,
        /// Ramp time (s), > 0.
        duration_s: f64,
    },
    /// `offset_n + amplitude_n sin(2 pi frequency_hz t)`.
    Sine {
        /// Mean force (N).
        offset_n: DVec3,
        /// Amplitude, per axis (N).
        amplitude_n: DVec3,
        /// Frequency (Hz), > 0.
        frequency_hz: f64,
    },
}

tagged_table! {
    HandPath by kind at "path",
    /// The `kind` of a [`HandPath`] table.
    kinds HandPathKind {
        Hold = "hold" { at_m: POSITION },
        Line = "line" { from_m: POSITION, to_m: POSITION, duration_s: PATH_TIME },
        Waypoints = "waypoints" { points_m: WAYPOINTS, speed_m_per_s: PATH_SPEED },
        Circle = "circle" {
            center_m: POSITION,
            radius_m: RADIUS,
            normal: CIRCLE_NORMAL,
            period_s: PATH_TIME
        },
        Raster = "raster" {
            origin_m: POSITION,
            sweep_m: POSITION,
            step_m: POSITION,
            lines: RASTER_LINES,
            speed_m_per_s: PATH_SPEED
        },
        Force = "force" { profile: OwnTable },
    }
    /// A `[path]` table as written: every key of every kind, checked against its `kind` by
    /// `HandPath::try_from` (super::tagged says why).
    table HandPathTable {
        at_m: DVec3,
        from_m: DVec3,
        to_m: DVec3,
        duration_s: f64,
        points_m: Vec<DVec3>,
        speed_m_per_s: f64,
        center_m: DVec3,
        radius_m: f64,
        normal: DVec3,
        period_s: f64,
        origin_m: DVec3,
        sweep_m: DVec3,
        step_m: DVec3,
        lines: u32,
        profile: ForceProfile,
    }
}

tagged_table! {
    ForceProfile by shape at "path.profile",
    /// The `shape` of a [`ForceProfile`] table.
    kinds ForceProfileShape {
        Constant = "constant" { force_n: HAND_FORCE },
        Ramp = "ramp" { from_n: HAND_FORCE, to_n: HAND_FORCE, duration_s: PATH_TIME },
        Sine = "sine" { offset_n: HAND_FORCE, amplitude_n: HAND_FORCE, frequency_hz: FREQUENCY },
    }
    /// A `[path.profile]` table as written: every key of every shape, checked against its `shape` by
    /// `ForceProfile::try_from` (super::tagged says why).
    table ForceProfileTable {
        force_n: DVec3,
        from_n: DVec3,
        to_n: DVec3,
        duration_s: f64,
        offset_n: DVec3,
        amplitude_n: DVec3,
        frequency_hz: f64,
    }
}

/// Clamps time to the path's domain: negative and non-finite times count as 0.
fn path_time(t_s: f64) -> f64 {
    if t_s.is_finite() {
        t_s.max(0.0)
    } else {
        0.0
    }
}

/// Position and velocity on a polyline of `count` vertices walked at `speed` from time 0.
/// `vertex(i)` gives vertex i; zero-length segments are skipped. No allocation.
fn polyline_at(count: usize, vertex: impl Fn(usize) -> DVec3, speed: f64, t_s: f64) -> HandDrive {
    let mut remaining_m = speed * path_time(t_s);
    let mut current = vertex(0);
    for i in 1..count {
        let next = vertex(i);
        let segment = next - current;
        let length_m = segment.length();
        if length_m > 0.0 {
            if remaining_m < length_m {
                let direction = segment / length_m;
                return HandDrive::Target {
                    position_m: current + direction * remaining_m,
                    velocity_m_per_s: direction * speed,
                };
            }
            remaining_m -= length_m;
        }
        current = next;
    }
    HandDrive::Target {
        position_m: current,
        velocity_m_per_s: DVec3::ZERO,
    }
}

impl HandPath {
    /// Checks that every parameter is finite and in range ([`super::keys`], each key's in the
    /// `tagged_table!` above). [`SimArm::new`](super::SimArm::new) calls this.
    pub fn validate(&self) -> Result<(), SimError> {
        self.check_keys()
    }

    /// The hand's drive at time `t_s`: a target with its velocity, or a force. Pure and allocation-free.
    pub fn drive_at(&self, t_s: f64) -> HandDrive {
        match self {
            HandPath::Hold { at_m } => HandDrive::Target {
                position_m: *at_m,
                velocity_m_per_s: DVec3::ZERO,
            },
            HandPath::Line {
                from_m,
                to_m,
                duration_s,
            } => {
                let t = path_time(t_s);
                if t >= *duration_s {
                    HandDrive::Target {
                        position_m: *to_m,
                        velocity_m_per_s: DVec3::ZERO,
                    }
                } else {
                    let fraction = t / duration_s;
                    HandDrive::Target {
                        position_m: from_m.lerp(*to_m, fraction),
                        velocity_m_per_s: (*to_m - *from_m) / *duration_s,
                    }
                }
            }
            HandPath::Waypoints {
                points_m,
                speed_m_per_s,
            } => polyline_at(points_m.len(), |i| points_m[i], *speed_m_per_s, t_s),
            HandPath::Circle {
                center_m,
                radius_m,
                normal,
                period_s,
            } => {
                let (u, w) = normal.normalize().any_orthonormal_pair();
                let omega_rad_per_s = TAU / period_s;
                let angle_rad = omega_rad_per_s * path_time(t_s);
                let (sin, cos) = angle_rad.sin_cos();
                HandDrive::Target {
                    position_m: *center_m + *radius_m * (cos * u + sin * w),
                    velocity_m_per_s: *radius_m * omega_rad_per_s * (-sin * u + cos * w),
                }
            }
            HandPath::Raster {
                origin_m,
                sweep_m,
                step_m,
                lines,
                speed_m_per_s,
            } => {
                let lines = (*lines).max(1) as usize;
                let across = if lines > 1 {
                    *step_m / (lines - 1) as f64
                } else {
                    DVec3::ZERO
                };
                let vertex = |j: usize| {
                    let row = j / 2;
                    let end_of_row = j % 2 == 1;
                    let along = if row.is_multiple_of(2) == end_of_row {
                        1.0
                    } else {
                        0.0
                    };
                    *origin_m + *sweep_m * along + across * row as f64
                };
                polyline_at(2 * lines, vertex, *speed_m_per_s, t_s)
            }
            HandPath::Force { profile } => HandDrive::Force {
                force_n: profile.force_at(t_s),
            },
        }
    }

    /// The target position at `t_s`, or `None` for a [`HandPath::Force`] profile (which has no target).
    pub fn target_at(&self, t_s: f64) -> Option<DVec3> {
        match self.drive_at(t_s) {
            HandDrive::Target { position_m, .. } => Some(position_m),
            HandDrive::Force { .. } => None,
        }
    }
}

impl ForceProfile {
    /// Checks that every parameter is finite and in range ([`super::keys`], each key's in the
    /// `tagged_table!` above).
    pub fn validate(&self) -> Result<(), SimError> {
        self.check_keys()
    }

    /// The force at `t_s` (N).
    pub fn force_at(&self, t_s: f64) -> DVec3 {
        let t = path_time(t_s);
        match self {
            ForceProfile::Constant { force_n } => *force_n,
            ForceProfile::Ramp {
                from_n,
                to_n,
                duration_s,
            } => from_n.lerp(*to_n, (t / duration_s).min(1.0)),
            ForceProfile::Sine {
                offset_n,
                amplitude_n,
                frequency_hz,
            } => *offset_n + *amplitude_n * (TAU * frequency_hz * t).sin(),
        }
    }
}

/// A `[path.profile]` table checks its own keys.
impl KeyCheck<ForceProfile> for OwnTable {
    fn check(&self, _name: &'static str, value: &ForceProfile) -> Result<(), SimError> {
        value.validate()
    }
}

#[cfg(test)]
#[path = "path_tests.rs"]
mod tests;
