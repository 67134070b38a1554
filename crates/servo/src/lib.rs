//! The real-time servo runtime (docs/design.md, "Threads"): the dedicated thread that reads the device, runs the
//! pure tick, passes the force through the safety pipeline and writes the device, on an absolute-deadline
//! schedule; and the lock-free boundaries around it (state out through a triple buffer, samples to the
//! recorder and commands in through SPSC rings).
//!
//! - [`api`]: what the outside sees and may ask (snapshots, statistics, control commands).

/// The session's outside face lives in [`voxhap_api`]; these names stay valid here.
pub use voxhap_api as api;
pub use voxhap_api::slice;
pub mod baseline;

pub use api::{
    ControlCommand, ControlError, ControlReply, HistogramReport, PrimitiveView, RealtimeReport,
    SafetyReport, SceneReport, SessionApi, Slice, SliceAxis, SliceRequest, Snapshot, StatsReport,
    VolumeReport,
};
mod commands;
mod control;
pub mod device;
pub mod energy;
pub mod external_force;
pub mod force_off;
mod join;
pub mod local_model;
pub mod mapped;
pub mod monitor;
pub mod passivity;
pub mod recorder;
pub mod rt;
pub mod runner;
pub mod schedule;
pub mod session;
pub mod setup;
pub mod sim;
pub mod stats;
pub mod steal;

pub use session::{Session, SessionConfig, SessionError, SessionShared, SessionSummary};
