//! Transfer functions: piecewise-linear maps from a data value to a primitive strength in newtons.
//!
//! Every volume-driven haptic mode ([`super`]) turns what it samples (a density, a speed, a vorticity, a
//! gradient magnitude) into a strength with one of these. A transfer function is a list of breakpoints
//! `(x_j, y_j)`, `x` in the data's own unit and `y` in newtons, with `x` strictly increasing. Between
//! breakpoints it interpolates linearly; below the first and above the last it holds the end value
//! (clamped, never extrapolated). With one breakpoint it is constant.
//!
//! In a scenario file a transfer function is a list of pairs, `transfer = [[0.2, 0.0], [0.6, 2.5]]`.
//! Validation (at load time, never on the servo thread) requires at least one breakpoint, finite numbers,
//! strictly increasing `x` within [`MAX_TRANSFER_VALUE`] of 0 and `y` from 0 to [`MAX_STRENGTH_N`], so
//! [`TransferFunction::eval`] always returns a finite strength `>= 0` for a finite input, and 0 for a
//! non-finite one. It does not allocate.

use super::limits::{readable, MAX_STRENGTH_N, MAX_TRANSFER_VALUE};
use serde::{Deserialize, Serialize};

/// Why a transfer function was refused. Messages read well after a field path, e.g.
/// `modes[1].transfer: x must increase (breakpoint 2: 0.3 after 0.5)`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TransferError {
    #[error("needs at least one breakpoint [x, newtons]")]
    Empty,
    #[error("breakpoint {index} is not finite: [{x}, {y}]")]
    NonFinite { index: usize, x: f64, y: f64 },
    #[error("x must increase (breakpoint {index}: {x} after {previous_x})")]
    NotIncreasing {
        index: usize,
        previous_x: f64,
        x: f64,
    },
    #[error("x must be from -{max} to {max} (breakpoint {index}: {})", readable(*.x), max = readable(MAX_TRANSFER_VALUE))]
    ValueOutOfRange { index: usize, x: f64 },
    #[error("strength must be from 0 to {max} N (breakpoint {index}: {})", readable(*.y), max = readable(MAX_STRENGTH_N))]
    NegativeStrength { index: usize, y: f64 },
    #[error("strength must be from 0 to {max} N (breakpoint {index}: {})", readable(*.y), max = readable(MAX_STRENGTH_N))]
    TooStrong { index: usize, y: f64 },
}

/// A validated piecewise-linear transfer function, value -> newtons, clamped at both ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Vec<[f64; 2]>", into = "Vec<[f64; 2]>")]
pub struct TransferFunction {
    /// Breakpoints `[x, newtons]`, `x` strictly increasing.
    points: Vec<[f64; 2]>,
}

impl TransferFunction {
    /// Checks and wraps the breakpoints `[x, newtons]`.
    pub fn new(points: Vec<[f64; 2]>) -> Result<Self, TransferError> {
        if points.is_empty() {
            return Err(TransferError::Empty);
        }
        for (index, &[x, y]) in points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                return Err(TransferError::NonFinite { index, x, y });
            }
            if x.abs() > MAX_TRANSFER_VALUE {
                return Err(TransferError::ValueOutOfRange { index, x });
            }
            if y < 0.0 {
                return Err(TransferError::NegativeStrength { index, y });
            }
            if y > MAX_STRENGTH_N {
                return Err(TransferError::TooStrong { index, y });
            }
            if index > 0 {
                let previous_x = points[index - 1][0];
                if x <= previous_x {
                    return Err(TransferError::NotIncreasing {
                        index,
                        previous_x,
                        x,
                    });
                }
            }
        }
        Ok(Self { points })
    }

    /// A constant strength.
    pub fn constant(strength_n: f64) -> Result<Self, TransferError> {
        Self::new(vec![[0.0, strength_n]])
    }

    /// A ramp from 0 N at `x0` to `strength_n` at `x1` (clamped outside).
    pub fn ramp(x0: f64, x1: f64, strength_n: f64) -> Result<Self, TransferError> {
        Self::new(vec![[x0, 0.0], [x1, strength_n]])
    }

    /// The breakpoints `[x, newtons]`.
    pub fn points(&self) -> &[[f64; 2]] {
        &self.points
    }

    /// The same breakpoints with every strength multiplied by `factor` and held at [`MAX_STRENGTH_N`] (a
    /// factor that is not a finite number >= 0 is taken as 0, so the result is always valid). `scaled(0.0)` is
    /// the mode switched off.
    pub fn scaled(&self, factor: f64) -> Self {
        let factor = if factor.is_finite() && factor >= 0.0 {
            factor
        } else {
            0.0
        };
        let points = self
            .points
            .iter()
            .map(|&[x, y]| [x, (y * factor).min(MAX_STRENGTH_N)])
            .collect();
        Self { points }
    }

    /// The largest strength the function can return (N).
    pub fn max_strength_n(&self) -> f64 {
        self.points.iter().map(|p| p[1]).fold(0.0, f64::max)
    }

    /// The strength at `value` (N): linear between breakpoints, clamped at the ends, 0 for a non-finite
    /// `value`. Binary search, no allocation.
    pub fn eval(&self, value: f64) -> f64 {
        if !value.is_finite() {
            return 0.0;
        }
        let points = &self.points;
        let first = points[0];
        let last = points[points.len() - 1];
        if value <= first[0] {
            return first[1];
        }
        if value >= last[0] {
            return last[1];
        }
        // points[upper - 1].x < value < points[upper].x
        let upper = points.partition_point(|p| p[0] < value);
        let [x0, y0] = points[upper - 1];
        let [x1, y1] = points[upper];
        let t = (value - x0) / (x1 - x0);
        // Convex combination of two non-negative finite numbers: finite and >= 0.
        (y0 + t * (y1 - y0)).max(0.0)
    }
}

impl TryFrom<Vec<[f64; 2]>> for TransferFunction {
    type Error = TransferError;

    fn try_from(points: Vec<[f64; 2]>) -> Result<Self, TransferError> {
        Self::new(points)
    }
}

impl From<TransferFunction> for Vec<[f64; 2]> {
    fn from(tf: TransferFunction) -> Self {
        tf.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn interpolates_and_clamps() {
        let tf = TransferFunction::new(vec![[0.2, 0.0], [0.6, 2.0], [1.0, 3.0]]).unwrap();
        assert_eq!(tf.eval(-5.0), 0.0);
        assert_eq!(tf.eval(0.2), 0.0);
        assert!((tf.eval(0.4) - 1.0).abs() < 1e-15);
        assert!((tf.eval(0.8) - 2.5).abs() < 1e-15);
        assert_eq!(tf.eval(7.0), 3.0);
        assert_eq!(tf.eval(f64::NAN), 0.0);
        assert_eq!(tf.eval(f64::INFINITY), 0.0);
        assert_eq!(tf.max_strength_n(), 3.0);
    }

    #[test]
    fn scaling_keeps_the_breakpoints() {
        let tf = TransferFunction::new(vec![[0.0, 0.0], [0.1, 0.4]]).unwrap();
        let off = tf.scaled(0.0);
        assert_eq!(off.points(), &[[0.0, 0.0], [0.1, 0.0]]);
        assert_eq!(tf.scaled(2.5).points(), &[[0.0, 0.0], [0.1, 1.0]]);
        // Not a finite factor >= 0: switched off, never a negative or infinite strength.
        for bad in [f64::NAN, -1.0, f64::NEG_INFINITY, f64::INFINITY] {
            assert_eq!(tf.scaled(bad).max_strength_n(), 0.0);
        }
        let huge = TransferFunction::constant(1e6).unwrap().scaled(1e10);
        assert_eq!(huge.max_strength_n(), 1e6);
    }

    #[test]
    fn one_breakpoint_is_constant() {
        let tf = TransferFunction::constant(1.5).unwrap();
        assert_eq!(tf.eval(-1e9), 1.5);
        assert_eq!(tf.eval(1e9), 1.5);
    }

    #[test]
    fn validation_names_the_problem() {
        assert_eq!(TransferFunction::new(vec![]), Err(TransferError::Empty));
        assert_eq!(
            TransferFunction::new(vec![[0.5, 1.0], [0.3, 2.0]])
                .unwrap_err()
                .to_string(),
            "x must increase (breakpoint 1: 0.3 after 0.5)"
        );
        assert!(matches!(
            TransferFunction::new(vec![[0.5, 1.0], [0.5, 2.0]]),
            Err(TransferError::NotIncreasing { index: 1, .. })
        ));
        assert!(matches!(
            TransferFunction::new(vec![[0.0, -1.0]]),
            Err(TransferError::NegativeStrength { index: 0, .. })
        ));
        assert!(matches!(
            TransferFunction::new(vec![[0.0, 1.0], [f64::NAN, 1.0]]),
            Err(TransferError::NonFinite { index: 1, .. })
        ));
        // The documented limits: 1e6 N and |x| <= 1e300 are accepted, just beyond them refused.
        assert!(TransferFunction::new(vec![[-1e300, 0.0], [1e300, 1e6]]).is_ok());
        assert_eq!(
            TransferFunction::new(vec![[0.0, 1.0], [1.0, 1.0000001e6]])
                .unwrap_err()
                .to_string(),
            "strength must be from 0 to 1000000 N (breakpoint 1: 1000000.1)"
        );
        assert_eq!(
            TransferFunction::new(vec![[0.0, -1.0]])
                .unwrap_err()
                .to_string(),
            "strength must be from 0 to 1000000 N (breakpoint 0: -1)"
        );
        assert_eq!(
            TransferFunction::new(vec![[-1e308, 0.0], [0.0, 1.0]])
                .unwrap_err()
                .to_string(),
            "x must be from -1e300 to 1e300 (breakpoint 0: -1e308)"
        );
    }

    #[test]
    fn breakpoints_at_the_value_limit_give_finite_strengths_between_them() {
        // The span of the two breakpoints is 2e300 (finite), so the interpolation is exact: halfway is half.
        let tf = TransferFunction::new(vec![[-1e300, 0.0], [1e300, 2.0]]).unwrap();
        assert_eq!(tf.eval(0.0), 1.0);
        assert_eq!(tf.eval(9e299), 1.9);
    }

    #[test]
    fn deserialises_from_pairs_and_rejects_bad_lists() {
        #[derive(Deserialize)]
        struct Holder {
            transfer: TransferFunction,
        }
        let ok: Holder = toml::from_str("transfer = [[0.0, 0.0], [1.0, 2.0]]").unwrap();
        assert_eq!(ok.transfer.eval(0.5), 1.0);
        let err = toml::from_str::<Holder>("transfer = [[1.0, 0.0], [0.0, 2.0]]")
            .err()
            .unwrap();
        assert!(err.to_string().contains("x must increase"), "{err}");
    }

    proptest! {
        /// Any list of pairs either is refused or gives finite, non-negative strengths bounded by the
        /// largest breakpoint strength, for any input (the decoder never panics).
        #[test]
        fn eval_is_finite_nonnegative_and_bounded(
            points in proptest::collection::vec((any::<f64>(), any::<f64>()), 0..8),
            sorted in any::<bool>(),
            inputs in proptest::collection::vec(any::<f64>(), 1..16),
        ) {
            let mut points: Vec<[f64; 2]> = points.into_iter().map(|(x, y)| [x, y]).collect();
            if sorted {
                points.sort_by(|a, b| a[0].total_cmp(&b[0]));
                for p in &mut points {
                    p[1] = p[1].abs() % 1e6;
                }
            }
            if let Ok(tf) = TransferFunction::new(points) {
                let max = tf.max_strength_n();
                for v in inputs {
                    let s = tf.eval(v);
                    prop_assert!(s.is_finite() && s >= 0.0 && s <= max * (1.0 + 1e-12), "{s} at {v}");
                }
            }
        }

        /// Between two breakpoints the function is monotone in x when the strengths are.
        #[test]
        fn ramp_is_monotone(a in -10.0..10.0f64, b in 0.001..10.0f64, s in 0.0..100.0f64, v in -20.0..20.0f64, dv in 0.0..1.0f64) {
            let tf = TransferFunction::ramp(a, a + b, s).unwrap();
            prop_assert!(tf.eval(v) <= tf.eval(v + dv) + 1e-12);
        }
    }
}
