//! Why a stability measurement could not be made.

use crate::sim::{ScenarioError, SimRunError};
use voxhap_device::sim::{SimError, ZohError};
use voxhap_protocol::LocalBuildError;

/// Why a stability run or a force-error run failed. Each names what was asked.
#[derive(Debug, thiserror::Error)]
pub enum StabilityError {
    /// The scenario built for a run (or read from a file) was refused.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// The simulated run stopped.
    #[error(transparent)]
    Run(#[from] SimRunError),
    /// The simulated arm refused a step or its configuration.
    #[error("simulated arm: {0}")]
    Arm(#[from] SimError),
    /// A device rate that is not a whole multiple of the host rate with whole-microsecond cycles.
    #[error(
        "local rate {device_hz} Hz: must be a whole multiple of the host rate ({host_hz} Hz), at most 100000 Hz, \
         with a whole number of microseconds per cycle"
    )]
    LocalRate {
        /// The device rate asked for.
        device_hz: f64,
        /// The host rate.
        host_hz: f64,
    },
    /// The host could not build a local model from a tick.
    #[error("building a local model: {0}")]
    Model(#[from] LocalBuildError),
    /// The device loop did not finish its engage ramp in the time the run allows.
    #[error("the device loop did not engage within {seconds} s (ramp factor {factor})")]
    NoEngage {
        /// How long it had.
        seconds: f64,
        /// Where its ramp got to.
        factor: f64,
    },
    /// A bisection bracket that is not a bracket.
    #[error("search range {low_n_per_m} to {high_n_per_m} N/m: the low end must be positive and below the high end")]
    Range {
        /// Low end, N/m.
        low_n_per_m: f64,
        /// High end, N/m.
        high_n_per_m: f64,
    },
    /// The exact zero-order-hold boundary of a loop could not be computed from its figures.
    #[error(transparent)]
    Boundary(#[from] ZohError),
    /// A bisection tolerance out of range.
    #[error(
        "tolerance {0}: must be from 0.0001 to 0.5 (a ratio above 1 between the bracket's ends)"
    )]
    Tolerance(f64),
}
