//! The `serve` flags of the ROS 2 output.

use clap::Args;

/// The largest ROS 2 domain id: DDS's port formula (RTPS 2.5, 9.6.1.1: 7400 + 250 × domain + offsets) runs
/// out of UDP ports above it (ROS 2 docs, "The ROS_DOMAIN_ID").
pub const MAX_DOMAIN_ID: u16 = 232;

/// `--ros2`, `--ros2-domain`, `--ros2-localhost-only`.
#[derive(Debug, Clone, Args)]
pub struct Ros2Args {
    /// Publish the CRTK topics over ROS 2 (DDS; no ROS install needed): /voxhap/measured_cp, measured_cv,
    /// measured_cf, setpoint_cf, operating_state (docs/ros2.md).
    #[arg(long)]
    pub ros2: bool,
    /// ROS 2 domain id, 0 to 232 (default: $ROS_DOMAIN_ID, else 0).
    #[arg(long, value_name = "ID", env = "ROS_DOMAIN_ID", hide_env_values = true, default_value_t = 0,
          value_parser = clap::value_parser!(u16).range(0..=i64::from(MAX_DOMAIN_ID)))]
    pub ros2_domain: u16,
    /// Keep ROS 2 traffic on this machine (the loopback interface only); also set by ROS_LOCALHOST_ONLY=1
    /// or ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, as for ROS 2 nodes.
    #[arg(long, env = "ROS_LOCALHOST_ONLY", hide_env_values = true, value_parser = clap::builder::FalseyValueParser::new())]
    pub ros2_localhost_only: bool,
}

/// What the ROS 2 output is started with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ros2Settings {
    /// ROS 2 (DDS) domain id.
    pub domain_id: u16,
    /// Loopback only.
    pub localhost_only: bool,
}

impl Ros2Args {
    /// The settings when `--ros2` is given.
    pub fn resolve(&self) -> Option<Ros2Settings> {
        let range = std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE").unwrap_or_default();
        self.ros2.then(|| Ros2Settings {
            domain_id: self.ros2_domain,
            localhost_only: self.ros2_localhost_only
                || range.trim().eq_ignore_ascii_case("LOCALHOST"),
        })
    }
}
