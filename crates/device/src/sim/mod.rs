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
pub mod bisect;
pub mod effects;
mod error;
pub mod keys;
mod path;
pub mod preset;
mod tagged;
pub mod zoh;
pub mod zoh_boundary;
#[cfg(any(test, feature = "test-support"))]
pub mod zoh_exact;

pub use arm::{
    ArmParams, HandParams, LocalModelSim, MissingArmKey, SimArm, SimArmConfig, StepOutcome,
    Workspace, WorkspaceShape, MAX_LOCAL_RATE_HZ,
};
pub(crate) use arm::{
    DEFAULT_SUBSTEPS_PER_TICK, DEFAULT_WALL_DAMPING_N_S_PER_M, DEFAULT_WALL_STIFFNESS_N_PER_M,
};
pub use effects::DeviceEffects;
pub use error::{readable, SimError};
pub use keys::{
    MAX_ARM_MASS_KG, MAX_FREQUENCY_HZ, MAX_HAND_FORCE_N, MAX_PATH_VERTICES, MAX_POSITION_M,
    MAX_SPEED_M_PER_S, PATH_TIME_RANGE_S,
};
pub use path::{ForceProfile, ForceProfileShape, HandDrive, HandPath, HandPathKind};
pub use preset::{ArmPreset, PresetFigures};
pub use tagged::TaggedTableError;
pub use zoh_boundary::{zoh_boundary, ZohError, ZohLoop};

#[cfg(test)]
#[path = "boundary_tests.rs"]
mod boundary_tests;
