//! The device side of voxhap's local-model capability (protocol/SPEC.md section 10): a control loop a firmware
//! links to render contact at its own rate. Each cycle it reads the handle, solves the proxy against the host's
//! latest local model with voxhap's certified solver, and applies the coupling force with its passivity
//! controller's damping (in the model's passivity mode), clamped, ramped and slew-limited; a model past its expiry
//! ramps the force to zero by itself. docs/local-model.md has its use, its
//! guarantees and its measured cost per solve.
//!
//! `#![no_std]` and allocation-free: the solver's workspace lives in fixed arrays sized for the protocol's
//! maximum of three non-directed primitives ([`voxhap_protocol::MAX_LOCAL_PRIMITIVES`]), and its pass budget
//! ([`DEVICE_SOLVER_CONFIG`]) bounds the time of every solve. A crate of its own rather than a module of
//! `voxhap-solver`: it needs the protocol's message types and session, and the solver (below `voxhap-core`)
//! must not depend on the device protocol (which sits under `voxhap-device`).
//!
//! Where it sits: above `voxhap-protocol` (the [`DeviceSession`] that owns the watchdog and the messages) and
//! `voxhap-solver`; `voxhap mock-device` runs it, as a firmware would.
//!
//! [`DeviceSession`]: voxhap_protocol::DeviceSession
#![no_std]
#![deny(missing_docs)]

#[cfg(test)]
extern crate std;

mod device_loop;
mod passivity;
mod ramp;

pub use device_loop::{LocalLoop, LoopConfig, DEVICE_SOLVER_CONFIG};
pub use passivity::{DevicePassivity, PassivityTotals};
pub use ramp::{Ramp, ENGAGE_BELOW_N, ENGAGE_US, SLEW_N_PER_S};
