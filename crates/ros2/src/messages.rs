//! The ROS 2 message types voxhap publishes, each a struct whose fields follow its `.msg` definition in
//! order: serde then writes exactly the CDR (XCDR1, little endian) a ROS 2 node reads for that type, since
//! ROS 2's DDS mapping turns each `.msg` into an IDL struct with the same fields in the same order
//! (`package::msg::dds_::Type_`).
//!
//! Sources: `std_msgs/Header` and `builtin_interfaces/Time` (ROS 2 common_interfaces and rcl_interfaces),
//! `geometry_msgs` (common_interfaces), `crtk_msgs/OperatingState` (crtk_msgs 1.3.0:
//! `std_msgs/Header header, string state, bool is_homed, bool is_busy`).

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`: seconds and nanoseconds since the Unix epoch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From nanoseconds since the Unix epoch (saturating at `i32::MAX` seconds, as ROS 2 does).
    pub fn from_unix_ns(ns: u64) -> Time {
        let sec = ns / 1_000_000_000;
        Time {
            sec: i32::try_from(sec).unwrap_or(i32::MAX),
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/Point` and `geometry_msgs/Vector3` (the same three doubles).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl From<DVec3> for Vector3 {
    fn from(v: DVec3) -> Vector3 {
        Vector3 {
            x: v.x,
            y: v.y,
            z: v.z,
        }
    }
}

/// `geometry_msgs/Quaternion` (x, y, z, w).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Quaternion {
    /// No rotation.
    pub const IDENTITY: Quaternion = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    };
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// `geometry_msgs/TwistStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}

/// `geometry_msgs/Wrench`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    pub force: Vector3,
    pub torque: Vector3,
}

/// `geometry_msgs/WrenchStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WrenchStamped {
    pub header: Header,
    pub wrench: Wrench,
}

/// `crtk_msgs/OperatingState` (crtk_msgs 1.3.0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OperatingState {
    pub header: Header,
    /// `DISABLED`, `ENABLED`, `PAUSED` or `FAULT`.
    pub state: String,
    pub is_homed: bool,
    pub is_busy: bool,
}
