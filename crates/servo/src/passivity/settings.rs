//! `[passivity]` in a scene file: the passivity controller's mode and parameters, range-checked with errors
//! naming the key ([`super::controller`] for the method).

use serde::{Deserialize, Serialize};
use voxhap_device::latency::ticks_rounded_up;

/// Largest `[passivity] max_damping_n_s_per_m` accepted (N s/m).
pub const MAX_CONTROLLER_DAMPING_N_S_PER_M: f64 = 1000.0;
/// Largest `[passivity] threshold_j` accepted (J): 1 mJ, ten times `--fail-on active`'s tolerance.
pub const MAX_THRESHOLD_J: f64 = 1e-3;
/// Default `max_damping_n_s_per_m` (N s/m).
pub const DEFAULT_MAX_DAMPING_N_S_PER_M: f64 = 20.0;
/// Default `threshold_j` (J): 1 µJ.
pub const DEFAULT_THRESHOLD_J: f64 = 1e-6;
/// Largest `[passivity] latency_s` accepted (s): 50 ms, 200 ticks at 4 kHz (within
/// [`MAX_LATENCY_TICKS`]).
pub const MAX_OBSERVER_LATENCY_S: f64 = 0.05;
/// The longest device latency the observer pairs exactly (ticks); longer latencies are booked as this.
pub const MAX_LATENCY_TICKS: usize = 255;

/// Whole ticks from a latency in seconds at period `dt_s`, rounded up by the one rule for a delay in ticks
/// (`voxhap_device::latency::ticks_rounded_up`: a part per million of a tick is taken as rounding error, so
/// 1 ms at 4 kHz is 4 ticks), at most [`MAX_LATENCY_TICKS`]. Rounding up is the safe side
/// (`super::controller` module docs, "Latency").
pub fn ticks_of(latency_s: f64, dt_s: f64) -> usize {
    (ticks_rounded_up(latency_s, dt_s) as usize).min(MAX_LATENCY_TICKS)
}

/// What the passivity observer and controller do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PassivityMode {
    /// Nothing: no observer, no controller, changes in contact applied at once.
    Off,
    /// The observer books the energy; the controller adds no force. Changes in contact are introduced
    /// passively.
    Observe,
    /// The observer books, and the controller dissipates what the coupling generated beyond its reference.
    Control,
}

impl PassivityMode {
    /// `off`, `observe` or `control`.
    pub fn name(self) -> &'static str {
        match self {
            PassivityMode::Off => "off",
            PassivityMode::Observe => "observe",
            PassivityMode::Control => "control",
        }
    }
}

/// `[passivity]`: the mode and the method's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PassivitySettings {
    /// Left out: `control` for every real device, `observe` for the simulated arm ([`Self::mode_for`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<PassivityMode>,
    /// The most damping the controller adds in one tick (N s/m), > 0.
    #[serde(default = "default_max_damping")]
    pub max_damping_n_s_per_m: f64,
    /// Generated energy beyond the reference that the controller lets pass before it acts (J), >= 0.
    #[serde(default = "default_threshold")]
    pub threshold_j: f64,
    /// The device's latency the observer pairs forces and motion with (s), 0 to [`MAX_OBSERVER_LATENCY_S`];
    /// left out: the driver's declared link latency (its worst case), or the simulated arm's
    /// `[arm] latency_s`, or none when neither is known (`super::latency::ObserverLatency::choose`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latency_s: Option<f64>,
}

fn default_max_damping() -> f64 {
    DEFAULT_MAX_DAMPING_N_S_PER_M
}

fn default_threshold() -> f64 {
    DEFAULT_THRESHOLD_J
}

impl Default for PassivitySettings {
    fn default() -> Self {
        PassivitySettings {
            mode: None,
            max_damping_n_s_per_m: DEFAULT_MAX_DAMPING_N_S_PER_M,
            threshold_j: DEFAULT_THRESHOLD_J,
            latency_s: None,
        }
    }
}

/// What is wrong with a `[passivity]` table: the key and the value given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PassivitySettingsError {
    #[error("passivity.max_damping_n_s_per_m: must be a number > 0 and at most {MAX_CONTROLLER_DAMPING_N_S_PER_M} N s/m, got {0}")]
    MaxDamping(f64),
    #[error("passivity.threshold_j: must be a number from 0 to {MAX_THRESHOLD_J:e} J, got {0}")]
    Threshold(f64),
    #[error("passivity.latency_s: must be a number from 0 to {MAX_OBSERVER_LATENCY_S} s, got {0}")]
    Latency(f64),
}

impl PassivitySettings {
    /// Checks the parameters; the message names the key.
    pub fn validate(&self) -> Result<(), PassivitySettingsError> {
        let b = self.max_damping_n_s_per_m;
        if !(b.is_finite() && b > 0.0 && b <= MAX_CONTROLLER_DAMPING_N_S_PER_M) {
            return Err(PassivitySettingsError::MaxDamping(b));
        }
        let e = self.threshold_j;
        if !(e.is_finite() && (0.0..=MAX_THRESHOLD_J).contains(&e)) {
            return Err(PassivitySettingsError::Threshold(e));
        }
        if let Some(latency) = self.latency_s {
            if !(latency.is_finite() && (0.0..=MAX_OBSERVER_LATENCY_S).contains(&latency)) {
                return Err(PassivitySettingsError::Latency(latency));
            }
        }
        Ok(())
    }

    /// The mode in force: the one written, else `control` for a real device and `observe` for the
    /// simulated arm (whose sims show the uncompensated coupling unless asked).
    pub fn mode_for(&self, simulated_arm: bool) -> PassivityMode {
        self.mode.unwrap_or(if simulated_arm {
            PassivityMode::Observe
        } else {
            PassivityMode::Control
        })
    }
}
