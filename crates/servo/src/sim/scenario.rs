//! Scene files, for `voxhap sim` and `voxhap serve` alike: the volumes, the modes, the coupling, the solver
//! settings, the simulated arm and hand, the hand's path and (for `sim`) the duration, in one TOML file.
//!
//! One schema, one validator: [`Scenario`] is what `sim` runs and what `serve` renders
//! (crate::setup builds its scene from it), and [`Scenario::validate`] checks both, the solver settings
//! included ([`SolverSettings::validate`]). The only difference is that `sim` needs `duration_s`
//! ([`Purpose::Sim`]); `serve` ignores it. `[arm]`, `[hand]` and `[path]` default to the simulated arm of
//! `voxhap serve` when left out. `damping_n_s_per_m` is rendered by both, from the probe velocity the arm
//! reports (exact, or estimated with `[arm] velocity_window_ticks`).
//!
//! Off the servo path: a scenario is read and validated once ([`Scenario::parse`]), its volumes are loaded
//! or generated ([`Scenario::load`]) into a [`RenderScene`], and the runner ([`super::runner`]) ticks it.
//! Unknown keys are errors, and every error names the key (`modes[1].transfer: x must increase ...`,
//! `arm: missing field mass_kg`). Relative volume file paths are resolved against the directory of the
//! scenario file (not the working directory), so a scenario runs the same from anywhere.

use super::events::{self, EventError, PlannedEvent, SimEvent};
use super::local::{MAX_LOCAL_DAMPING_N_S_PER_M, MAX_LOCAL_STIFFNESS_N_PER_M};
use crate::passivity::{PassivitySettings, PassivitySettingsError};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use voxhap_core::haptics::modes::{ModeConfig, ModeError, RenderScene};
use voxhap_core::haptics::tick::SolverKind;
use voxhap_core::haptics::SolverConfig;
use voxhap_core::volume::{procedural, AnyVolume};
pub use voxhap_device::sim::MAX_POSITION_M;
use voxhap_device::sim::{
    readable, ArmParams, HandParams, HandPath, LocalModelSim, SimArm, SimArmConfig, SimError,
};
use voxhap_io as io;
pub use voxhap_io::scene::STIFFNESS_RANGE_N_PER_M;

/// Longest scenario accepted (s): a day at 1 kHz is 86.4 million ticks.
pub const MAX_DURATION_S: f64 = 86_400.0;
/// Servo rates a scenario may ask for (Hz); the headless run costs rate x duration ticks.
pub const RATE_HZ_RANGE: std::ops::RangeInclusive<f64> = 1.0..=100_000.0;
/// Most ticks one scenario runs (a day at 1 kHz is 86.4 million).
pub const MAX_TICKS: u64 = 100_000_000;
/// Physics substeps of the simulated arm per tick: each costs a step of work every tick.
pub const SUBSTEPS_PER_TICK_RANGE: std::ops::RangeInclusive<u32> = 1..=1000;

/// A scenario as written in its TOML file (schema in the module docs and the README (`voxhap sim` / "Scenario files")).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// A label for traces and plots.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// What the scenario shows (free text).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Simulated time (s), > 0; needed by `sim`, ignored by `serve` (0 when not given).
    #[serde(default)]
    pub duration_s: f64,
    /// Servo rate (Hz), > 0; default 1000.
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// Coupling stiffness k (N/m), > 0.
    pub k_n_per_m: f64,
    /// Coupling damping (N s/m), >= 0; default 0. Rendered by `serve` and `sim`.
    #[serde(default)]
    pub damping_n_s_per_m: f64,
    /// Where the arm starts at rest (m); default: the hand path's target at t = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_m: Option<DVec3>,
    /// Solver settings; `--solver` overrides `kind`.
    #[serde(default)]
    pub solver: SolverSettings,
    /// The volumes, by name.
    pub volumes: Vec<VolumeSpec>,
    /// The haptic modes, in trace column order (at most 8).
    #[serde(default)]
    pub modes: Vec<ModeConfig>,
    #[serde(default = "default_arm")]
    pub arm: ArmParams,
    #[serde(default = "default_hand")]
    pub hand: HandParams,
    #[serde(default = "default_path")]
    pub path: HandPath,
    /// `[device]`: a device profile for `serve` (device::profile; `--device-profile` replaces it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<toml::Table>,
    /// `[local_model]`: the simulated arm renders local models with its own loop at `rate_hz`
    /// (protocol/SPEC.md section 10; `device::sim`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_model: Option<LocalModelSim>,
    /// `[passivity]`: the passivity observer and controller (crate::passivity).
    #[serde(default)]
    pub passivity: PassivitySettings,
    /// `[[events]]`: control commands at given times (`sim` only; `serve` refuses them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<SimEvent>,
}

fn default_arm() -> ArmParams {
    voxhap_device::mock::default_arm_config().arm
}

fn default_hand() -> HandParams {
    voxhap_device::mock::default_arm_config().hand
}

fn default_path() -> HandPath {
    voxhap_device::mock::default_arm_config().path
}

/// What a scene file is read for: `sim` needs a duration, `serve` does not.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Purpose {
    Sim,
    Serve,
}

fn default_rate_hz() -> f64 {
    1000.0
}

/// `[solver]`: which solver and the exact solver's budget.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSettings {
    /// `exact` (default), `euler` or `constraint`.
    #[serde(default)]
    pub kind: SolverKind,
    /// Exact solver: stop when the certified bound is at most this (m); default 1e-12.
    #[serde(default = "default_tolerance_m")]
    pub tolerance_m: f64,
    /// Exact solver: most block sweeps per tick; default 10000.
    #[serde(default = "default_max_sweeps")]
    pub max_sweeps: u32,
}

fn default_tolerance_m() -> f64 {
    1e-12
}

fn default_max_sweeps() -> u32 {
    10_000
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self {
            kind: SolverKind::default(),
            tolerance_m: default_tolerance_m(),
            max_sweeps: default_max_sweeps(),
        }
    }
}

/// Smallest and largest accepted `[solver] tolerance_m` (m): below 1e-18 m no f64 position can be certified
/// (the solver would stall every tick), above 1 mm the bound says nothing a user would want.
pub const TOLERANCE_RANGE_M: (f64, f64) = (1e-18, 1e-3);
/// Largest accepted `[solver] max_sweeps`.
pub const MAX_SWEEPS_LIMIT: u32 = 10_000_000;

impl SolverSettings {
    /// Checks the settings; the message names the key (`solver.max_sweeps: ...`).
    pub fn validate(&self) -> Result<(), SolverSettingsError> {
        let (lo, hi) = TOLERANCE_RANGE_M;
        if !(self.tolerance_m.is_finite() && self.tolerance_m >= lo && self.tolerance_m <= hi) {
            return Err(SolverSettingsError::Tolerance(self.tolerance_m));
        }
        if self.max_sweeps == 0 || self.max_sweeps > MAX_SWEEPS_LIMIT {
            return Err(SolverSettingsError::MaxSweeps(self.max_sweeps));
        }
        Ok(())
    }

    /// The exact solver's configuration (deterministic: no time budget in a sim).
    pub fn solver_config(&self) -> SolverConfig {
        SolverConfig {
            tolerance_m: self.tolerance_m,
            max_sweeps: self.max_sweeps,
            ..SolverConfig::default()
        }
    }
}

/// What is wrong with a `[solver]` table: the key and the value given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SolverSettingsError {
    /// `tolerance_m` is outside [`TOLERANCE_RANGE_M`].
    #[error("solver.tolerance_m: must be a number from {lo:e} to {hi:e} m, got {0}", lo = TOLERANCE_RANGE_M.0, hi = TOLERANCE_RANGE_M.1)]
    Tolerance(f64),
    /// `max_sweeps` is 0 or above [`MAX_SWEEPS_LIMIT`].
    #[error("solver.max_sweeps: must be from 1 to {max}, got {0}", max = MAX_SWEEPS_LIMIT)]
    MaxSweeps(u32),
}

/// What is wrong with a scenario's values: each names the key and the value given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioValueError {
    /// A key that must be a finite positive number is not.
    #[error("{key}: must be a finite number > 0, got {value}")]
    NotPositive {
        /// The key.
        key: &'static str,
        /// The value given.
        value: f64,
    },
    /// `voxhap sim` needs `duration_s`.
    #[error("duration_s: missing (voxhap sim needs it)")]
    MissingDuration,
    /// `damping_n_s_per_m` is negative or not finite.
    #[error("damping_n_s_per_m: must be a finite number >= 0, got {0}")]
    Damping(f64),
    /// `duration_s` is above [`MAX_DURATION_S`].
    #[error("duration_s: {0} s is longer than the {max} s limit", max = MAX_DURATION_S)]
    TooLong(f64),
    /// `rate_hz` is outside [`RATE_HZ_RANGE`].
    #[error("rate_hz: {0} Hz is out of range {lo}..={hi} Hz", lo = RATE_HZ_RANGE.start(), hi = RATE_HZ_RANGE.end())]
    Rate(f64),
    /// `arm.substeps_per_tick` is outside [`SUBSTEPS_PER_TICK_RANGE`].
    #[error("arm.substeps_per_tick: {0} is out of range {lo}..={hi}", lo = SUBSTEPS_PER_TICK_RANGE.start(), hi = SUBSTEPS_PER_TICK_RANGE.end())]
    Substeps(u32),
    /// `k_n_per_m` is outside [`STIFFNESS_RANGE_N_PER_M`].
    #[error("k_n_per_m: {k} N/m is out of range: give a number from {lo} to {hi} N/m", k = readable(*.0), lo = readable(STIFFNESS_RANGE_N_PER_M.0), hi = readable(STIFFNESS_RANGE_N_PER_M.1))]
    Stiffness(f64),
    /// `local_model.rate_hz` is not a whole multiple of `rate_hz` up to 100 kHz.
    #[error("local_model.rate_hz: {local_hz} Hz must be a whole multiple of rate_hz ({servo_hz} Hz), at most 100000 Hz, with a whole number of microseconds per cycle")]
    LocalRate { local_hz: f64, servo_hz: f64 },
    /// With `[local_model]`, `k_n_per_m` is above what a local model carries.
    #[error("k_n_per_m: {0} N/m is above the {max} N/m a local model carries ([local_model]: whole N/m in 16 bits)", max = MAX_LOCAL_STIFFNESS_N_PER_M)]
    LocalStiffness(f64),
    /// With `[local_model]`, `damping_n_s_per_m` is above what a local model carries.
    #[error("damping_n_s_per_m: {0} N s/m is above the {max} N s/m a local model carries ([local_model]: mN s/m in 16 bits)", max = MAX_LOCAL_DAMPING_N_S_PER_M)]
    LocalDamping(f64),
    /// The `[solver]` table.
    #[error(transparent)]
    Solver(#[from] SolverSettingsError),
    /// `duration_s x rate_hz` is above [`MAX_TICKS`].
    #[error("duration_s x rate_hz: {0} ticks is more than the {max}-tick limit", max = MAX_TICKS)]
    TooManyTicks(u64),
    /// `duration_s` at `rate_hz` rounds to no tick.
    #[error("duration_s: {duration_s} s at {rate_hz} Hz is less than one tick")]
    LessThanOneTick {
        /// The duration given (s).
        duration_s: f64,
        /// The rate given (Hz).
        rate_hz: f64,
    },
    /// `start_m` is not finite or outside [`MAX_POSITION_M`].
    #[error("start_m: must be three finite numbers from -{max} to {max} m, got {got:?}", max = MAX_POSITION_M, got = .0.to_array())]
    Start(DVec3),
    /// Modes name volumes but there are none.
    #[error("volumes: modes name volumes but none are given")]
    NoVolumes,
    /// `volumes[i]` has both a builtin and a file.
    #[error("volumes[{0}]: give one of builtin and file, not both")]
    BuiltinAndFile(usize),
    /// `volumes[i]` has neither a builtin nor a file.
    #[error("volumes[{0}]: needs builtin or file")]
    NoSource(usize),
    /// The `[passivity]` table.
    #[error(transparent)]
    Passivity(#[from] PassivitySettingsError),
    /// An `[[events]]` table.
    #[error(transparent)]
    Event(#[from] EventError),
    /// `[[events]]` in a scene file for `serve`.
    #[error("events: scripted events are for `voxhap sim`; send commands to a running `serve` through its control API")]
    EventsInServe,
    /// `volumes[i].part` is set on a file volume.
    #[error("volumes[{0}].part: only used with a two-field builtin")]
    PartWithFile(usize),
}

/// `[[volumes]]`: a named volume from a built-in generator or a file. Exactly one of `builtin`, `file`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeSpec {
    /// The name modes use to refer to it.
    pub name: String,
    /// A built-in procedural volume: `sphere`, `torus`, `shells`, `rankine`, `burgers`, `density-flow`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub builtin: Option<String>,
    /// A volume file (.nii, .nii.gz, .nrrd, .nhdr, .mha, .mhd, .toml), relative to the scenario file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// For a built-in with two fields (`density-flow`): `scalar` or `vector`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part: Option<VolumePart>,
}

impl VolumeSpec {
    /// Loads or generates this volume (`index` is its place in `volumes`, for messages; files relative to
    /// `base_dir`). Returns the volume and where it came from (`builtin:sphere`, the file path).
    pub fn load(
        &self,
        index: usize,
        base_dir: &Path,
        origin: &str,
    ) -> Result<(AnyVolume, String), ScenarioError> {
        let spec = self;
        let description;
        // `key` is the key below `volumes[index]` the message is about ("" for the table).
        let invalid = |key: &str, message: String| ScenarioError::Invalid {
            origin: origin.to_owned(),
            message: format!("volumes[{index}]{key}: {message}"),
        };
        let volume = if let Some(name) = &spec.builtin {
            let built =
                procedural::builtin(name).map_err(|err| invalid(".builtin", err.to_string()))?;
            description = format!("builtin:{name}");
            match (spec.part, built.scalar, built.vector) {
                (None | Some(VolumePart::Scalar), Some(s), None) => AnyVolume::Scalar(s),
                (None | Some(VolumePart::Vector), None, Some(v)) => AnyVolume::Vector(v),
                (Some(VolumePart::Scalar), Some(s), Some(_)) => AnyVolume::Scalar(s),
                (Some(VolumePart::Vector), Some(_), Some(v)) => AnyVolume::Vector(v),
                (None, Some(_), Some(_)) => {
                    return Err(invalid(
                        ".part",
                        format!(
                            "builtin {name:?} has a scalar and a vector field: set part = \"scalar\" or \"vector\""
                        ),
                    ))
                }
                (Some(part), _, _) => {
                    return Err(invalid(
                        ".part",
                        format!("builtin {name:?} has no {part:?} field"),
                    ))
                }
                (None, None, None) => {
                    return Err(invalid(".builtin", format!("builtin {name:?} is empty")))
                }
            }
        } else if let Some(file) = &spec.file {
            // Confined to the scenario's folder (after symlinks) unless --allow-outside-paths.
            let options = io::process_options();
            let path = io::confined_path(base_dir, file, options.allow_outside_paths).map_err(
                |problem| ScenarioError::Load {
                    origin: origin.to_owned(),
                    index,
                    name: spec.name.clone(),
                    source: Box::new(io::LoadProblem::File(problem).at(&base_dir.join(file))),
                },
            )?;
            let loaded = io::load_with(&path, &options).map_err(|source| ScenarioError::Load {
                origin: origin.to_owned(),
                index,
                name: spec.name.clone(),
                source: Box::new(source),
            })?;
            description = file.display().to_string();
            loaded.volume
        } else {
            return Err(invalid("", "needs builtin or file".to_owned()));
        };
        Ok((volume, description))
    }
}

/// Which field of a two-field built-in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VolumePart {
    Scalar,
    Vector,
}

/// Why a scenario could not be read or built. Every message names the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("cannot read scenario file {}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{origin}: {message}")]
    Invalid { origin: String, message: String },
    #[error("{origin}: volumes[{index}] ({name})")]
    Load {
        origin: String,
        index: usize,
        name: String,
        source: Box<io::LoadError>,
    },
    #[error("{origin}")]
    Modes { origin: String, source: ModeError },
    #[error("{origin}")]
    Arm { origin: String, source: SimError },
}

/// A scenario with its volumes loaded and its scene built: ready to run.
#[derive(Debug, Clone)]
pub struct LoadedScenario {
    pub scenario: Scenario,
    pub scene: RenderScene,
    pub arm: SimArmConfig,
    /// Where the arm starts (m).
    pub start_m: DVec3,
    /// The volumes as a short description for traces, e.g. `builtin:sphere` or a file path.
    pub volume_description: String,
    /// The `[[events]]`, checked and with their scenes built (sim::events).
    pub events: Vec<PlannedEvent>,
}

impl Scenario {
    /// Parses and validates scenario text for `sim`; `origin` names it in errors (usually the file path).
    pub fn parse(text: &str, origin: &str) -> Result<Scenario, ScenarioError> {
        Self::parse_for(text, origin, Purpose::Sim)
    }

    /// Parses and validates a scene file's text for `purpose`.
    pub fn parse_for(
        text: &str,
        origin: &str,
        purpose: Purpose,
    ) -> Result<Scenario, ScenarioError> {
        Self::parse_text(text, origin, purpose, true)
    }

    /// Parses and validates, for `sim`, a scenario's text as rewritten by `--set` (sim::overrides): as
    /// [`Scenario::parse`], but messages give no line and column, which would point into the rewritten text
    /// rather than the user's file.
    pub fn parse_edited(text: &str, origin: &str) -> Result<Scenario, ScenarioError> {
        Self::parse_text(text, origin, Purpose::Sim, false)
    }

    /// Parses and validates `text`; `locate`: serde's messages say where in `text` the value is.
    fn parse_text(
        text: &str,
        origin: &str,
        purpose: Purpose,
        locate: bool,
    ) -> Result<Scenario, ScenarioError> {
        let invalid = |message: String| ScenarioError::Invalid {
            origin: origin.to_owned(),
            message,
        };
        let deserializer = toml::Deserializer::parse(text)
            .map_err(|err| invalid(err.to_string().trim_end().to_owned()))?;
        // One line: the key's full path, serde's message, where it is in the file (when `locate`).
        let scenario: Scenario = serde_path_to_error::deserialize(deserializer).map_err(|err| {
            let path = err.path().to_string();
            let inner = err.into_inner();
            let mut message = inner.message().trim_end().to_owned();
            if let Some(span) = inner.span().filter(|_| locate) {
                let before = &text.as_bytes()[..span.start.min(text.len())];
                let line = before.iter().filter(|b| **b == b'\n').count() + 1;
                let line_start = before
                    .iter()
                    .rposition(|b| *b == b'\n')
                    .map_or(0, |i| i + 1);
                let column = String::from_utf8_lossy(&before[line_start..])
                    .chars()
                    .count()
                    + 1;
                message = format!("{message} (line {line}, column {column})");
            }
            invalid(if path == "." || path.is_empty() {
                message
            } else {
                format!("{path}: {message}")
            })
        })?;
        scenario
            .validate(purpose)
            .map_err(|problem| invalid(problem.to_string()))?;
        Ok(scenario)
    }

    /// Reads and validates a scenario file.
    pub fn read(path: &Path) -> Result<Scenario, ScenarioError> {
        let text = voxhap_io::read_text_file(path).map_err(|source| ScenarioError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// The one validator of scene files (module docs).
    pub fn validate(&self, purpose: Purpose) -> Result<(), ScenarioValueError> {
        use ScenarioValueError as E;
        let positive = |key: &'static str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(E::NotPositive { key, value })
            }
        };
        if purpose == Purpose::Sim && self.duration_s == 0.0 {
            return Err(E::MissingDuration);
        }
        if purpose == Purpose::Sim || self.duration_s != 0.0 {
            positive("duration_s", self.duration_s)?;
        }
        if !(self.damping_n_s_per_m.is_finite() && self.damping_n_s_per_m >= 0.0) {
            return Err(E::Damping(self.damping_n_s_per_m));
        }
        if self.duration_s > MAX_DURATION_S {
            return Err(E::TooLong(self.duration_s));
        }
        positive("rate_hz", self.rate_hz)?;
        if !RATE_HZ_RANGE.contains(&self.rate_hz) {
            return Err(E::Rate(self.rate_hz));
        }
        if !SUBSTEPS_PER_TICK_RANGE.contains(&self.arm.substeps_per_tick) {
            return Err(E::Substeps(self.arm.substeps_per_tick));
        }
        positive("k_n_per_m", self.k_n_per_m)?;
        let (k_min, k_max) = STIFFNESS_RANGE_N_PER_M;
        if !(k_min..=k_max).contains(&self.k_n_per_m) {
            return Err(E::Stiffness(self.k_n_per_m));
        }
        if let Some(local) = self.local_model {
            if local.cycles_per_period(self.rate_hz).is_none() {
                return Err(E::LocalRate {
                    local_hz: local.rate_hz,
                    servo_hz: self.rate_hz,
                });
            }
            if self.k_n_per_m > MAX_LOCAL_STIFFNESS_N_PER_M {
                return Err(E::LocalStiffness(self.k_n_per_m));
            }
            if self.damping_n_s_per_m > MAX_LOCAL_DAMPING_N_S_PER_M {
                return Err(E::LocalDamping(self.damping_n_s_per_m));
            }
        }
        self.solver.validate()?;
        self.passivity.validate()?;
        if purpose == Purpose::Serve && !self.events.is_empty() {
            return Err(E::EventsInServe);
        }
        events::check_times(&self.events, self.duration_s)?;
        if self.tick_count() > MAX_TICKS {
            return Err(E::TooManyTicks(self.tick_count()));
        }
        if purpose == Purpose::Sim && self.tick_count() == 0 {
            return Err(E::LessThanOneTick {
                duration_s: self.duration_s,
                rate_hz: self.rate_hz,
            });
        }
        if let Some(start) = self.start_m {
            if !(start.is_finite() && start.abs().max_element() <= MAX_POSITION_M) {
                return Err(E::Start(start));
            }
        }
        if self.volumes.is_empty() && self.modes.iter().any(|m| m.volume.is_some()) {
            return Err(E::NoVolumes);
        }
        for (index, volume) in self.volumes.iter().enumerate() {
            match (&volume.builtin, &volume.file) {
                (Some(_), Some(_)) => return Err(E::BuiltinAndFile(index)),
                (None, None) => return Err(E::NoSource(index)),
                (None, Some(_)) if volume.part.is_some() => return Err(E::PartWithFile(index)),
                _ => {}
            }
        }
        Ok(())
    }

    /// Servo ticks in the run: `round(duration_s * rate_hz)`.
    pub fn tick_count(&self) -> u64 {
        (self.duration_s * self.rate_hz).round() as u64
    }

    /// Tick length (s).
    pub fn dt_s(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// Loads or generates the volumes (files relative to `base_dir`, the scenario file's directory) and
    /// builds the scene and the arm configuration.
    pub fn load(self, base_dir: &Path, origin: &str) -> Result<LoadedScenario, ScenarioError> {
        let mut volumes = Vec::with_capacity(self.volumes.len());
        let mut descriptions = Vec::with_capacity(self.volumes.len());
        for (index, spec) in self.volumes.iter().enumerate() {
            let (volume, description) = spec.load(index, base_dir, origin)?;
            descriptions.push(description);
            volumes.push((spec.name.clone(), volume));
        }
        let scene = RenderScene::new(self.k_n_per_m, volumes, &self.modes).map_err(|source| {
            ScenarioError::Modes {
                origin: origin.to_owned(),
                source,
            }
        })?;
        let start_m = match self.start_m.or_else(|| self.path.target_at(0.0)) {
            Some(start) => start,
            None => {
                return Err(ScenarioError::Invalid {
                    origin: origin.to_owned(),
                    message: "start_m: needed when the hand path is a force profile".to_owned(),
                })
            }
        };
        let arm = SimArmConfig {
            arm: self.arm,
            hand: self.hand,
            path: self.path.clone(),
            local_model: self.local_model,
        };
        // Check the arm now, so that a bad [arm], [hand] or [path] is refused before any trace is created.
        SimArm::new(arm.clone(), start_m).map_err(|source| ScenarioError::Arm {
            origin: origin.to_owned(),
            source,
        })?;
        let events = events::plan(
            &self.events,
            &scene,
            &self.modes,
            self.k_n_per_m,
            self.damping_n_s_per_m,
            self.rate_hz,
            self.local_model.is_some(),
        )
        .map_err(|problem| ScenarioError::Invalid {
            origin: origin.to_owned(),
            message: problem.to_string(),
        })?;
        Ok(LoadedScenario {
            scenario: self,
            scene,
            arm,
            start_m,
            volume_description: descriptions.join(", "),
            events,
        })
    }
}

impl LoadedScenario {
    /// Reads, validates and loads a scenario file (volume files relative to its directory).
    pub fn from_file(path: &Path) -> Result<LoadedScenario, ScenarioError> {
        let scenario = Scenario::read(path)?;
        let base_dir = path.parent().unwrap_or(Path::new(""));
        scenario.load(base_dir, &path.display().to_string())
    }
}

#[cfg(test)]
#[path = "scenario_tests.rs"]
mod tests;
