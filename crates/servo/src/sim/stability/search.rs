//! The largest passive stiffness: a bisection on [`super::judge`]'s verdicts.

use super::arms::ArmCase;
use super::error::StabilityError;
use super::judge::{judge, LoopKind};

/// The largest passive stiffness in `[low, high]` (passive at `low`, not at `high`): bisected on a log scale
/// until `high / low <= 1 + tolerance`; the last passive stiffness is returned.
pub fn bisect(
    arm: &ArmCase,
    kind: LoopKind,
    low_n_per_m: f64,
    high_n_per_m: f64,
    tolerance: f64,
) -> Result<f64, StabilityError> {
    check(low_n_per_m, high_n_per_m, tolerance)?;
    let (mut lo, mut hi) = (low_n_per_m, high_n_per_m);
    while hi / lo > 1.0 + tolerance {
        let mid = (lo * hi).sqrt();
        if judge(arm, kind, mid)?.passive() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(lo)
}

fn check(low: f64, high: f64, tolerance: f64) -> Result<(), StabilityError> {
    if !(low.is_finite() && high.is_finite() && low > 0.0 && low < high) {
        return Err(StabilityError::Range {
            low_n_per_m: low,
            high_n_per_m: high,
        });
    }
    if !(1e-4..=0.5).contains(&tolerance) {
        return Err(StabilityError::Tolerance(tolerance));
    }
    Ok(())
}

/// What a search found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Limit {
    /// The largest passive stiffness, N/m (to the search's tolerance).
    Found(f64),
    /// Passive even at the top of the search range, N/m.
    AtLeast(f64),
    /// Not passive even at the bottom of the search range, N/m.
    Below(f64),
}

impl Limit {
    /// The figure: the stiffness found, or the end of the range it lies beyond.
    pub fn n_per_m(&self) -> f64 {
        match *self {
            Limit::Found(k) | Limit::AtLeast(k) | Limit::Below(k) => k,
        }
    }
}

/// The largest passive stiffness of `arm` under `kind`, searched from a quarter to `ceiling` times the loop's
/// passivity bound ([`LoopKind::bound_n_per_m`]) to `tolerance`.
pub fn largest_passive(
    arm: &ArmCase,
    kind: LoopKind,
    ceiling: f64,
    tolerance: f64,
) -> Result<Limit, StabilityError> {
    let bound = kind.bound_n_per_m(arm.damping_n_s_per_m);
    let (low, high) = (bound / 4.0, bound * ceiling);
    check(low, high, tolerance)?;
    if !judge(arm, kind, low)?.passive() {
        return Ok(Limit::Below(low));
    }
    if judge(arm, kind, high)?.passive() {
        return Ok(Limit::AtLeast(high));
    }
    bisect(arm, kind, low, high, tolerance).map(Limit::Found)
}
