//! Scene files, for `voxhap sim` and `voxhap serve` alike: the volumes, the modes, the coupling, the solver
//! settings, the simulated arm and hand, the hand's path and (for `sim`) the duration, in one TOML file.
//!
//! One schema, one validator: [`Scenario`] is what `sim` runs and what `serve` renders
//! (crate::setup builds its scene from it), and [`Scenario::validate`] checks both, the solver settings
//! included ([`SolverSettings::validate`]). The only difference is that `sim` needs `duration_s`
//! ([`Purpose::Sim`]); `serve` ignores it. `[arm]`, `[hand]` and `[path]` default to the simulated arm of
//! `voxhap serve` when left out. `damping_n_s_per_m` is rendered by `serve`; `sim` refuses a non-zero one
//! rather than ignore it.
//!
//! Off the servo path: a scenario is read and validated once ([`Scenario::parse`]), its volumes are loaded
//! or generated ([`Scenario::load`]) into a [`RenderScene`], and the runner ([`super::runner`]) ticks it.
//! Unknown keys are errors, and every error names the key (`modes[1].transfer: x must increase ...`,
//! `arm: missing field mass_kg`). Relative volume file paths are resolved against the directory of the
//! scenario file (not the working directory), so a scenario runs the same from anywhere.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use voxhap_core::haptics::modes::{ModeConfig, ModeError, RenderScene};
use voxhap_core::haptics::tick::SolverKind;
use voxhap_core::haptics::SolverConfig;
use voxhap_core::volume::{procedural, AnyVolume};
pub use voxhap_device::sim::MAX_POSITION_M;
use voxhap_device::sim::{
    readable, ArmParams, HandParams, HandPath, SimArm, SimArmConfig, SimError,
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
    /// Coupling damping (N s/m), >= 0; default 0. Rendered by `serve`; `sim` refuses a non-zero one.
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
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = TOLERANCE_RANGE_M;
        if !(self.tolerance_m.is_finite() && self.tolerance_m >= lo && self.tolerance_m <= hi) {
            return Err(format!(
                "solver.tolerance_m: must be a number from {lo:e} to {hi:e} m, got {}",
                self.tolerance_m
            ));
        }
        if self.max_sweeps == 0 || self.max_sweeps > MAX_SWEEPS_LIMIT {
            return Err(format!(
                "solver.max_sweeps: must be from 1 to {MAX_SWEEPS_LIMIT}, got {}",
                self.max_sweeps
            ));
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
        scenario.validate(purpose).map_err(invalid)?;
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
    pub fn validate(&self, purpose: Purpose) -> Result<(), String> {
        let positive = |key: &str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(format!("{key}: must be a finite number > 0, got {value}"))
            }
        };
        if purpose == Purpose::Sim && self.duration_s == 0.0 {
            return Err("duration_s: missing (voxhap sim needs it)".to_owned());
        }
        if purpose == Purpose::Sim || self.duration_s != 0.0 {
            positive("duration_s", self.duration_s)?;
        }
        if self.damping_n_s_per_m != 0.0 && purpose == Purpose::Sim {
            return Err(
                "damping_n_s_per_m: voxhap sim does not render coupling damping; remove it or use serve"
                    .to_owned(),
            );
        }
        if !(self.damping_n_s_per_m.is_finite() && self.damping_n_s_per_m >= 0.0) {
            return Err(format!(
                "damping_n_s_per_m: must be a finite number >= 0, got {}",
                self.damping_n_s_per_m
            ));
        }
        if self.duration_s > MAX_DURATION_S {
            return Err(format!(
                "duration_s: {} s is longer than the {MAX_DURATION_S} s limit",
                self.duration_s
            ));
        }
        positive("rate_hz", self.rate_hz)?;
        if !RATE_HZ_RANGE.contains(&self.rate_hz) {
            return Err(format!(
                "rate_hz: {} Hz is out of range {}..={} Hz",
                self.rate_hz,
                RATE_HZ_RANGE.start(),
                RATE_HZ_RANGE.end()
            ));
        }
        if !SUBSTEPS_PER_TICK_RANGE.contains(&self.arm.substeps_per_tick) {
            return Err(format!(
                "arm.substeps_per_tick: {} is out of range {}..={}",
                self.arm.substeps_per_tick,
                SUBSTEPS_PER_TICK_RANGE.start(),
                SUBSTEPS_PER_TICK_RANGE.end()
            ));
        }
        positive("k_n_per_m", self.k_n_per_m)?;
        let (k_min, k_max) = STIFFNESS_RANGE_N_PER_M;
        if !(k_min..=k_max).contains(&self.k_n_per_m) {
            return Err(format!(
                "k_n_per_m: {} N/m is out of range: give a number from {} to {} N/m",
                readable(self.k_n_per_m),
                readable(k_min),
                readable(k_max)
            ));
        }
        self.solver.validate()?;
        if self.tick_count() > MAX_TICKS {
            return Err(format!(
                "duration_s x rate_hz: {} ticks is more than the {MAX_TICKS}-tick limit",
                self.tick_count()
            ));
        }
        if purpose == Purpose::Sim && self.tick_count() == 0 {
            return Err(format!(
                "duration_s: {} s at {} Hz is less than one tick",
                self.duration_s, self.rate_hz
            ));
        }
        if let Some(start) = self.start_m {
            if !(start.is_finite() && start.abs().max_element() <= MAX_POSITION_M) {
                return Err(format!(
                    "start_m: must be three finite numbers from -{MAX_POSITION_M} to {MAX_POSITION_M} m, got {:?}",
                    start.to_array()
                ));
            }
        }
        if self.volumes.is_empty() && self.modes.iter().any(|m| m.volume.is_some()) {
            return Err("volumes: modes name volumes but none are given".to_owned());
        }
        for (index, volume) in self.volumes.iter().enumerate() {
            match (&volume.builtin, &volume.file) {
                (Some(_), Some(_)) => {
                    return Err(format!(
                        "volumes[{index}]: give one of builtin and file, not both"
                    ))
                }
                (None, None) => {
                    return Err(format!("volumes[{index}]: needs builtin or file"));
                }
                (None, Some(_)) if volume.part.is_some() => {
                    return Err(format!(
                        "volumes[{index}].part: only used with a two-field builtin"
                    ))
                }
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
        };
        // Check the arm now, so that a bad [arm], [hand] or [path] is refused before any trace is created.
        SimArm::new(arm.clone(), start_m).map_err(|source| ScenarioError::Arm {
            origin: origin.to_owned(),
            source,
        })?;
        Ok(LoadedScenario {
            scenario: self,
            scene,
            arm,
            start_m,
            volume_description: descriptions.join(", "),
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
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MINIMAL: &str = r#"
duration_s = 0.5
k_n_per_m = 500.0

[[volumes]]
name = "density"
builtin = "sphere"

[[modes]]
kind = "surface"
volume = "density"
transfer = [[0.45, 0.0], [0.5, 2.0]]

[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }

[hand]
stiffness_n_per_m = 300.0
damping_n_s_per_m = 3.0

[path]
kind = "line"
from_m = [0.0, 0.0, 0.045]
to_m = [0.0, 0.0, 0.02]
duration_s = 0.5
"#;

    /// The error with its sources, as `voxhap` prints it.
    fn chain(err: &dyn std::error::Error) -> String {
        let mut text = err.to_string();
        let mut source = err.source();
        while let Some(inner) = source {
            text = format!("{text}: {inner}");
            source = inner.source();
        }
        text
    }

    fn error_of(text: &str) -> String {
        Scenario::parse(text, "test.toml").unwrap_err().to_string()
    }

    #[test]
    fn minimal_scenario_parses_and_loads() {
        let scenario = Scenario::parse(MINIMAL, "test.toml").unwrap();
        assert_eq!(scenario.tick_count(), 500);
        assert_eq!(scenario.rate_hz, 1000.0);
        let loaded = scenario.load(Path::new("."), "test.toml").unwrap();
        assert_eq!(loaded.scene.mode_names(), ["surface"]);
        assert_eq!(loaded.start_m, DVec3::new(0.0, 0.0, 0.045));
        assert_eq!(loaded.volume_description, "builtin:sphere");
    }

    #[test]
    fn errors_name_the_key() {
        let typo = MINIMAL.replace("k_n_per_m", "k_n_per_mm");
        assert!(
            error_of(&typo).contains("k_n_per_mm"),
            "{}",
            error_of(&typo)
        );
        let bad_tf = MINIMAL.replace("[[0.45, 0.0], [0.5, 2.0]]", "[[0.5, 0.0], [0.45, 2.0]]");
        let message = error_of(&bad_tf);
        assert!(
            message.contains("modes[0].transfer") && message.contains("x must increase"),
            "{message}"
        );
        let unknown_mode_key =
            MINIMAL.replace("kind = \"surface\"", "kind = \"surface\"\nstiffness = 3");
        assert!(
            error_of(&unknown_mode_key).contains("stiffness"),
            "{}",
            error_of(&unknown_mode_key)
        );
        let negative = MINIMAL.replace("duration_s = 0.5\nk_n", "duration_s = -1.0\nk_n");
        assert!(
            error_of(&negative).starts_with("test.toml: duration_s: must be"),
            "{}",
            error_of(&negative)
        );
        let both = MINIMAL.replace(
            "builtin = \"sphere\"",
            "builtin = \"sphere\"\nfile = \"x.nii\"",
        );
        assert!(error_of(&both).contains("volumes[0]: give one of builtin and file"));
        let missing_arm = MINIMAL.replace("mass_kg = 0.1\n", "");
        assert!(
            error_of(&missing_arm).contains("mass_kg"),
            "{}",
            error_of(&missing_arm)
        );
    }

    /// A wrong-typed value, an unknown key, a key of another kind or a missing key in any table is
    /// refused naming the key's full path (tables chosen by `kind`/`shape` included: device::sim::tagged).
    #[test]
    fn every_table_names_the_key_in_a_serde_error() {
        let path_line = "[path]\nkind = \"line\"\nfrom_m = [0.0, 0.0, 0.045]\nto_m = [0.0, 0.0, 0.02]\nduration_s = 0.5\n";
        let with_path = |path: &str| MINIMAL.replace(path_line, path);
        let with_workspace =
            |workspace: &str| MINIMAL.replace("workspace = { shape = \"unbounded\" }", workspace);
        let cases: Vec<(String, &str)> = vec![
            (
                MINIMAL.replace("k_n_per_m = 500.0", "k_n_per_m = \"stiff\""),
                "test.toml: k_n_per_m: invalid type: string \"stiff\", expected f64 (line 3, column 13)",
            ),
            (
                format!("{MINIMAL}\n[solver]\nmax_sweeps = \"many\"\n"),
                "test.toml: solver.max_sweeps: invalid type: string \"many\", expected u32 (line ",
            ),
            (
                MINIMAL.replace("builtin = \"sphere\"", "builtin = \"sphere\"\npart = 3"),
                "test.toml: volumes[0].part: wanted string or table (line 8, column 8)",
            ),
            (
                MINIMAL.replace("kind = \"surface\"", "kind = \"surface\"\nenabled = \"yes\""),
                "test.toml: modes[0].enabled: invalid type: string \"yes\", expected a boolean",
            ),
            (
                MINIMAL.replace("mass_kg = 0.1", "mass_kg = \"heavy\""),
                "test.toml: arm.mass_kg: invalid type: string \"heavy\", expected f64",
            ),
            (
                with_workspace("workspace = { shape = \"sphere\", center_m = [0.0, 0.0, 0.0], radius_m = \"big\" }"),
                "test.toml: arm.workspace.radius_m: invalid type: string \"big\", expected f64",
            ),
            (
                with_workspace("workspace = { shape = \"box\", min_m = [0.0, 0.0], max_m = [0.1, 0.1, 0.1] }"),
                "test.toml: arm.workspace.min_m: invalid length 2",
            ),
            (
                with_workspace("workspace = { shape = \"unbounded\", radius = 0.1 }"),
                "test.toml: arm.workspace.radius: unknown field `radius`, expected one of `shape`, `min_m`, `max_m`, `center_m`, `radius_m`",
            ),
            (
                with_workspace("workspace = { shape = \"unbounded\", radius_m = 0.1 }"),
                "test.toml: arm.workspace: shape = \"unbounded\" takes no key `radius_m` (it takes none)",
            ),
            (
                with_workspace("workspace = { shape = \"ball\" }"),
                "test.toml: arm.workspace.shape: unknown variant `ball`, expected one of `box`, `sphere`, `unbounded`",
            ),
            (
                MINIMAL.replace("stiffness_n_per_m = 300.0", "stiffness_n_per_m = [300.0]"),
                "test.toml: hand.stiffness_n_per_m: invalid type: sequence, expected f64",
            ),
            (
                with_path("[path]\nkind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.04]]\nspeed_m_per_s = \"fast\"\n"),
                "test.toml: path.speed_m_per_s: invalid type: string \"fast\", expected f64",
            ),
            (
                with_path("[path]\nkind = \"waypoints\"\npoints_m = [[0.0, 0.0, 0.04], [0.0, \"y\", 0.0]]\nspeed_m_per_s = 0.1\n"),
                "test.toml: path.points_m[1]",
            ),
            (
                with_path("[path]\nkind = \"raster\"\norigin_m = [0.0, 0.0, 0.0]\nsweep_m = [0.01, 0.0, 0.0]\nstep_m = [0.0, 0.01, 0.0]\nlines = -2\nspeed_m_per_s = 0.1\n"),
                "test.toml: path.lines: invalid value: integer `-2`, expected u32",
            ),
            (
                with_path("[path]\nkind = \"hold\"\nat_m = [0.0, 0.0, 0.04]\nspeed = 2\n"),
                "test.toml: path.speed: unknown field `speed`, expected one of `kind`, `at_m`,",
            ),
            (
                with_path("[path]\nkind = \"hold\"\nat_m = [0.0, 0.0, 0.04]\nradius_m = 0.1\n"),
                "test.toml: path: kind = \"hold\" takes no key `radius_m` (its keys: `at_m`)",
            ),
            (
                with_path("[path]\nkind = \"line\"\nfrom_m = [0.0, 0.0, 0.04]\nto_m = [0.0, 0.0, 0.0]\n"),
                "test.toml: path: missing field `duration_s` (kind = \"line\" needs it)",
            ),
            (
                with_path("[path]\nkind = \"walk\"\n"),
                "test.toml: path.kind: unknown variant `walk`, expected one of `hold`, `line`, `waypoints`, `circle`, `raster`, `force`",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"ramp\"\nfrom_n = [0.0, 0.0, 0.0]\nto_n = [0.0, 0.0, -1.0]\nduration_s = \"slow\"\n"),
                "test.toml: path.profile.duration_s: invalid type: string \"slow\", expected f64",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"constant\"\nforce_n = [0.0, 0.0, -1.0]\nfrequency_hz = 2.0\n"),
                "test.toml: path.profile: shape = \"constant\" takes no key `frequency_hz` (its keys: `force_n`)",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"sine\"\noffset_n = [0.0, 0.0, 0.0]\namplitude_n = [0.0, 0.0, 1.0]\n"),
                "test.toml: path.profile: missing field `frequency_hz` (shape = \"sine\" needs it)",
            ),
            (
                with_path("[path]\nkind = \"force\"\n[path.profile]\nshape = \"constant\"\nforce = [0.0, 0.0, -1.0]\n"),
                "test.toml: path.profile.force: unknown field `force`, expected one of `shape`, `force_n`,",
            ),
        ];
        for (text, expected) in &cases {
            let message = error_of(text);
            assert!(
                message.contains(expected),
                "expected {expected:?}\n     got {message:?}"
            );
            assert!(!message.contains('\n'), "one line: {message:?}");
        }
        // Text rewritten by --set: no line and column (they would point into the rewritten text).
        let edited = Scenario::parse_edited(&cases[0].0, "test.toml (with --set)")
            .unwrap_err()
            .to_string();
        assert_eq!(
            edited,
            "test.toml (with --set): k_n_per_m: invalid type: string \"stiff\", expected f64"
        );
    }

    #[test]
    fn load_errors_name_the_volume_and_mode() {
        let wrong_kind = MINIMAL.replace("builtin = \"sphere\"", "builtin = \"rankine\"");
        let err = Scenario::parse(&wrong_kind, "t.toml")
            .unwrap()
            .load(Path::new("."), "t.toml")
            .unwrap_err();
        let err = chain(&err);
        assert!(
            err.contains("modes[0].volume") && err.contains("vector volume"),
            "{err}"
        );
        let missing_file = MINIMAL.replace("builtin = \"sphere\"", "file = \"no-such.nii.gz\"");
        let err = Scenario::parse(&missing_file, "t.toml")
            .unwrap()
            .load(Path::new("/nonexistent-dir"), "t.toml")
            .unwrap_err();
        let err = chain(&err);
        assert!(
            err.contains("volumes[0] (density)") && err.contains("/nonexistent-dir/no-such.nii.gz"),
            "{err}"
        );
        let two_fields = MINIMAL.replace("builtin = \"sphere\"", "builtin = \"density-flow\"");
        let err = Scenario::parse(&two_fields, "t.toml")
            .unwrap()
            .load(Path::new("."), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("set part"), "{err}");
        let bad_arm = MINIMAL.replace("mass_kg = 0.1", "mass_kg = -0.1");
        let err = Scenario::parse(&bad_arm, "t.toml")
            .unwrap()
            .load(Path::new("."), "t.toml")
            .unwrap_err();
        assert_eq!(
            chain(&err),
            "t.toml: simulated arm parameter arm.mass_kg = -0.1 must be finite and > 0"
        );
    }

    proptest! {
        /// Arbitrary text never panics the parser.
        #[test]
        fn arbitrary_text_never_panics(text in "\\PC{0,400}") {
            let _ = Scenario::parse(&text, "fuzz.toml");
        }

        /// Mutations of a valid scenario (bytes replaced, cut, or spliced) are parsed or refused, never panic,
        /// and whatever parses also loads or is refused cleanly.
        #[test]
        fn mutated_scenarios_never_panic(
            edits in proptest::collection::vec((0usize..2000, any::<u8>()), 0..6),
            cut in 0usize..2000,
        ) {
            let mut bytes = MINIMAL.as_bytes().to_vec();
            for (at, byte) in edits {
                let at = at % bytes.len();
                bytes[at] = byte;
            }
            bytes.truncate(cut.max(1).min(bytes.len()));
            let text = String::from_utf8_lossy(&bytes);
            if let Ok(scenario) = Scenario::parse(&text, "fuzz.toml") {
                let _ = scenario.load(Path::new("/nonexistent-dir"), "fuzz.toml");
            }
        }
    }
}
