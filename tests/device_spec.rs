//! The real host (`voxhap serve --device serial:PTY`) against a device written from protocol/SPEC.md alone
//! (tests/util/spec_device.rs), checked from the device's side: every assertion is on what the device received.
//!
//! Each test runs `serve` against a `SpecDevice` that may misbehave (refuse Enable, fault, go silent, glitch,
//! corrupt its replies) and asserts the host behaviour that protocol/SPEC.md section 7.1 ("Host behaviour a
//! firmware can rely on") promises. The tests take turns (one `serve` at a time) so that timing on a loaded 2-core
//! machine stays reasonable; every bound is count-based and generous.
//!
//! By topic: [`vectors`] checks the double itself; [`session`] a clean session, the handshake and stopping;
//! [`faults`] faults and refusals; [`external_force`] the external force input over the WebSocket API; [`link`] link health; [`limits`] plausibility, limits and fewer degrees of
//! freedom; [`misbehaviour`] random misbehaviour; [`stall`] the stall monitor. The harness (how `serve` is run,
//! waited for and checked) is tests/util/spec_serve.rs.

mod external_force;
mod faults;
mod limits;
mod link;
mod misbehaviour;
mod session;
mod stall;
mod vectors;
