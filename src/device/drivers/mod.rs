//! Device drivers, one per family, each on a transport (src/device/transport) and each a
//! [`HapticDevice`](crate::device::HapticDevice):
//!
//! - [`protocol`]: voxhap's own wire protocol (protocol/SPEC.md) over serial or USB HID, for microcontroller arms
//!   and for `voxhap mock-device`;
//! - [`woodenhaptics`]: WoodenHaptics 1.5 over USB HID (motor currents out, encoder counts in, kinematics here);
//! - [`haply`]: Haply 2DIY over USB serial (pantograph, planar);
//! - [`replay`]: plays back the probe positions of a recorded force trace.

pub mod haply;
pub mod protocol;
pub mod replay;
pub mod woodenhaptics;

pub use haply::{Haply2Diy, Haply2DiyConfig};
pub use protocol::{HidLink, MessageLink, ProtocolConfig, ProtocolDevice, SerialLink};
pub use replay::{parse_replay_spec, ReplayDevice, ReplayOptions};
pub use woodenhaptics::{WoodenHaptics, WoodenHapticsConfig};
