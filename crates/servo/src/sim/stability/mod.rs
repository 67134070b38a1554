//! How stiff a wall each simulated arm holds, and what a local model costs: the measurements behind
//! `voxhap stability` and the tables of docs/stability.md and docs/local-model.md.
//!
//! - [`arms`]: the arms measured (the presets, with the figures they lack and where each comes from);
//! - [`judge`]: one short run at a stiffness and its verdict (passive or not), for a host that closes the
//!   contact loop with set-forces ([`LoopKind::Host`], through [`crate::sim::run`]) or a device that closes it
//!   with a local model at its own rate ([`LoopKind::Local`], through [`local`]);
//! - [`setup`]: the run every verdict is made on;
//! - [`search`]: the bisection for the largest passive stiffness;
//! - [`local`]: the headless host + device loop of a local-model device (the reference device loop of
//!   `voxhap-local` behind the protocol's device session, as `voxhap mock-device --local-model` runs it);
//! - [`stale`]: the force error of a model that is up to one host period old, along a scenario's path, and
//!   the bytes a model takes on the link.
//!
//! Everything here is deterministic: the same arguments give the same figures on any machine.

pub mod arms;
mod error;
pub mod judge;
pub mod local;
mod memory;
pub mod search;
pub mod setup;
pub mod stale;

pub use arms::{ArmCase, ARMS, DAMPING_ESTIMATE, MASS_ESTIMATE};
pub use error::StabilityError;
pub use judge::{judge, LoopKind, Verdict};
pub use memory::MemoryTrace;
pub use search::{bisect, largest_passive, Limit};
pub use setup::{PUSH_N, RUN_S};
pub use stale::{stale_force, StaleForce};
