//! Why a device could not be set up ([`OpenError`]) or connected ([`ConnectError`]).

use std::path::PathBuf;
use voxhap_device::sim::SimError;
use voxhap_device::supervisor::SupervisorConfigError;
use voxhap_device::ErrorKind;

/// Why a device could not be connected: the kind, and the driver's own words (with the OS reason).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct ConnectError {
    /// The kind of failure.
    pub kind: ErrorKind,
    /// What the driver said.
    pub message: String,
}

impl ConnectError {
    pub(super) fn from_error<E: voxhap_device::Error>(error: &E) -> ConnectError {
        ConnectError {
            kind: error.kind(),
            message: error.to_string(),
        }
    }
}

/// Why a device could not be set up. Each message holds its cause once: a variant either is its cause
/// (`transparent`) or names it in its text without returning it from `source()`, so an error chain printed
/// with `{:#}` never repeats it.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(transparent)]
    Safety(#[from] SupervisorConfigError),
    /// Every `SimError` message already starts with "simulated arm".
    #[error("{0}")]
    Sim(SimError),
    #[error("replay trace {path}: {message}")]
    Replay { path: PathBuf, message: String },
    #[error("device path {0:?} is not valid UTF-8")]
    Path(PathBuf),
    #[error("could not start the connector thread: {0}")]
    Thread(String),
    #[error("{0}")]
    Profile(String),
}

impl From<SimError> for OpenError {
    fn from(error: SimError) -> Self {
        OpenError::Sim(error)
    }
}
