//! voxhap: a haptic proxy rendering server for volume data. This crate is the `voxhap` command line
//! ([`cli`]) and, for tests, benchmarks and the Python package, one place to reach the workspace's crates
//! under their module names: [`haptics`] and [`volume`] (voxhap-core, voxhap-solver, voxhap-io),
//! [`device`], [`api`], [`view`], [`record`], [`servo`] and [`sim`], [`server`]. ARCHITECTURE.md draws how
//! they depend on each other.

pub mod cli;

pub use voxhap_api as api;
pub use voxhap_core::{clock, status};
pub use voxhap_device as device;
pub use voxhap_record as record;
pub use voxhap_server as server;
pub use voxhap_servo as servo;
pub use voxhap_servo::sim;
pub use voxhap_view as view;

/// Haptic rendering: voxhap-core's modes and tick, voxhap-solver's primitives and solver, and the solve-scene
/// files of voxhap-io.
pub mod haptics {
    pub use voxhap_core::haptics::*;
    pub use voxhap_io::scene;
}

/// Volumes (voxhap-core) and the volume files they are read from (voxhap-io).
pub mod volume {
    pub use voxhap_core::volume::*;
    pub use voxhap_io as io;
}

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
