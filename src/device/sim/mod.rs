//! The simulated arm: a point mass moved by a virtual hand, feeling the rendered force.
//!
//! In the data flow of docs/design.md ("Threads") the simulated arm stands in for a real device: each servo tick
//! the loop reads [`SimArm::position_m`] as the probe position, computes the force, and hands it back with
//! [`SimArm::step`], which advances the arm's physics by one tick. Time is passed in, so runs are
//! deterministic and can go faster than real time.
//!
//! Model (all SI): the end effector is a point mass `m` with viscous damping `b_arm` to ground. Three
//! forces act on it besides damping:
//!
//! * the rendered force from the haptic loop, held constant over the tick (zero-order hold, as a real
//!   device's amplifier does);
//! * the virtual hand ([`HandParams`], [`HandPath`]): a spring-damper `k_h (target - x) + b_h (v_target - v)`
//!   towards a scripted moving target, or a scripted force profile;
//! * the workspace limit ([`Workspace`]): a stiff one-sided wall. With `d` the distance outside the
//!   workspace and `n` the outward normal, the wall pushes with `max(0, k_w d + b_w v.n)` along `-n`, so it
//!   acts only while the arm is outside and never pulls inward. At rest under a force `F` pushing outward
//!   the arm sits `F / k_w` outside; an arm arriving with speed can overshoot further, by at most
//!   `sqrt(2 E / k_w)` where `E` is its kinetic plus hand-spring energy (every damper only dissipates).
//!   These are the documented tolerances of the limit.
//!
//! Integration is semi-implicit (symplectic) Euler with `substeps_per_tick` equal substeps of
//! `h = dt / substeps`: `v += h a(x, v, t)`, then `x += h v`. The hand target is evaluated at each substep's
//! start time. For `m x'' = -k x - b x'` this is stable when `h^2 k/m < 4 - 2 h b/m`; [`SimArm::new`]
//! computes the conservative limit `h <= min(sqrt(m / k_total), m / b_total)` (with `k_total = k_h + k_w`,
//! `b_total = b_arm + b_h + b_w`) and [`SimArm::step`] refuses longer substeps.
//!
//! Steady-state behaviour (what the tests check): following a target that moves at constant velocity `V`,
//! the arm settles at the target's velocity and lags it by `b_arm V / k_h` (the arm's damping has to be
//! pulled by the hand spring); holding a fixed target under a constant rendered force `F`, it settles at
//! `target + F / k_h`. The rendered force's own stiffness (the coupling) is outside this model; the sampled
//! loop's stability is the servo's business.

mod arm;
mod path;
mod tagged;

pub use arm::{
    ArmParams, HandParams, SimArm, SimArmConfig, StepOutcome, Workspace, WorkspaceShape,
};
pub use path::{
    ForceProfile, ForceProfileShape, HandDrive, HandPath, HandPathKind, MAX_ARM_MASS_KG,
    MAX_FREQUENCY_HZ, MAX_HAND_FORCE_N, MAX_PATH_VERTICES, MAX_POSITION_M, MAX_SPEED_M_PER_S,
    PATH_TIME_RANGE_S,
};

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
    /// [`path`]'s constants): it would overflow to infinity or NaN within the run, or ask for more than any
    /// arm or hand can do.
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
}
