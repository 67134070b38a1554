//! The supervisor's settings ([`SupervisorConfig`]) and their check: every count non-zero, the connect timeout in
//! range, and the safety and input settings checked by their own stages.

use crate::plausibility::InputConfig;
use crate::safety::{SafetyConfig, SettingError};

/// Settings of the supervisor (defaults: protocol/SPEC.md, "Host behaviour a firmware can rely on").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisorConfig {
    /// The output limits (their force limit is further lowered to the device's maximum).
    pub safety: SafetyConfig,
    /// The input checks (their speed limit is further lowered to the device's maximum).
    pub input: InputConfig,
    /// Time between reopen attempts while the device is gone (µs).
    pub reconnect_interval_us: u64,
    /// How long a (re)connect waits for the device's answer to its handshake (µs; `serve --connect-timeout`):
    /// for voxhap-protocol devices, for a DeviceInfo answering Hello, then again for the first State.
    /// [`CONNECT_TIMEOUT_RANGE_US`].
    pub connect_timeout_us: u64,
    /// Failed exchanges in a row (timeouts, corrupted frames, refusals) that count as a lost link.
    pub max_consecutive_errors: u32,
    /// Time without a valid state that counts as a lost link (µs).
    pub link_timeout_us: u64,
    /// A state older than this many ticks (counted from the force it answers, see
    /// `HapticDevice::state_age_ticks`) is not used to render force; zero is sent instead.
    pub stale_state_ticks: u32,
    /// On-time ticks in a row, after connecting, each ending with a state within the staleness bound
    /// (`stale_state_ticks`), before the device is enabled.
    pub steady_ticks_before_enable: u32,
    /// The same count after a device watchdog trip or a stall, before the device is enabled again.
    pub healthy_ticks_before_reenable: u32,
    /// Ticks after an Enable during which a status that still says "not enabled" is not yet believed (the
    /// answer may have been sampled before the Enable arrived).
    pub enable_grace_ticks: u32,
    /// Shortest time between two Enables for a device that keeps dropping out without saying why (µs).
    pub reenable_interval_us: u64,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        SupervisorConfig {
            safety: SafetyConfig::default(),
            input: InputConfig::default(),
            reconnect_interval_us: 200_000,
            connect_timeout_us: 3_000_000,
            max_consecutive_errors: 10,
            link_timeout_us: 20_000,
            stale_state_ticks: 3,
            steady_ticks_before_enable: 50,
            healthy_ticks_before_reenable: 20,
            enable_grace_ticks: 20,
            reenable_interval_us: 200_000,
        }
    }
}

/// A supervisor setting that cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SupervisorConfigError {
    /// An output limit.
    #[error("safety setting {0}")]
    Safety(SettingError),
    /// An input check.
    #[error("input check setting {0}")]
    Input(SettingError),
    /// A link-health setting.
    #[error("supervisor setting {name} must be >= 1")]
    Zero {
        /// Setting name.
        name: &'static str,
    },
    /// A setting outside its range.
    #[error("supervisor setting {name} = {value} is outside {min} ..= {max}")]
    Range {
        /// Setting name.
        name: &'static str,
        /// The value given.
        value: u64,
        /// Smallest allowed.
        min: u64,
        /// Largest allowed.
        max: u64,
    },
}

/// The connect timeout's range (µs): at least a Hello's first wait (100 ms), at most 10 minutes.
pub const CONNECT_TIMEOUT_RANGE_US: (u64, u64) = (100_000, 600_000_000);

impl SupervisorConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SupervisorConfigError> {
        self.safety
            .validate()
            .map_err(SupervisorConfigError::Safety)?;
        self.input
            .validate()
            .map_err(SupervisorConfigError::Input)?;
        for (name, value) in [
            (
                "max_consecutive_errors",
                u64::from(self.max_consecutive_errors),
            ),
            ("link_timeout_us", self.link_timeout_us),
            ("stale_state_ticks", u64::from(self.stale_state_ticks)),
            (
                "steady_ticks_before_enable",
                u64::from(self.steady_ticks_before_enable),
            ),
            (
                "healthy_ticks_before_reenable",
                u64::from(self.healthy_ticks_before_reenable),
            ),
        ] {
            if value == 0 {
                return Err(SupervisorConfigError::Zero { name });
            }
        }
        let (min, max) = CONNECT_TIMEOUT_RANGE_US;
        if !(min..=max).contains(&self.connect_timeout_us) {
            return Err(SupervisorConfigError::Range {
                name: "connect_timeout_us",
                value: self.connect_timeout_us,
                min,
                max,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod config_tests {
    use super::{SupervisorConfig, CONNECT_TIMEOUT_RANGE_US};

    #[test]
    fn a_connect_timeout_out_of_range_is_refused_naming_the_key() {
        assert!(SupervisorConfig::default().validate().is_ok());
        let (min, max) = CONNECT_TIMEOUT_RANGE_US;
        for bad in [0, min - 1, max + 1] {
            let config = SupervisorConfig {
                connect_timeout_us: bad,
                ..SupervisorConfig::default()
            };
            let error = config.validate().unwrap_err().to_string();
            assert!(error.contains("connect_timeout_us"), "{error}");
        }
        for good in [min, max] {
            let config = SupervisorConfig {
                connect_timeout_us: good,
                ..SupervisorConfig::default()
            };
            assert!(config.validate().is_ok());
        }
    }
}
