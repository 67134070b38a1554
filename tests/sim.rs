//! `voxhap sim` and the sims/ scenarios end to end: every shipped scenario runs, every claim sims/README.md
//! makes about a scenario is asserted here on its trace (the sphere yields at s, friction slips at mu N,
//! the vortex proxy stays on the core, the multi-modal scene is certified on every tick and the constraint
//! approach sinks), runs are byte-for-byte deterministic, and the MRI brain sim runs on the template
//! shipped in data/. Keep sims/README.md in step with the numbers asserted here.
//!
//! By topic: [`scenarios`] the scenarios' claims; [`cli`] determinism and the command line; [`limits`] refused
//! values, the size limit and the solver budget. The helpers are tests/util/sim.rs.

mod cli;
mod limits;
mod local_model;
mod mid_contact;
mod passivity;
mod scenarios;
mod shipped_passive;
mod stability;
mod sweep;
