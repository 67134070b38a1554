//! The Foxglove topics voxhap publishes, shared by the live view (`src/server/foxglove.rs`, over the
//! Foxglove WebSocket protocol) and the MCAP trace writer (`mcap_trace.rs`), so a recorded session opens in
//! Foxglove or Lichtblick with the same topics, frames and schemas as a live one.
//!
//! Messages are the Foxglove SDK's well-known schemas (`foxglove::messages`), protobuf-encoded through
//! the SDK's [`foxglove::Encode`] implementations:
//!
//! | topic | schema | content |
//! |---|---|---|
//! | [`PROBE_TOPIC`] | `foxglove.FrameTransform` | frame [`PROBE_FRAME`] in [`WORLD_FRAME`]: the device position (m) |
//! | [`PROXY_TOPIC`] | `foxglove.FrameTransform` | frame [`PROXY_FRAME`] in [`WORLD_FRAME`]: the proxy position (m) |
//! | [`FORCE_TOPIC`] | `foxglove.Vector3` | force sent to the device after safety (N) |
//!
//! The live view adds `/voxhap/primitives`, `/voxhap/bound` and `/voxhap/stats` (see the server module).
//! World space is voxhap's world space (RAS, metres); rotations are the identity.

use ::foxglove::messages::{FrameTransform, Quaternion, Timestamp, Vector3};
use glam::DVec3;

/// The probe (device) position as a transform of [`PROBE_FRAME`] in [`WORLD_FRAME`].
pub const PROBE_TOPIC: &str = "/voxhap/probe";
/// The proxy position as a transform of [`PROXY_FRAME`] in [`WORLD_FRAME`].
pub const PROXY_TOPIC: &str = "/voxhap/proxy";
/// The force sent to the device (N), as a `foxglove.Vector3`.
pub const FORCE_TOPIC: &str = "/voxhap/force";
/// The fixed frame everything is expressed in (voxhap world space, metres).
pub const WORLD_FRAME: &str = "world";
/// The frame that follows the probe.
pub const PROBE_FRAME: &str = "probe";
/// The frame that follows the proxy.
pub const PROXY_FRAME: &str = "proxy";

/// A Foxglove vector from a glam one.
pub fn vector3(v: DVec3) -> Vector3 {
    Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// A Foxglove timestamp `ns` nanoseconds after the Unix epoch (saturating at the protobuf range, which
/// ends in 2106).
pub fn timestamp_from_ns(ns: u64) -> Timestamp {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (ns % 1_000_000_000) as u32)
}

/// A transform of `child` in [`WORLD_FRAME`] at `position_m`, identity rotation, stamped `time_ns`.
/// Reuse one per topic and update it with [`set_translation`] to avoid rebuilding the frame names.
pub fn frame_transform(child: &str, position_m: DVec3, time_ns: u64) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp_from_ns(time_ns)),
        parent_frame_id: WORLD_FRAME.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Some(vector3(position_m)),
        rotation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// Moves `transform` to `position_m` at `time_ns` (no allocation).
pub fn set_translation(transform: &mut FrameTransform, position_m: DVec3, time_ns: u64) {
    transform.timestamp = Some(timestamp_from_ns(time_ns));
    transform.translation = Some(vector3(position_m));
}

#[cfg(test)]
mod tests {
    use super::*;
    use ::foxglove::{Decode, Encode};

    #[test]
    fn frame_transforms_round_trip_through_the_sdk_encoding() {
        let mut transform = frame_transform(PROBE_FRAME, DVec3::new(0.01, -0.02, 0.03), 5);
        set_translation(&mut transform, DVec3::new(0.5, 0.25, -0.125), 1_500_000_001);
        let mut bytes = Vec::new();
        transform.encode(&mut bytes).unwrap();
        let back = FrameTransform::decode(&bytes[..]).unwrap();
        assert_eq!(back, transform);
        assert_eq!(back.timestamp.unwrap().sec(), 1);
        assert_eq!(back.timestamp.unwrap().nsec(), 500_000_001);
        assert_eq!(back.parent_frame_id, "world");
        assert_eq!(back.child_frame_id, "probe");
        let schema = FrameTransform::get_schema().unwrap();
        assert_eq!(schema.name, "foxglove.FrameTransform");
        assert_eq!(schema.encoding, "protobuf");
        assert_eq!(FrameTransform::get_message_encoding(), "protobuf");
        assert_eq!(Vector3::get_schema().unwrap().name, "foxglove.Vector3");
    }

    #[test]
    fn timestamps_saturate_instead_of_wrapping() {
        let far = timestamp_from_ns(u64::MAX);
        assert_eq!(far.sec(), u32::MAX);
        assert!(far.nsec() < 1_000_000_000);
    }
}
