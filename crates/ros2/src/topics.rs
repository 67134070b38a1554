//! Topic names, type names and QoS, as a ROS 2 node would declare them.
//!
//! ROS 2 maps a topic `/voxhap/measured_cp` to the DDS topic `rt/voxhap/measured_cp` and a message type
//! `geometry_msgs/msg/PoseStamped` to the DDS type `geometry_msgs::msg::dds_::PoseStamped_` (ROS 2 design,
//! "Topic and Service name mapping to DDS"); ros2-client does both.
//!
//! QoS: the streams use ROS 2's default publisher profile (reliable, volatile, keep last 10): a reliable
//! writer serves both reliable and best-effort readers (`ros2 topic echo`, rviz, a `sensor_data`
//! subscriber), where a best-effort one would be refused by a reliable reader. The operating state is
//! reliable, transient local, keep last 1, like a latched topic: a subscriber that joins late gets the
//! current state at once (a volatile subscriber is compatible with it too).

use ros2_client::{
    qos::{Durability, History, WhenFull},
    MessageTypeName, QosProfile,
};

/// The namespace every topic is in.
pub const NAMESPACE: &str = "/voxhap";
/// The node's name (`/voxhap/voxhap` in `ros2 node list`).
pub const NODE_NAME: &str = "voxhap";

/// One published topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicSpec {
    /// Base name under [`NAMESPACE`].
    pub name: &'static str,
    /// ROS package of the message type.
    pub package: &'static str,
    /// Message type name.
    pub type_name: &'static str,
    /// Latched (transient local, keep last 1) rather than a stream.
    pub latched: bool,
}

impl TopicSpec {
    /// The ROS 2 type, e.g. `geometry_msgs::msg::dds_::PoseStamped_` on the wire.
    pub fn message_type(&self) -> MessageTypeName {
        MessageTypeName::new(self.package, self.type_name)
    }

    /// The ROS 2 topic name, e.g. `/voxhap/measured_cp`.
    pub fn ros_name(&self) -> String {
        format!("{NAMESPACE}/{}", self.name)
    }

    /// The QoS this topic is published with.
    pub fn qos(&self) -> QosProfile {
        if self.latched {
            latched_qos()
        } else {
            stream_qos()
        }
    }
}

/// A stream topic (not latched).
const fn stream(name: &'static str, package: &'static str, type_name: &'static str) -> TopicSpec {
    TopicSpec {
        name,
        package,
        type_name,
        latched: false,
    }
}

/// The probe position.
pub const MEASURED_CP: TopicSpec = stream("measured_cp", "geometry_msgs", "PoseStamped");
/// The probe velocity.
pub const MEASURED_CV: TopicSpec = stream("measured_cv", "geometry_msgs", "TwistStamped");
/// The rendered force.
pub const MEASURED_CF: TopicSpec = stream("measured_cf", "geometry_msgs", "WrenchStamped");
/// The force sent.
pub const SETPOINT_CF: TopicSpec = stream("setpoint_cf", "geometry_msgs", "WrenchStamped");
/// The external force in (`serve --external-force`): CRTK's Cartesian force setpoint, subscribed to with
/// [`command_qos`].
pub const SERVO_CF: TopicSpec = stream("servo_cf", "geometry_msgs", "WrenchStamped");
/// The CRTK operating state (latched).
pub const OPERATING_STATE: TopicSpec = TopicSpec {
    latched: true,
    ..stream("operating_state", "crtk_msgs", "OperatingState")
};

/// Every topic, in the order they are created.
pub const ALL: [TopicSpec; 5] = [
    MEASURED_CP,
    MEASURED_CV,
    MEASURED_CF,
    SETPOINT_CF,
    OPERATING_STATE,
];

/// What a reliable write does when its window is full of unacknowledged samples: fail at once (the sample
/// is dropped and counted), so a stuck reader cannot hold up the publishing thread.
const WHEN_FULL: WhenFull = WhenFull::Fail;

/// The streams' QoS: ROS 2's default (reliable, volatile, keep last 10).
pub fn stream_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WHEN_FULL)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

/// The `servo_cf` subscription's QoS: best effort, volatile, keep last 1. A best-effort reader matches both
/// reliable publishers (`ros2 topic pub`'s default) and best-effort ones (`sensor_data`), where a reliable
/// reader would refuse the latter (ROS 2 QoS compatibility); and a setpoint older than the newest is of no
/// use, so nothing is kept or resent.
pub fn command_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1 })
}

/// The operating state's QoS: reliable, transient local, keep last 1.
pub fn latched_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WHEN_FULL)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}
