//! CRTK over ROS 2 without a ROS install: `voxhap serve --ros2` publishes the servo session's pose, velocity,
//! wrenches and operating state as ROS 2 topics, over DDS with the pure-Rust `ros2-client` (RustDDS).
//!
//! Where it sits: like the OpenIGTLink and Foxglove outputs, it only reads the session's newest
//! [`voxhap_api::Snapshot`] (the servo thread's triple buffer, through a closure the caller gives). It runs
//! on a thread of its own at a rate derived from the servo rate ([`publish_period`]); a slow network or
//! subscriber makes it miss ticks, never the servo thread.
//!
//! - [`messages`]: the ROS 2 message types (`geometry_msgs`, `std_msgs`, `crtk_msgs`) laid out field by field
//!   as their `.msg` files, so serde writes the CDR that every ROS 2 node reads.
//! - [`crtk`]: one snapshot to the CRTK messages, and the CRTK operating state of an output state.
//! - [`topics`]: topic names, type names and QoS.
//! - [`output`]: the publishing thread.
//! - [`servo_cf`]: the force channel in (`/voxhap/servo_cf`, with `serve --external-force`).
//! - [`args`]: the `serve` flags (`--ros2`, `--ros2-domain`, `--ros2-localhost-only`).

pub mod args;
pub mod crtk;
pub mod error;
pub mod messages;
pub mod output;
pub mod servo_cf;
pub mod topics;

pub use args::{Ros2Args, Ros2Settings};
pub use error::Ros2Error;
pub use output::{publish_period, Ros2Output};
pub use servo_cf::{ExternalForceSink, ServoCfStats};
