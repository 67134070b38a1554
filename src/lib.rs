//! voxhap: a haptic proxy rendering server for volume data.
//!
//! Data flow (see ARCHITECTURE.md and DESIGN.md section 5): a device reports the probe position, the
//! haptic modes sample volumes ([`volume`]) around the proxy and emit haptic primitives ([`haptics`]),
//! the exact solver finds the proxy position where the primitives balance the virtual coupling, and
//! the coupling force goes back to the device.

pub mod cli;
pub mod clock;
pub mod device;
pub mod haptics;
pub mod record;
pub mod server;
pub mod servo;
pub mod sim;
pub mod volume;
