//! Why a simulated arm could not be built or stepped ([`SimError`]), and numbers written as a reader does.

/// `> 0 and at most 100` or `from 0.001 to 1000000`: a range as an error message gives it.
fn describe_range(min: f64, max: f64, min_excluded: bool) -> String {
    let (min, max) = (readable(min), readable(max));
    if min_excluded {
        format!("a number > {min} and at most {max}")
    } else {
        format!("a number from {min} to {max}")
    }
}

/// A number as a reader writes it: `0.02`, `10000000`, but `1e300` and `1e-300` (Rust's `Display` writes
/// every digit of a large float).
pub fn readable(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e16 {
        format!("{x:.0}")
    } else if x != 0.0 && !(1e-3..=1e7).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Why a simulated arm could not be built or stepped. Copy and allocation-free, so the servo thread can
/// return it.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A scalar parameter is out of range.
    #[error("simulated arm parameter {name} = {value} must be {requirement}")]
    InvalidParameter {
        /// Parameter name as written in the scenario file.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What it must be.
        requirement: &'static str,
    },
    /// A vector parameter has a NaN or infinite component.
    #[error("simulated arm parameter {name} has a non-finite component")]
    NonFiniteVector {
        /// Parameter name as written in the scenario file.
        name: &'static str,
    },
    /// A finite scalar parameter outside the range in which a run means something (the limits are in
    /// [`keys`](super::keys)'s constants): it would overflow to infinity or NaN within the run, or ask for
    /// more than any arm or hand can do.
    #[error(
        "simulated arm parameter {name} = {} is out of range: give {} {unit}",
        readable(*.value),
        describe_range(*.min, *.max, *.min_excluded)
    )]
    OutOfRange {
        /// Parameter name as written in the scenario file.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// Smallest allowed value (excluded when `min_excluded`).
        min: f64,
        /// Largest allowed value.
        max: f64,
        min_excluded: bool,
        unit: &'static str,
    },
    /// A finite vector parameter with a component larger than its limit.
    #[error(
        "simulated arm parameter {name} has a component of {} {unit}, out of range: each of x, y, z \
         must be from -{} to {} {unit}",
        readable(*.value),
        readable(*.limit),
        readable(*.limit)
    )]
    VectorOutOfRange {
        /// Parameter name as written in the scenario file.
        name: &'static str,
        /// The offending component.
        value: f64,
        /// Largest allowed size of a component.
        limit: f64,
        unit: &'static str,
    },
    /// A list (waypoints) longer than the path may walk every substep.
    #[error("simulated arm parameter {name} has {count} entries, more than the {limit} allowed")]
    TooMany {
        /// Parameter name as written in the scenario file.
        name: &'static str,
        count: usize,
        limit: usize,
    },
    /// A waypoint path with no points.
    #[error("simulated arm parameter path.points_m: a waypoints path needs at least one point")]
    EmptyWaypoints,
    /// The workspace box has `min_m` above `max_m` on some axis.
    #[error("simulated arm parameter arm.workspace.max_m: must be >= min_m on every axis (a box)")]
    InvertedBox,
    /// `step` got a non-finite time or a non-positive or non-finite tick length.
    #[error("simulated arm step: t_s = {t_s} and dt_s = {dt_s} must be finite with dt_s > 0")]
    InvalidTime {
        /// Tick start time given (s).
        t_s: f64,
        /// Tick length given (s).
        dt_s: f64,
    },
    /// The physics substep is too long for the stiffness and damping: raise `substeps_per_tick`.
    #[error(
        "simulated arm substep {substep_s} s exceeds the stable limit {max_substep_s} s: \
         raise arm.substeps_per_tick or lower the stiffness"
    )]
    SubstepTooLong {
        /// The substep asked for (s).
        substep_s: f64,
        /// The longest stable substep (s).
        max_substep_s: f64,
    },
    /// `period_jitter_s` is half a tick or more: sample instants could cross.
    #[error(
        "simulated arm parameter arm.period_jitter_s = {jitter_s} must be below half the tick ({dt_s} s)"
    )]
    JitterTooLarge {
        /// The jitter given (s).
        jitter_s: f64,
        /// The tick (s).
        dt_s: f64,
    },
}
