//! What can go wrong starting the ROS 2 output.

/// Starting the ROS 2 output failed.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// The DDS participant (sockets, discovery) could not be created.
    #[error("ros2: cannot start DDS on domain {domain_id}: {cause}")]
    Participant {
        /// The ROS 2 domain id asked for.
        domain_id: u16,
        /// What RustDDS reported.
        cause: String,
    },
    /// A node, topic or publisher could not be created.
    #[error("ros2: cannot create {what}: {cause}")]
    Create {
        /// The node, topic or publisher.
        what: String,
        /// What ros2-client reported.
        cause: String,
    },
    /// The publishing thread could not be started.
    #[error("ros2: cannot start the publishing thread: {0}")]
    Thread(#[source] std::io::Error),
    /// The `/voxhap/servo_cf` subscriber thread could not be started.
    #[error("ros2: cannot start the /voxhap/servo_cf subscriber thread: {0}")]
    SubscriberThread(#[source] std::io::Error),
    /// `ROS_DOMAIN_ID` holds no domain id.
    #[error("ros2: ROS_DOMAIN_ID={value:?} is not a ROS 2 domain id (0 to 232); set it or give --ros2-domain ID")]
    DomainEnv {
        /// The variable's value.
        value: String,
    },
    /// The servo rate is not a positive finite number.
    #[error("ros2: the servo rate {rate_hz} Hz is not a positive finite number")]
    Rate {
        /// The rate given.
        rate_hz: f64,
    },
}
