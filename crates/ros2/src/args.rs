//! The `serve` flags of the ROS 2 output.

use crate::error::Ros2Error;
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
    #[arg(long, value_name = "ID",
          value_parser = clap::value_parser!(u16).range(0..=i64::from(MAX_DOMAIN_ID)))]
    pub ros2_domain: Option<u16>,
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

/// `ROS_DOMAIN_ID` as ROS 2 reads it: unset or empty is domain 0.
fn domain_from_env(value: Option<&str>) -> Result<u16, Ros2Error> {
    let text = value.unwrap_or("").trim();
    if text.is_empty() {
        return Ok(0);
    }
    text.parse::<u16>()
        .ok()
        .filter(|id| *id <= MAX_DOMAIN_ID)
        .ok_or_else(|| Ros2Error::DomainEnv {
            value: text.to_owned(),
        })
}

impl Ros2Args {
    /// The settings when `--ros2` is given (`ROS_DOMAIN_ID` and `ROS_AUTOMATIC_DISCOVERY_RANGE` are read only
    /// then, so a bad value there never stops a `serve` without `--ros2`).
    pub fn resolve(&self) -> Result<Option<Ros2Settings>, Ros2Error> {
        if !self.ros2 {
            return Ok(None);
        }
        let domain_id = match self.ros2_domain {
            Some(id) => id,
            None => domain_from_env(std::env::var("ROS_DOMAIN_ID").ok().as_deref())?,
        };
        let range = std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE").unwrap_or_default();
        Ok(Some(Ros2Settings {
            domain_id,
            localhost_only: self.ros2_localhost_only
                || range.trim().eq_ignore_ascii_case("LOCALHOST"),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_domain_id_is_read_as_ros_2_reads_it() {
        // The ROS_DOMAIN_ID page: ids 0 to 232; unset means domain 0.
        assert_eq!(domain_from_env(None).unwrap(), 0);
        assert_eq!(domain_from_env(Some("")).unwrap(), 0);
        assert_eq!(domain_from_env(Some("42")).unwrap(), 42);
        assert_eq!(domain_from_env(Some("232")).unwrap(), 232);
        for bad in ["233", "-1", "abc", "1.5"] {
            let error = domain_from_env(Some(bad)).unwrap_err().to_string();
            assert!(
                error.contains("ROS_DOMAIN_ID") && error.contains(bad),
                "{error}"
            );
        }
    }
}
