//! Haptic devices: the arms whose probe position feeds the servo loop and which render its force.
//!
//! Sits at both ends of the data flow in docs/design.md ("Threads"): a device reports the probe position to the
//! servo thread and receives the rendered force. The layers, bottom up:
//!
//! - [`transport`]: bytes or reports to and from somewhere (serial port or pseudo-terminal, USB HID; with the
//!   `test-support` feature also in-memory pipes and scripted test doubles);
//! - [`drivers`]: one per device family, each on a transport (voxhap's own protocol over serial or HID,
//!   WoodenHaptics 1.5, Haply 2DIY, Novint Falcon); all implement [`HapticDevice`] (`traits.rs`);
//! - [`Lifecycle`]: open → enabled → open → closed, enforced once for every driver;
//! - [`plausibility`] and [`safety`]: the host's safety pipeline, applied to every sample a device reports and
//!   to every force before any driver;
//! - [`dof`]: which components a 1- or 2-DOF device uses (SPEC 6.8); the others are dropped on the way in and
//!   out;
//! - [`supervisor`]: lifecycle, safety, link health, the device's drive state (faults, recovery) and
//!   reconnection: the one object the servo loop talks to;
//! - [`local_offer`]: the tick's local model for a device that renders contact itself (SPEC section 10);
//! - [`mock`]: the simulated arm behind the real protocol, with fault injection (`voxhap mock-device`);
//! - [`latency`]: how late each real device's state is on its link, from its vendor's documents;
//! - [`discovery`]: which serial ports and HID devices are present, and which ones voxhap recognises.
//!
//! [`sim`] is the in-process simulated arm used by scenarios, tests and demos.

pub mod discovery;
pub mod dof;
pub mod drivers;
pub mod error;
pub mod info;
pub mod latency;
pub mod lifecycle;
pub mod local_offer;
pub mod mapping;
pub mod mock;
pub mod physics;
pub mod plausibility;
pub mod profile;
pub mod safety;
pub mod sim;
pub mod supervisor;
mod supervisor_config;
mod supervisor_tick;
mod traits;
pub mod transport;

pub use error::{DeviceError, Error, ErrorKind};
pub use info::{DeviceEvent, DeviceInfo, DeviceState, DeviceStatus, SurplusCount};
pub use lifecycle::{Lifecycle, LifecycleError, LifecycleState};
pub use traits::{EmergencyStop, HapticDevice};
