//! `voxhap sim`: headless, deterministic runs of a scenario (volumes, modes, simulated arm, hand path)
//! through the real servo tick, recorded as a force trace.
//!
//! Data flow: [`scenario`] reads and validates the TOML file and builds the [`voxhap_core::haptics::modes::RenderScene`]
//! and the arm; [`runner`] closes the loop simulated arm -> [`voxhap_core::haptics::tick::tick`] -> simulated arm
//! with a mock clock (the tick counter) and hands every tick to a [`voxhap_record::TraceWriter`]; with
//! `[local_model]` the arm is a device whose own loop ([`local`]) renders each tick's local model at its rate.

pub mod events;
pub mod local;
pub mod overrides;
pub mod runner;
pub mod scenario;
pub mod schema;
pub mod stability;

pub use runner::{run, SimRunError, SimSummary};
pub use scenario::{
    LoadedScenario, Scenario, ScenarioError, ScenarioValueError, SolverSettings,
    SolverSettingsError, VolumePart, VolumeSpec,
};
