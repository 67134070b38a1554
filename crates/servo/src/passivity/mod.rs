//! Passive rendering of the coupling: a passivity observer and controller, and the passive introduction of
//! changes made while the probe is in contact.
//!
//! Where it sits in a servo tick (`voxhap serve`'s [`crate::runner`] and `voxhap sim`'s [`crate::sim::runner`]
//! alike): the pure tick renders the proxy; [`transition`] decides which point the coupling spring pulls
//! towards (the proxy, or a virtual proxy while a change made in contact is introduced); the coupling damping
//! is added; [`controller`] observes the energy of what was sent and reported and adds its damping force; then
//! the safety pipeline (non-finite check, clamp, engage rule, slew limit, watchdog) and the device. The observer
//! books the force the safety pipeline actually sent, so what the pipeline cut is counted exactly.
//!
//! Why here (crate `voxhap-servo`, not `voxhap-core`): the observer needs what only the servo loop knows (the
//! force the device was sent after the safety pipeline, the reported probe, the device's latency in ticks),
//! and the pure tick in `voxhap-core` stays a function of the scene and the probe.

pub mod controller;
pub mod latency;
pub mod link_delay;
pub mod link_stats;
pub mod settings;
#[cfg(test)]
mod test_link;
pub mod transition;

pub use controller::{PassivityController, PassivityTotals, MAX_LATENCY_TICKS};
pub use latency::{LatencyOrigin, ObserverLatency};
pub use link_delay::{LinkFollower, PairingChange};
pub use link_stats::LinkDelayStats;
pub use settings::{PassivityMode, PassivitySettings, PassivitySettingsError};
pub use transition::CouplingTransition;
