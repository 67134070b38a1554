//! voxhap: a haptic proxy rendering server for volume data.
//!
//! Data flow (see ARCHITECTURE.md and docs/design.md, "Threads"): a device reports the probe position, the
//! haptic modes sample volumes ([`volume`]) around the proxy and emit haptic primitives ([`haptics`]),
//! the exact solver finds the proxy position where the primitives balance the virtual coupling, and
//! the coupling force goes back to the device.

pub mod api;
pub mod cli;
pub mod clock;
pub mod device;
pub mod haptics;
pub mod record;
pub mod server;
pub mod servo;
pub mod sim;
pub mod status;
pub mod view;
pub mod volume;

/// The Rust examples in the documentation pages, compiled (and, unless marked `no_run`, run) by
/// `cargo test --doc`, so a page cannot show code that no longer builds. Every fenced block without a
/// language in these pages is marked `text`, since rustdoc would take it for Rust.
#[cfg(doctest)]
mod docs_examples {
    #[doc = include_str!("../docs/serve.md")]
    struct Serve;
    #[doc = include_str!("../docs/scenarios.md")]
    struct Scenarios;
    #[doc = include_str!("../docs/sim-arm.md")]
    struct SimArm;
    #[doc = include_str!("../docs/recording.md")]
    struct Recording;
    #[doc = include_str!("../docs/firmware.md")]
    struct Firmware;
    #[doc = include_str!("../docs/devices/host.md")]
    struct DeviceLayer;
}
