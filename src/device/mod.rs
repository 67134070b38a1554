//! Haptic devices: the arms whose probe position feeds the servo loop and which render its force.
//!
//! Sits at both ends of the data flow in DESIGN.md section 5: a device reports the probe position to the
//! servo thread and receives the rendered force. [`sim`] is the in-process simulated arm used by scenarios,
//! tests and demos.

pub mod sim;
