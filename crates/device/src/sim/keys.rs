//! What each key of a hand path, a force profile and a workspace accepts, stated once: the validators check with
//! these ([`KeyCheck`], called for every key `tagged_table!` declares with one), and the scene reference
//! (voxhap-servo's schema table) describes the same constants, so a unit or a range is written in one place.

use glam::DVec3;

use super::SimError;

/// Largest size of a coordinate of any position of a path, a workspace or a start point (m): a kilometre, far
/// beyond any arm's reach, and small enough that squares and products of positions stay finite.
pub const MAX_POSITION_M: f64 = 1e3;
/// Fastest a path may move the hand (m/s): a human hand moves a few metres per second at most.
pub const MAX_SPEED_M_PER_S: f64 = 100.0;
/// Shortest and longest time of a path or force profile (a line's travel, a circle's period, a ramp) (s):
/// below a millisecond the target's velocity (distance over time) leaves physical sense and, near zero,
/// overflows; a circle's angle `2 pi t / period` loses all precision.
pub const PATH_TIME_RANGE_S: (f64, f64) = (1e-3, 1e6);
/// Largest size of a coordinate of a hand force (N): a hundred kilograms' weight, far beyond a hand's push.
pub const MAX_HAND_FORCE_N: f64 = 1e3;
/// Highest frequency of a sine force profile (Hz).
pub const MAX_FREQUENCY_HZ: f64 = 1e4;
/// Most waypoints, and most raster lines: every physics substep walks the path's vertices.
pub const MAX_PATH_VERTICES: usize = 10_000;
/// Heaviest simulated arm (kg): a tonne. Heavier, the arm does not move at any force a haptic loop renders.
pub const MAX_ARM_MASS_KG: f64 = 1e3;

/// Checks that `value` is finite, > 0 and within `[min, max]`; a `min` of 0 is reported as excluded (the
/// range is then `(0, max]`).
fn check_between(
    name: &'static str,
    value: f64,
    (min, max): (f64, f64),
    unit: &'static str,
) -> Result<(), SimError> {
    check_positive(name, value)?;
    if !(min..=max).contains(&value) {
        return Err(SimError::OutOfRange {
            name,
            value,
            min,
            max,
            min_excluded: min == 0.0,
            unit,
        });
    }
    Ok(())
}

/// Checks that every component of `value` is finite and at most `limit` in size.
fn check_vector_within(
    name: &'static str,
    value: DVec3,
    limit: f64,
    unit: &'static str,
) -> Result<(), SimError> {
    check_vector(name, value)?;
    let largest = value.abs().max_element();
    if largest > limit {
        let value =
            value.to_array().into_iter().fold(
                0.0,
                |worst: f64, c| {
                    if c.abs() > worst.abs() {
                        c
                    } else {
                        worst
                    }
                },
            );
        return Err(SimError::VectorOutOfRange {
            name,
            value,
            limit,
            unit,
        });
    }
    Ok(())
}

pub(super) fn check_positive(name: &'static str, value: f64) -> Result<(), SimError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SimError::InvalidParameter {
            name,
            value,
            requirement: "finite and > 0",
        })
    }
}

fn check_vector(name: &'static str, value: DVec3) -> Result<(), SimError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(SimError::NonFiniteVector { name })
    }
}

/// Checks one key's value; `name` is the key as an error names it (`path.from_m`).
pub trait KeyCheck<V> {
    fn check(&self, name: &'static str, value: &V) -> Result<(), SimError>;
}

/// A key's unit and bounds: [`VectorRange`] for a vector key, [`NumberRange`] for a number key.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyRange<B> {
    pub bounds: B,
    pub unit: &'static str,
}

/// A vector key: each component finite and at most `bounds` in size.
pub type VectorRange = KeyRange<f64>;

/// A number key: finite, > 0 and from `bounds.0` to `bounds.1`; a `bounds.0` of 0 is excluded (the range is
/// then `(0, bounds.1]`).
pub type NumberRange = KeyRange<(f64, f64)>;

impl<B> KeyRange<B> {
    /// A key in `unit` within `bounds`.
    pub const fn new(bounds: B, unit: &'static str) -> Self {
        KeyRange { bounds, unit }
    }
}

impl KeyCheck<DVec3> for VectorRange {
    fn check(&self, name: &'static str, value: &DVec3) -> Result<(), SimError> {
        check_vector_within(name, *value, self.bounds, self.unit)
    }
}

impl KeyCheck<f64> for NumberRange {
    fn check(&self, name: &'static str, value: &f64) -> Result<(), SimError> {
        check_between(name, *value, self.bounds, self.unit)
    }
}

/// A list of points: at least one, at most `most`, each within `each`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointsRange {
    pub each: VectorRange,
    pub most: usize,
}

impl KeyCheck<Vec<DVec3>> for PointsRange {
    fn check(&self, name: &'static str, value: &Vec<DVec3>) -> Result<(), SimError> {
        if value.is_empty() {
            return Err(SimError::EmptyWaypoints);
        }
        if value.len() > self.most {
            return Err(SimError::TooMany {
                name,
                count: value.len(),
                limit: self.most,
            });
        }
        value
            .iter()
            .try_for_each(|point| self.each.check(name, point))
    }
}

/// A whole number from 1 to `most`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CountRange {
    pub most: usize,
    pub unit: &'static str,
}

impl KeyCheck<u32> for CountRange {
    fn check(&self, name: &'static str, value: &u32) -> Result<(), SimError> {
        check_positive(name, f64::from(*value))?;
        if *value as usize > self.most {
            return Err(SimError::OutOfRange {
                name,
                value: f64::from(*value),
                min: 1.0,
                max: self.most as f64,
                min_excluded: false,
                unit: self.unit,
            });
        }
        Ok(())
    }
}

/// A direction: a finite vector of length > 0, the length's error named `length_name`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Direction {
    pub length_name: &'static str,
}

impl KeyCheck<DVec3> for Direction {
    fn check(&self, name: &'static str, value: &DVec3) -> Result<(), SimError> {
        check_vector(name, *value)?;
        check_positive(self.length_name, value.length())
    }
}

/// A table of its own, which checks its keys itself (`[path.profile]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OwnTable;

/// Any position of a path, a workspace or a start point: [`MAX_POSITION_M`].
pub const POSITION: VectorRange = KeyRange::new(MAX_POSITION_M, "m");
/// A radius (a circle path's, a ball workspace's): at most [`MAX_POSITION_M`].
pub const RADIUS: NumberRange = KeyRange::new((0.0, MAX_POSITION_M), "m");
/// A hand force: [`MAX_HAND_FORCE_N`].
pub const HAND_FORCE: VectorRange = KeyRange::new(MAX_HAND_FORCE_N, "N");
/// A time of a path or a force profile (a line's travel, a circle's period, a ramp): [`PATH_TIME_RANGE_S`].
pub const PATH_TIME: NumberRange = KeyRange::new(PATH_TIME_RANGE_S, "s");
/// A path's speed: at most [`MAX_SPEED_M_PER_S`].
pub const PATH_SPEED: NumberRange = KeyRange::new((0.0, MAX_SPEED_M_PER_S), "m/s");
/// A sine force profile's frequency: at most [`MAX_FREQUENCY_HZ`].
pub const FREQUENCY: NumberRange = KeyRange::new((0.0, MAX_FREQUENCY_HZ), "Hz");
/// The waypoints of a path: positions, at most [`MAX_PATH_VERTICES`].
pub const WAYPOINTS: PointsRange = PointsRange {
    each: POSITION,
    most: MAX_PATH_VERTICES,
};
/// The passes of a raster path: at most [`MAX_PATH_VERTICES`].
pub const RASTER_LINES: CountRange = CountRange {
    most: MAX_PATH_VERTICES,
    unit: "lines",
};
/// A circle path's axis.
pub const CIRCLE_NORMAL: Direction = Direction {
    length_name: "path.normal (length)",
};
/// The simulated arm's mass: at most [`MAX_ARM_MASS_KG`].
pub const ARM_MASS: NumberRange = KeyRange::new((0.0, MAX_ARM_MASS_KG), "kg");
