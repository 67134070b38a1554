//! Device profiles: a small TOML file (or a `[device]` table in a scene file) saying how one arm is used in
//! this lab: where its workspace lands in the scene ([`WorkspaceMapping`]), limits that may only lower the
//! device's own, the velocity filter, and kinematics calibration constants for drivers that compute kinematics.
//!
//! Where it sits: read off the real-time path when `voxhap serve` starts (`--device-profile NAME|FILE`, or the
//! scene's `[device]` table); its limits are folded into the supervisor's settings before the device opens, its
//! mapping and coupling caps go into `servo::mapped::MappedDevice`, its kinematics into the driver's config.
//! `voxhap calibrate` writes one. docs/workspace.md is the user's reference; every key is listed there.
//!
//! ```toml
//! device = "haply2diy"           # which family the kinematics are for (optional otherwise)
//! base = "haply2diy"             # start from a built-in profile, override what follows (optional)
//! [mapping]
//! scale = 1.0                     # scene metres per device metre
//! translation_m = [0.0, -0.08, 0.0]
//! rotation_deg = [0.0, 0.0, 0.0]  # or rotation_matrix = [[1,0,0],[0,1,0],[0,0,1]] (rows)
//! # fit_volume = true             # instead of scale/translation: fit the volume (see WorkspaceMapping::fit)
//! [limits]                        # each only lowers the device's declared value
//! max_force_n = 1.5
//! max_stiffness_n_per_m = 800.0   # as felt by the hand
//! max_damping_n_s_per_m = 0.5     # as felt by the hand
//! slew_n_per_ms = 0.5
//! max_speed_m_per_s = 2.0
//! [velocity_filter]
//! cutoff_hz = 50.0
//! [workspace]                     # the reachable box measured by `voxhap calibrate` (device frame)
//! min_m = [-0.05, 0.02, 0.0]
//! max_m = [0.05, 0.14, 0.0]
//! [kinematics]                    # haply2diy and woodenhaptics-hid only
//! proximal_link_m = 0.07
//! ```

use super::drivers::falcon::{FalconConfig, FalconGeometry};
use super::drivers::haply::Haply2DiyConfig;
use super::drivers::woodenhaptics::WoodenHapticsConfig;
use super::drivers::woodenhaptics_constants::WoodenHapticsConstants;
use super::drivers::woodenhaptics_serial::{WoodyConfig, WoodyModel};
use super::mapping::{matrix_from_rows, rotation_from_degrees, MappingError, WorkspaceMapping};
use super::supervisor::SupervisorConfig;
use super::DeviceInfo;
use glam::{DMat3, DVec3};
use serde::Deserialize;
use std::path::Path;

/// The built-in profiles: name, file text (contrib/profiles/).
pub const BUILTIN_PROFILES: &[(&str, &str)] = &[
    ("sim", include_str!("../../../contrib/profiles/sim.toml")),
    (
        "haply-inverse",
        include_str!("../../../contrib/profiles/haply-inverse.toml"),
    ),
    (
        "haply2diy",
        include_str!("../../../contrib/profiles/haply2diy.toml"),
    ),
    (
        "woodenhaptics",
        include_str!("../../../contrib/profiles/woodenhaptics.toml"),
    ),
    (
        "woodenhaptics-hid",
        include_str!("../../../contrib/profiles/woodenhaptics-hid.toml"),
    ),
    (
        "falcon",
        include_str!("../../../contrib/profiles/falcon.toml"),
    ),
];

/// Device families a profile may name in `device` (the `--device` kinds).
pub const DEVICE_FAMILIES: &[&str] = &[
    "sim",
    "mock",
    "serial",
    "hid",
    "replay",
    "haply-inverse",
    "haply2diy",
    "woodenhaptics",
    "woodenhaptics-hid",
    "falcon",
];

/// Largest profile file read (bytes): a profile is a few hundred bytes.
pub const MAX_PROFILE_BYTES: u64 = 64 * 1024;

/// Why a profile cannot be used. Every message names the profile and the key.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The file could not be read.
    #[error("device profile {origin}: {source}")]
    Read {
        origin: String,
        source: std::io::Error,
    },
    /// Neither a file nor a built-in name.
    #[error(
        "device profile {given:?} is neither a file nor a built-in profile (built-in: {builtin})"
    )]
    Unknown { given: String, builtin: String },
    /// A key has a bad value, or is not known.
    #[error("device profile {origin}: {key}: {problem}")]
    Key {
        origin: String,
        key: String,
        problem: String,
    },
}

/// `[mapping]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingSection {
    scale: Option<f64>,
    translation_m: Option<[f64; 3]>,
    rotation_deg: Option<[f64; 3]>,
    rotation_matrix: Option<[[f64; 3]; 3]>,
    fit_volume: Option<bool>,
}

/// `[limits]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct LimitsSection {
    max_force_n: Option<f64>,
    max_stiffness_n_per_m: Option<f64>,
    max_damping_n_s_per_m: Option<f64>,
    slew_n_per_ms: Option<f64>,
    max_speed_m_per_s: Option<f64>,
}

/// `[workspace]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct WorkspaceSection {
    min_m: Option<[f64; 3]>,
    max_m: Option<[f64; 3]>,
}

/// `[velocity_filter]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct VelocityFilterSection {
    cutoff_hz: Option<f64>,
}

/// A profile file as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProfileFile {
    name: Option<String>,
    device: Option<String>,
    /// Read from the table before deserialising (the built-in underneath).
    #[serde(rename = "base")]
    _base: Option<String>,
    #[serde(default)]
    mapping: MappingSection,
    #[serde(default)]
    limits: LimitsSection,
    #[serde(default)]
    velocity_filter: VelocityFilterSection,
    #[serde(default)]
    workspace: WorkspaceSection,
    kinematics: Option<toml::Table>,
}

/// Haply 2DIY kinematics constants (see `drivers::haply`); each replaces the driver's default.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Haply2DiyKinematics {
    pub proximal_link_m: Option<f64>,
    pub distal_link_m: Option<f64>,
    pub base_distance_m: Option<f64>,
    pub encoder_offset_deg: Option<[f32; 2]>,
    pub encoder_resolution: Option<[f32; 2]>,
}

/// WoodenHaptics, Polhem and retrofitted PHANTOM (Teensy firmware) constants, one table per model: the one
/// for the model the device reports replaces that model's published constants (forsslund/hfabapi
/// hfab_math.h), key by key.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WoodenHapticsKinematics {
    /// Model 3 (`woodenhaptics_v2015()`).
    pub woodenhaptics: Option<WoodenHapticsConstants>,
    /// Model 1 (`polhem_v3()`).
    pub polhem: Option<WoodenHapticsConstants>,
    /// Model 2 (`vintage()`).
    pub vintage: Option<WoodenHapticsConstants>,
}

/// Kinematics constants for the drivers that compute kinematics on the host.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum Kinematics {
    /// None given: the driver's published defaults.
    #[default]
    Default,
    Haply2Diy(Haply2DiyKinematics),
    /// The legacy HID driver's constants (`encoder_home_counts` is refused: that driver has none).
    WoodenHapticsHid(WoodenHapticsConstants),
    WoodenHaptics(Box<WoodenHapticsKinematics>),
    /// The Falcon's constants: the keys given replace libnifalcon's (missing keys keep them).
    Falcon(FalconGeometry),
}

/// Where the workspace goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MappingChoice {
    /// This mapping.
    Fixed(WorkspaceMapping),
    /// Fit the loaded volume's bounds into the device's workspace, keeping this rotation.
    FitVolume { rotation: DMat3 },
    /// This mapping while the volume's bounds are within reach under it; otherwise the fit, keeping its
    /// rotation. What a real device gets by default (no mapping given, no `--fit-volume`, no
    /// `--no-fit-volume`; docs/workspace.md).
    FitWhenOutOfReach(WorkspaceMapping),
}

/// Limits that can only lower the device's own (`None`: the device's).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ProfileLimits {
    pub max_force_n: Option<f64>,
    /// As felt by the hand (device units).
    pub max_stiffness_n_per_m: Option<f64>,
    /// As felt by the hand (device units).
    pub max_damping_n_s_per_m: Option<f64>,
    pub slew_n_per_ms: Option<f64>,
    pub max_speed_m_per_s: Option<f64>,
}

/// A checked profile.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceProfile {
    /// Its name (the `name` key, or where it came from).
    pub name: String,
    /// Where it came from (file path, built-in name, scene file).
    pub origin: String,
    /// The device family it is for, when it says.
    pub device: Option<String>,
    pub mapping: MappingChoice,
    pub limits: ProfileLimits,
    /// Cutoff of the velocity estimate's low-pass filter (Hz), when set.
    pub velocity_cutoff_hz: Option<f64>,
    /// The reachable box measured by `voxhap calibrate` (device frame, m); a fit uses it instead of the
    /// device's declared workspace.
    pub workspace_m: Option<(DVec3, DVec3)>,
    pub kinematics: Kinematics,
    /// True when the profile's own text has a `[mapping]` table (one inherited through `base` does not
    /// count): such a mapping is the user's choice, never replaced by an automatic fit.
    pub mapping_given: bool,
}

impl Default for DeviceProfile {
    fn default() -> Self {
        DeviceProfile {
            name: "default".to_owned(),
            origin: "default".to_owned(),
            device: None,
            mapping: MappingChoice::Fixed(WorkspaceMapping::IDENTITY),
            limits: ProfileLimits::default(),
            velocity_cutoff_hz: None,
            workspace_m: None,
            kinematics: Kinematics::Default,
            mapping_given: false,
        }
    }
}

/// The built-in profile named `name`, if there is one.
pub fn builtin_text(name: &str) -> Option<&'static str> {
    BUILTIN_PROFILES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

fn builtin_names() -> String {
    BUILTIN_PROFILES
        .iter()
        .map(|(n, _)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Lays `over` onto `under`, table by table (a key in `over` replaces the same key in `under`).
fn overlay(under: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (under.get_mut(&key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above)) => overlay(below, above),
            (_, value) => {
                under.insert(key, value);
            }
        }
    }
}

impl DeviceProfile {
    /// `--device-profile NAME|FILE`: an existing file is read; otherwise a built-in name.
    pub fn resolve(given: &str) -> Result<DeviceProfile, ProfileError> {
        let path = Path::new(given);
        if path.exists() {
            return DeviceProfile::read(path);
        }
        match builtin_text(given) {
            Some(text) => DeviceProfile::parse(text, &format!("built-in {given}")),
            None => Err(ProfileError::Unknown {
                given: given.to_owned(),
                builtin: builtin_names(),
            }),
        }
    }

    /// Reads a profile file.
    pub fn read(path: &Path) -> Result<DeviceProfile, ProfileError> {
        let origin = path.display().to_string();
        let read_error = |source| ProfileError::Read {
            origin: origin.clone(),
            source,
        };
        let length = std::fs::metadata(path).map_err(read_error)?.len();
        if length > MAX_PROFILE_BYTES {
            return Err(ProfileError::Key {
                origin,
                key: "(file)".to_owned(),
                problem: format!(
                    "{length} bytes is too long for a profile (at most {MAX_PROFILE_BYTES})"
                ),
            });
        }
        let text = std::fs::read_to_string(path).map_err(read_error)?;
        DeviceProfile::parse(&text, &origin)
    }

    /// Parses a profile's text (`origin` names it in errors).
    pub fn parse(text: &str, origin: &str) -> Result<DeviceProfile, ProfileError> {
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| ProfileError::Key {
                origin: origin.to_owned(),
                key: "(syntax)".to_owned(),
                problem: e.to_string().trim_end().to_owned(),
            })?;
        DeviceProfile::from_table(table, origin)
    }

    /// A profile from a parsed table (a file, or a scene's `[device]` table).
    pub fn from_table(table: toml::Table, origin: &str) -> Result<DeviceProfile, ProfileError> {
        let key_error = |key: &str, problem: String| ProfileError::Key {
            origin: origin.to_owned(),
            key: key.to_owned(),
            problem,
        };
        let mapping_given = table.contains_key("mapping");
        let table = match table.get("base") {
            None => table,
            Some(toml::Value::String(base)) => {
                let text = builtin_text(base).ok_or_else(|| {
                    key_error(
                        "base",
                        format!("{base:?} is not a built-in profile ({})", builtin_names()),
                    )
                })?;
                let mut under: toml::Table = text.parse().map_err(|e: toml::de::Error| {
                    key_error("base", format!("built-in {base} does not parse: {e}"))
                })?;
                under.remove("name");
                overlay(&mut under, table);
                under
            }
            Some(_) => return Err(key_error("base", "must be a string".to_owned())),
        };
        let file: ProfileFile = serde_path_to_error::deserialize(toml::Value::Table(table))
            .map_err(|err| {
                let path = err.path().to_string();
                key_error(
                    if path.is_empty() { "." } else { &path },
                    err.into_inner().to_string().trim_end().to_owned(),
                )
            })?;
        let mut profile = file.check(origin)?;
        profile.mapping_given = mapping_given;
        Ok(profile)
    }

    /// The profile a device of this `--device` kind gets when none is given: its built-in profile
    /// (contrib/profiles/KIND.toml) when there is one, else the identity with the device's own limits; in
    /// both cases no mapping counts as given (`mapping_given` is false).
    pub fn default_for(family: &str) -> Result<DeviceProfile, ProfileError> {
        let mut profile = match builtin_text(family) {
            Some(text) => DeviceProfile::parse(text, &format!("built-in {family}"))?,
            None => DeviceProfile {
                name: format!("default ({family})"),
                ..DeviceProfile::default()
            },
        };
        profile.mapping_given = false;
        Ok(profile)
    }

    /// Turns a fixed mapping into [`MappingChoice::FitWhenOutOfReach`] (a fitting one is left as it is).
    pub fn fit_when_out_of_reach(&mut self) {
        if let MappingChoice::Fixed(mapping) = self.mapping {
            self.mapping = MappingChoice::FitWhenOutOfReach(mapping);
        }
    }

    /// The mapping for a device with the workspace box `[min, max]` (replaced by the profile's measured
    /// `[workspace]` when it has one) and a volume with the bounds given (when one is loaded): the fixed one,
    /// the fitted one, or (for [`MappingChoice::FitWhenOutOfReach`]) the fixed one unless the volume is out
    /// of its reach, then the fitted one.
    pub fn mapping_for(
        &self,
        device_min_m: DVec3,
        device_max_m: DVec3,
        volume_bounds_m: Option<(DVec3, DVec3)>,
    ) -> Result<WorkspaceMapping, MappingError> {
        let (device_min_m, device_max_m) = self.workspace_m.unwrap_or((device_min_m, device_max_m));
        match self.mapping {
            MappingChoice::Fixed(mapping) => Ok(mapping),
            MappingChoice::FitWhenOutOfReach(mapping) => match volume_bounds_m {
                Some((min, max)) if !mapping.reaches(device_min_m, device_max_m, min, max) => {
                    WorkspaceMapping::fit(mapping.rotation(), device_min_m, device_max_m, min, max)
                }
                _ => Ok(mapping),
            },
            MappingChoice::FitVolume { rotation } => {
                let (min, max) = volume_bounds_m.ok_or(MappingError::Fit {
                    what: "the volume",
                    problem: "the scene has no volume to fit",
                })?;
                WorkspaceMapping::fit(rotation, device_min_m, device_max_m, min, max)
            }
        }
    }

    /// Folds the force, slew, speed and filter settings into the supervisor's (each only lowers; the
    /// supervisor lowers force and speed further to the device's declared maxima when it attaches).
    pub fn apply_to(&self, config: &mut SupervisorConfig) {
        let lower = |current: &mut f64, limit: Option<f64>| {
            if let Some(limit) = limit {
                *current = current.min(limit);
            }
        };
        lower(&mut config.safety.max_force_n, self.limits.max_force_n);
        lower(&mut config.safety.slew_n_per_ms, self.limits.slew_n_per_ms);
        lower(
            &mut config.input.max_speed_m_per_s,
            self.limits.max_speed_m_per_s,
        );
        if let Some(cutoff) = self.velocity_cutoff_hz {
            config.input.velocity_cutoff_hz = cutoff;
        }
    }

    /// The largest stiffness the hand may feel (N/m): the device's declaration lowered by the profile.
    pub fn felt_stiffness_limit_n_per_m(&self, declared_n_per_m: f64) -> f64 {
        match self.limits.max_stiffness_n_per_m {
            Some(limit) if declared_n_per_m > 0.0 => declared_n_per_m.min(limit),
            Some(limit) => limit,
            None => declared_n_per_m,
        }
    }

    /// Lines for the operator where the profile asks for more than the device declares (those limits have no
    /// effect: a profile only lowers).
    pub fn notes_against(&self, info: &DeviceInfo) -> Vec<String> {
        let mut notes = Vec::new();
        let mut check = |key: &str, asked: Option<f64>, declared: f64, unit: &str| {
            if let Some(asked) = asked {
                if declared > 0.0 && asked > declared {
                    notes.push(format!(
                        "profile {}: limits.{key} = {asked} {unit} is above the device's {declared} {unit}; \
                         the device's value holds (a profile only lowers limits)",
                        self.name
                    ));
                }
            }
        };
        check(
            "max_force_n",
            self.limits.max_force_n,
            info.max_force_n,
            "N",
        );
        check(
            "max_stiffness_n_per_m",
            self.limits.max_stiffness_n_per_m,
            info.max_stiffness_n_per_m,
            "N/m",
        );
        check(
            "max_speed_m_per_s",
            self.limits.max_speed_m_per_s,
            info.max_speed_m_per_s,
            "m/s",
        );
        notes
    }

    /// Applies the 2DIY kinematics constants (where given) to a driver config.
    pub fn apply_haply2diy(&self, config: &mut Haply2DiyConfig) {
        if let Kinematics::Haply2Diy(k) = &self.kinematics {
            set(&mut config.proximal_link_m, k.proximal_link_m);
            set(&mut config.distal_link_m, k.distal_link_m);
            set(&mut config.base_distance_m, k.base_distance_m);
            set(&mut config.encoder_offset_deg, k.encoder_offset_deg);
            set(&mut config.encoder_resolution, k.encoder_resolution);
        }
    }

    /// Applies the WoodenHaptics (Teensy firmware) constants (where given) to a driver config: each model's
    /// table replaces that model's published constants when the device reports that model.
    pub fn apply_woodenhaptics(&self, config: &mut WoodyConfig) {
        if let Kinematics::WoodenHaptics(k) = &self.kinematics {
            for (model, constants) in [
                (WoodyModel::WoodenHaptics, k.woodenhaptics),
                (WoodyModel::Polhem, k.polhem),
                (WoodyModel::VintagePhantom, k.vintage),
            ] {
                if let Some(constants) = constants {
                    config.model_constants[model.index()] = constants;
                }
            }
        }
    }

    /// Applies the Falcon's kinematic constants (where given) to a driver config.
    pub fn apply_falcon(&self, config: &mut FalconConfig) {
        if let Kinematics::Falcon(geometry) = &self.kinematics {
            config.geometry = *geometry;
        }
    }

    /// Applies the WoodenHaptics (HID) kinematics constants (where given) to a driver config.
    pub fn apply_woodenhaptics_hid(&self, config: &mut WoodenHapticsConfig) {
        if let Kinematics::WoodenHapticsHid(constants) = &self.kinematics {
            constants.apply_to_hid(config);
        }
    }
}

fn set<T: Copy>(target: &mut T, value: Option<T>) {
    if let Some(value) = value {
        *target = value;
    }
}

impl ProfileFile {
    fn check(self, origin: &str) -> Result<DeviceProfile, ProfileError> {
        let key_error = |key: &str, problem: String| ProfileError::Key {
            origin: origin.to_owned(),
            key: key.to_owned(),
            problem,
        };
        if let Some(device) = &self.device {
            if !DEVICE_FAMILIES.contains(&device.as_str()) {
                return Err(key_error(
                    "device",
                    format!(
                        "{device:?} is not a device family ({})",
                        DEVICE_FAMILIES.join(", ")
                    ),
                ));
            }
        }
        // Mapping.
        let m = &self.mapping;
        let rotation = match (m.rotation_deg, m.rotation_matrix) {
            (Some(_), Some(_)) => {
                return Err(key_error(
                    "mapping.rotation_matrix",
                    "give rotation_deg or rotation_matrix, not both".to_owned(),
                ))
            }
            (Some(deg), None) => {
                if deg.iter().any(|d| !d.is_finite()) {
                    return Err(key_error(
                        "mapping.rotation_deg",
                        format!("{deg:?} must be three finite angles in degrees"),
                    ));
                }
                rotation_from_degrees(deg)
            }
            (None, Some(rows)) => matrix_from_rows(rows),
            (None, None) => DMat3::IDENTITY,
        };
        let rotation_key = if m.rotation_matrix.is_some() {
            "mapping.rotation_matrix"
        } else {
            "mapping.rotation_deg"
        };
        let mapping = if m.fit_volume == Some(true) {
            for (key, given) in [
                ("mapping.scale", m.scale.is_some()),
                ("mapping.translation_m", m.translation_m.is_some()),
            ] {
                if given {
                    return Err(key_error(
                        key,
                        "cannot be given with fit_volume = true (the fit computes it)".to_owned(),
                    ));
                }
            }
            WorkspaceMapping::new(rotation, 1.0, DVec3::ZERO)
                .map_err(|e| key_error(rotation_key, e.to_string()))?;
            MappingChoice::FitVolume { rotation }
        } else {
            let mapping = WorkspaceMapping::new(
                rotation,
                m.scale.unwrap_or(1.0),
                DVec3::from_array(m.translation_m.unwrap_or([0.0; 3])),
            )
            .map_err(|e| {
                let key = match e {
                    MappingError::Scale(_) => "mapping.scale",
                    MappingError::Translation(_) => "mapping.translation_m",
                    _ => rotation_key,
                };
                key_error(key, e.to_string())
            })?;
            MappingChoice::Fixed(mapping)
        };
        // Limits: positive and finite.
        let l = &self.limits;
        for (key, value) in [
            ("limits.max_force_n", l.max_force_n),
            ("limits.max_stiffness_n_per_m", l.max_stiffness_n_per_m),
            ("limits.slew_n_per_ms", l.slew_n_per_ms),
            ("limits.max_speed_m_per_s", l.max_speed_m_per_s),
            ("velocity_filter.cutoff_hz", self.velocity_filter.cutoff_hz),
        ] {
            if let Some(value) = value {
                if !(value.is_finite() && value > 0.0) {
                    return Err(key_error(key, format!("{value} must be finite and > 0")));
                }
            }
        }
        if let Some(value) = l.max_damping_n_s_per_m {
            if !(value.is_finite() && value >= 0.0) {
                return Err(key_error(
                    "limits.max_damping_n_s_per_m",
                    format!("{value} must be finite and >= 0"),
                ));
            }
        }
        // Measured workspace.
        let workspace_m = match (self.workspace.min_m, self.workspace.max_m) {
            (None, None) => None,
            (Some(min), Some(max)) => {
                let (min, max) = (DVec3::from_array(min), DVec3::from_array(max));
                if !(min.is_finite() && max.is_finite()) || min.cmpgt(max).any() || min == max {
                    return Err(key_error(
                        "workspace.max_m",
                        format!(
                            "{:?} .. {:?} must be finite corners with min <= max and some extent",
                            min.to_array(),
                            max.to_array()
                        ),
                    ));
                }
                Some((min, max))
            }
            (None, Some(_)) => {
                return Err(key_error(
                    "workspace.min_m",
                    "missing (max_m is given)".to_owned(),
                ))
            }
            (Some(_), None) => {
                return Err(key_error(
                    "workspace.max_m",
                    "missing (min_m is given)".to_owned(),
                ))
            }
        };
        // Kinematics.
        let kinematics = match self.kinematics {
            None => Kinematics::Default,
            Some(table) => {
                fn numbers_only(table: &toml::Table, prefix: &str) -> Result<(), (String, String)> {
                    for (key, value) in table {
                        let numbers = match value {
                            toml::Value::Float(_) | toml::Value::Integer(_) => true,
                            toml::Value::Array(items) => items.iter().all(|v| {
                                matches!(v, toml::Value::Float(_) | toml::Value::Integer(_))
                            }),
                            _ => false,
                        };
                        if !numbers {
                            return Err((
                                format!("{prefix}{key}"),
                                "must be a number or an array of numbers".to_owned(),
                            ));
                        }
                    }
                    Ok(())
                }
                let parse = |table: toml::Table| -> Result<toml::Value, ProfileError> {
                    numbers_only(&table, "kinematics.")
                        .map_err(|(key, problem)| key_error(&key, problem))?;
                    Ok(toml::Value::Table(table))
                };
                // One table per model: each holds numbers only.
                let parse_per_model = |table: toml::Table| -> Result<toml::Value, ProfileError> {
                    for (model, value) in &table {
                        if let toml::Value::Table(inner) = value {
                            numbers_only(inner, &format!("kinematics.{model}."))
                                .map_err(|(key, problem)| key_error(&key, problem))?;
                        }
                    }
                    Ok(toml::Value::Table(table))
                };
                let deserialize_error = |err: serde_path_to_error::Error<toml::de::Error>| {
                    key_error(
                        &format!("kinematics.{}", err.path()),
                        err.into_inner().to_string().trim_end().to_owned(),
                    )
                };
                let kinematics = match self.device.as_deref() {
                    Some("haply2diy") => Kinematics::Haply2Diy(
                        serde_path_to_error::deserialize(parse(table)?)
                            .map_err(deserialize_error)?,
                    ),
                    Some("woodenhaptics-hid") => Kinematics::WoodenHapticsHid(
                        serde_path_to_error::deserialize(parse(table)?)
                            .map_err(deserialize_error)?,
                    ),
                    Some("falcon") => Kinematics::Falcon(
                        serde_path_to_error::deserialize(parse(table)?)
                            .map_err(deserialize_error)?,
                    ),
                    Some("woodenhaptics") => Kinematics::WoodenHaptics(
                        serde_path_to_error::deserialize(parse_per_model(table)?)
                            .map_err(deserialize_error)?,
                    ),
                    other => {
                        return Err(key_error(
                            "kinematics",
                            format!(
                                "device {} takes no kinematics constants from a profile (haply2diy, \
                                 woodenhaptics, woodenhaptics-hid and falcon do; set device = \"...\")",
                                other.map_or("(not set)".to_owned(), |d| format!("{d:?}"))
                            ),
                        ))
                    }
                };
                check_kinematics(&kinematics)
                    .map_err(|(key, problem)| key_error(&format!("kinematics.{key}"), problem))?;
                kinematics
            }
        };
        Ok(DeviceProfile {
            name: self.name.unwrap_or_else(|| origin.to_owned()),
            origin: origin.to_owned(),
            device: self.device,
            mapping,
            limits: ProfileLimits {
                max_force_n: l.max_force_n,
                max_stiffness_n_per_m: l.max_stiffness_n_per_m,
                max_damping_n_s_per_m: l.max_damping_n_s_per_m,
                slew_n_per_ms: l.slew_n_per_ms,
                max_speed_m_per_s: l.max_speed_m_per_s,
            },
            velocity_cutoff_hz: self.velocity_filter.cutoff_hz,
            workspace_m,
            kinematics,
            mapping_given: false,
        })
    }
}

/// A check of a key's values ([`positive`], [`non_negative`], [`finite`]): the key and the problem when they
/// fail it.
type ValueCheck = fn(&str, &[f64]) -> Result<(), (String, String)>;

/// `values` finite and > 0, else `key` with the problem.
fn positive(key: &str, values: &[f64]) -> Result<(), (String, String)> {
    if values.iter().all(|v| v.is_finite() && *v > 0.0) {
        Ok(())
    } else {
        Err((key.to_owned(), format!("{values:?} must be finite and > 0")))
    }
}

/// `values` finite and >= 0, else `key` with the problem.
fn non_negative(key: &str, values: &[f64]) -> Result<(), (String, String)> {
    if values.iter().all(|v| v.is_finite() && *v >= 0.0) {
        Ok(())
    } else {
        Err((
            key.to_owned(),
            format!("{values:?} must be finite and >= 0"),
        ))
    }
}

/// `values` finite, else `key` with the problem.
fn finite(key: &str, values: &[f64]) -> Result<(), (String, String)> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err((key.to_owned(), format!("{values:?} must be finite")))
    }
}

/// Lengths, diameters, constants and resolutions must be finite and > 0 (a link length that the published
/// constants set to zero, >= 0); offsets finite. The error names the key (below `kinematics.`).
fn check_kinematics(kinematics: &Kinematics) -> Result<(), (String, String)> {
    match kinematics {
        Kinematics::Default => Ok(()),
        Kinematics::Haply2Diy(k) => {
            if let Some(v) = k.proximal_link_m {
                positive("proximal_link_m", &[v])?;
            }
            if let Some(v) = k.distal_link_m {
                positive("distal_link_m", &[v])?;
            }
            if let Some(v) = k.base_distance_m {
                non_negative("base_distance_m", &[v])?;
            }
            if let Some(v) = k.encoder_offset_deg {
                finite("encoder_offset_deg", &v.map(f64::from))?;
            }
            if let Some(v) = k.encoder_resolution {
                positive("encoder_resolution", &v.map(f64::from))?;
            }
            Ok(())
        }
        Kinematics::WoodenHapticsHid(k) => {
            if k.encoder_home_counts.is_some() {
                return Err((
                    "encoder_home_counts".to_owned(),
                    "the legacy HID driver has no encoder home offset (device = \"woodenhaptics\" takes one)"
                        .to_owned(),
                ));
            }
            check_woodenhaptics("", k, positive)
        }
        Kinematics::Falcon(g) => {
            for (key, value) in [
                ("a_m", g.a_m),
                ("b_m", g.b_m),
                ("c_m", g.c_m),
                ("d_m", g.d_m),
                ("e_m", g.e_m),
                ("wheel_slots", g.wheel_slots),
                ("shaft_diameter_m", g.shaft_diameter_m),
                ("small_arm_diameter_m", g.small_arm_diameter_m),
            ] {
                positive(key, &[value])?;
            }
            for (key, value) in [
                ("f_m", g.f_m),
                ("r_m", g.r_m),
                ("s_m", g.s_m),
                ("theta_offset_deg", g.theta_offset_deg),
            ] {
                finite(key, &[value])?;
            }
            Ok(())
        }
        Kinematics::WoodenHaptics(k) => {
            for (model, constants) in [
                ("woodenhaptics", &k.woodenhaptics),
                ("polhem", &k.polhem),
                ("vintage", &k.vintage),
            ] {
                if let Some(c) = constants {
                    check_woodenhaptics(&format!("{model}."), c, non_negative)?;
                }
            }
            Ok(())
        }
    }
}

/// One WoodenHaptics constants table (keys below `prefix`): diameters, torque constants and counts finite and
/// > 0, link lengths as `link_length_check` says, the origin finite.
fn check_woodenhaptics(
    prefix: &str,
    c: &WoodenHapticsConstants,
    link_length_check: ValueCheck,
) -> Result<(), (String, String)> {
    for (key, value) in [
        ("capstan_diameter_m", c.capstan_diameter_m),
        ("body_diameter_m", c.body_diameter_m),
        ("torque_constant_n_m_per_a", c.torque_constant_n_m_per_a),
        ("counts_per_revolution", c.counts_per_revolution),
    ] {
        if let Some(v) = value {
            positive(&format!("{prefix}{key}"), &v)?;
        }
    }
    if let Some(v) = c.link_length_m {
        link_length_check(&format!("{prefix}link_length_m"), &v)?;
    }
    if let Some(v) = c.workspace_origin_m {
        finite(&format!("{prefix}workspace_origin_m"), &v)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<DeviceProfile, ProfileError> {
        DeviceProfile::parse(text, "test.toml")
    }

    #[test]
    fn every_builtin_profile_parses() {
        for (name, text) in BUILTIN_PROFILES {
            let profile =
                DeviceProfile::parse(text, name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(profile.name, *name);
            assert!(DeviceProfile::resolve(name).is_ok());
        }
    }

    #[test]
    fn an_empty_profile_is_the_identity_with_the_devices_limits() {
        let profile = parse("").unwrap();
        assert_eq!(
            profile.mapping,
            MappingChoice::Fixed(WorkspaceMapping::IDENTITY)
        );
        assert_eq!(profile.limits, ProfileLimits::default());
        let mut config = SupervisorConfig::default();
        profile.apply_to(&mut config);
        assert_eq!(config, SupervisorConfig::default());
    }

    #[test]
    fn limits_only_lower() {
        let profile = parse(
            "[limits]\nmax_force_n = 1.5\nslew_n_per_ms = 9.0\nmax_speed_m_per_s = 2\n\
             max_stiffness_n_per_m = 800\n[velocity_filter]\ncutoff_hz = 30\n",
        )
        .unwrap();
        let mut config = SupervisorConfig::default();
        profile.apply_to(&mut config);
        assert_eq!(config.safety.max_force_n, 1.5);
        // 9 N/ms asks for more than the default 0.5: the default holds.
        assert_eq!(config.safety.slew_n_per_ms, 0.5);
        assert_eq!(config.input.max_speed_m_per_s, 2.0);
        assert_eq!(config.input.velocity_cutoff_hz, 30.0);
        assert_eq!(profile.felt_stiffness_limit_n_per_m(1000.0), 800.0);
        assert_eq!(profile.felt_stiffness_limit_n_per_m(500.0), 500.0);
        let mut info = DeviceInfo::basic("x", DVec3::splat(-0.1), DVec3::splat(0.1));
        info.max_force_n = 1.0;
        let notes = profile.notes_against(&info);
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(notes[0].contains("limits.max_force_n = 1.5"), "{notes:?}");
    }

    #[test]
    fn bad_values_name_their_key() {
        for (text, key) in [
            ("[limits]\nmax_force_n = -1\n", "limits.max_force_n"),
            ("[limits]\nmax_force_n = nan\n", "limits.max_force_n"),
            (
                "[limits]\nmax_stiffness_n_per_m = 0\n",
                "limits.max_stiffness_n_per_m",
            ),
            (
                "[limits]\nmax_damping_n_s_per_m = -0.1\n",
                "limits.max_damping_n_s_per_m",
            ),
            ("[limits]\nmax_force = 1\n", "limits.max_force"),
            (
                "[velocity_filter]\ncutoff_hz = inf\n",
                "velocity_filter.cutoff_hz",
            ),
            ("[mapping]\nscale = 0\n", "mapping.scale"),
            ("[mapping]\nscale = \"big\"\n", "mapping.scale"),
            (
                "[mapping]\ntranslation_m = [0, 0]\n",
                "mapping.translation_m",
            ),
            (
                "[mapping]\nrotation_matrix = [[1,0,0],[0,1,0],[0,0,-1]]\n",
                "mapping.rotation_matrix",
            ),
            (
                "[mapping]\nrotation_deg = [0, 0, inf]\n",
                "mapping.rotation_deg",
            ),
            (
                "[mapping]\nrotation_deg = [0,0,0]\nrotation_matrix = [[1,0,0],[0,1,0],[0,0,1]]\n",
                "mapping.rotation_matrix",
            ),
            ("[mapping]\nfit_volume = true\nscale = 2\n", "mapping.scale"),
            ("device = \"phantom\"\n", "device"),
            ("base = \"nothing\"\n", "base"),
            ("colour = 3\n", "colour"),
            ("[kinematics]\nproximal_link_m = 0.07\n", "kinematics"),
            (
                "device = \"haply2diy\"\n[kinematics]\nproximal_link_m = -0.07\n",
                "kinematics.proximal_link_m",
            ),
            (
                "device = \"haply2diy\"\n[kinematics]\nlink = 0.07\n",
                "kinematics.link",
            ),
            (
                "device = \"woodenhaptics-hid\"\n[kinematics]\nlink_length_m = [0.08, 0.2]\n",
                "kinematics.link_length_m",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\ncapstan_diameter_m = [0.01, 0, 0.01]\n",
                "kinematics.woodenhaptics.capstan_diameter_m",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.polhem]\ntorque_constant_n_m_per_a = [0.06, -0.05, 0.05]\n",
                "kinematics.polhem.torque_constant_n_m_per_a",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.vintage]\nworkspace_origin_m = [0.1, nan, 0]\n",
                "kinematics.vintage.workspace_origin_m",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.08, inf, 0.2]\n",
                "kinematics.woodenhaptics.link_length_m",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\ncounts_per_revolution = \"2000\"\n",
                "kinematics.woodenhaptics.counts_per_revolution",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.woody]\nlink_length_m = [0.08, 0.2, 0.2]\n",
                "kinematics.woody",
            ),
            (
                "device = \"falcon\"\n[kinematics]\na_m = 0\n",
                "kinematics.a_m",
            ),
            (
                "device = \"falcon\"\n[kinematics]\nwheel_slots = -320\n",
                "kinematics.wheel_slots",
            ),
            (
                "device = \"falcon\"\n[kinematics]\ns_m = nan\n",
                "kinematics.s_m",
            ),
            (
                "device = \"falcon\"\n[kinematics]\nlength = 0.06\n",
                "kinematics.length",
            ),
            ("[limits\n", "(syntax)"),
            ("[workspace]\nmin_m = [0, 0, 0]\n", "workspace.max_m"),
            (
                "[workspace]\nmin_m = [0, 0, 0]\nmax_m = [0, -1, 0]\n",
                "workspace.max_m",
            ),
        ] {
            let error = parse(text).expect_err(text).to_string();
            assert!(
                error.starts_with(&format!("device profile test.toml: {key}")),
                "{text:?} gave {error:?}, expected key {key}"
            );
        }
    }

    /// A value of the wrong type in any table of a profile is refused naming the key's full path.
    #[test]
    fn every_table_names_the_key_of_a_wrong_typed_value() {
        for (text, expected) in [
            ("name = 3\n", "name: invalid type: integer `3`, expected a string"),
            ("device = [\"sim\"]\n", "device: invalid type: sequence, expected a string"),
            ("base = 3\n", "base: must be a string"),
            (
                "[mapping]\nfit_volume = \"yes\"\n",
                "mapping.fit_volume: invalid type: string \"yes\", expected a boolean",
            ),
            (
                "[mapping]\nrotation_matrix = [[1, 0, 0], [0, 1, 0], [0, 0, \"1\"]]\n",
                "mapping.rotation_matrix[2][2]: invalid type: string \"1\", expected f64",
            ),
            (
                "[limits]\nslew_n_per_ms = \"fast\"\n",
                "limits.slew_n_per_ms: invalid type: string \"fast\", expected f64",
            ),
            (
                "[velocity_filter]\ncutoff_hz = [50]\n",
                "velocity_filter.cutoff_hz: invalid type: sequence, expected f64",
            ),
            (
                "[workspace]\nmin_m = [0, 0, \"low\"]\nmax_m = [1, 1, 1]\n",
                "workspace.min_m[2]: invalid type: string \"low\", expected f64",
            ),
            (
                "device = \"haply2diy\"\n[kinematics]\nencoder_offset_deg = [0.0]\n",
                "kinematics.encoder_offset_deg: invalid length 1, expected an array of length 2",
            ),
            (
                "device = \"falcon\"\n[kinematics]\na_m = \"long\"\n",
                "kinematics.a_m: must be a number or an array of numbers",
            ),
            (
                "device = \"woodenhaptics\"\n[kinematics.polhem]\nencoder_home_counts = [1.5, 0, 0]\n",
                "kinematics.polhem.encoder_home_counts[0]: invalid type: floating point `1.5`, expected i32",
            ),
            (
                "device = \"woodenhaptics-hid\"\n[kinematics]\nencoder_home_counts = [0, 0, 0]\n",
                "kinematics.encoder_home_counts: the legacy HID driver has no encoder home offset",
            ),
        ] {
            let error = parse(text).expect_err(text).to_string();
            let expected = format!("device profile test.toml: {expected}");
            assert!(
                error.starts_with(&expected),
                "{text:?}:\nexpected {expected:?}\n     got {error:?}"
            );
        }
    }

    #[test]
    fn base_profiles_are_overlaid_key_by_key() {
        let profile = parse(
            "base = \"haply2diy\"\nname = \"bench arm\"\n[kinematics]\ndistal_link_m = 0.095\n\
             [limits]\nmax_force_n = 1.0\n",
        )
        .unwrap();
        assert_eq!(profile.name, "bench arm");
        assert_eq!(profile.device.as_deref(), Some("haply2diy"));
        let builtin = DeviceProfile::resolve("haply2diy").unwrap();
        assert_eq!(profile.mapping, builtin.mapping);
        let mut config = Haply2DiyConfig::default();
        profile.apply_haply2diy(&mut config);
        assert_eq!(config.distal_link_m, 0.095);
        assert_eq!(
            config.proximal_link_m,
            Haply2DiyConfig::default().proximal_link_m
        );
        assert_eq!(profile.limits.max_force_n, Some(1.0));
    }

    #[test]
    fn the_docs_example_profile_parses() {
        // docs/workspace.md: a 2DIY rotated a quarter turn, magnified twice, gentler force.
        let profile = parse(
            "base = \"haply2diy\"\n[limits]\nmax_force_n = 1.0\nmax_stiffness_n_per_m = 1500\n\
             [mapping]\nscale = 2.0\ntranslation_m = [0.0, -0.16, 0.0]\nrotation_deg = [0, 0, 90]\n",
        )
        .unwrap();
        let MappingChoice::Fixed(m) = profile.mapping else {
            panic!("fixed mapping expected");
        };
        // The device's +x becomes the scene's +y, doubled; the 2DIY's box middle (0, 0.08) lands at (-0.16, -0.16).
        let p = m.to_scene_position_m(DVec3::new(0.0, 0.08, 0.0));
        assert!((p - DVec3::new(-0.16, -0.16, 0.0)).length() < 1e-12, "{p}");
        assert_eq!(profile.device.as_deref(), Some("haply2diy"));
    }

    #[test]
    fn fit_volume_profiles_fit_and_fixed_ones_do_not() {
        let profile = parse("[mapping]\nfit_volume = true\nrotation_deg = [0, 0, 90]\n").unwrap();
        let device = (DVec3::splat(-0.05), DVec3::splat(0.05));
        let volume = (DVec3::splat(-0.1), DVec3::splat(0.1));
        let m = profile
            .mapping_for(device.0, device.1, Some(volume))
            .unwrap();
        assert!((m.scale() - 2.0).abs() < 1e-12);
        assert!(profile.mapping_for(device.0, device.1, None).is_err());
        // A measured workspace replaces the declared one.
        let measured = parse(
            "[mapping]\nfit_volume = true\n[workspace]\nmin_m = [-0.02, -0.02, -0.02]\nmax_m = [0.02, 0.02, 0.02]\n",
        )
        .unwrap();
        let m = measured
            .mapping_for(device.0, device.1, Some(volume))
            .unwrap();
        assert!((m.scale() - 5.0).abs() < 1e-12, "{}", m.scale());
        let fixed = parse("[mapping]\nscale = 3\ntranslation_m = [0, 0.1, 0]\n").unwrap();
        let m = fixed.mapping_for(device.0, device.1, Some(volume)).unwrap();
        assert_eq!(m.scale(), 3.0);
        assert_eq!(m.translation_m(), DVec3::new(0.0, 0.1, 0.0));
    }

    #[test]
    fn a_real_device_defaults_to_its_builtin_and_fits_only_what_is_out_of_reach() {
        let mut falcon = DeviceProfile::default_for("falcon").unwrap();
        assert_eq!(falcon.device.as_deref(), Some("falcon"));
        assert!(!falcon.mapping_given);
        let builtin = DeviceProfile::resolve("falcon").unwrap();
        assert!(
            builtin.mapping_given,
            "a built-in named on purpose is a mapping given"
        );
        assert_eq!(falcon.mapping, builtin.mapping);
        // No built-in for the voxhap protocol: the identity.
        let mock = DeviceProfile::default_for("mock").unwrap();
        assert_eq!(mock.name, "default (mock)");
        assert_eq!(mock.mapping, DeviceProfile::default().mapping);
        assert_eq!(mock.kinematics, Kinematics::Default);
        falcon.fit_when_out_of_reach();
        let MappingChoice::FitWhenOutOfReach(given) = falcon.mapping else {
            panic!("{:?}", falcon.mapping);
        };
        // The Falcon's box: x, y ±0.06 m, z 0.075 .. 0.175 m; the built-in centres it on the origin.
        let device = (
            DVec3::new(-0.06, -0.06, 0.075),
            DVec3::new(0.06, 0.06, 0.175),
        );
        let small = (DVec3::splat(-0.04), DVec3::splat(0.04));
        assert_eq!(
            falcon.mapping_for(device.0, device.1, Some(small)).unwrap(),
            given
        );
        assert_eq!(falcon.mapping_for(device.0, device.1, None).unwrap(), given);
        let head = (DVec3::new(-0.1, -0.12, 0.2), DVec3::new(0.1, 0.12, 0.4));
        let fitted = falcon.mapping_for(device.0, device.1, Some(head)).unwrap();
        assert!((fitted.scale() - 2.0).abs() < 1e-12, "{}", fitted.scale());
        assert!(fitted.reaches(device.0, device.1, head.0, head.1));
        // Only the user's own [mapping] counts as given; one inherited through base does not.
        assert!(parse("[mapping]\nscale = 2\n").unwrap().mapping_given);
        assert!(
            !parse("base = \"falcon\"\n[limits]\nmax_force_n = 2\n")
                .unwrap()
                .mapping_given
        );
    }

    #[test]
    fn the_woodenhaptics_builtin_lists_hfabapis_published_constants() {
        let profile = DeviceProfile::resolve("woodenhaptics").unwrap();
        let mut config = WoodyConfig::default();
        profile.apply_woodenhaptics(&mut config);
        for model in [
            WoodyModel::WoodenHaptics,
            WoodyModel::Polhem,
            WoodyModel::VintagePhantom,
        ] {
            assert_ne!(
                config.model_constants[model.index()],
                WoodenHapticsConstants::default()
            );
            assert_eq!(
                config.model_constants[model.index()].applied_to(model.config()),
                model.config(),
                "{model:?}"
            );
        }
    }

    /// Changing a WoodenHaptics constant changes position and current as hfabapi's equations predict
    /// (serial chain: x = cos θA (Lb sin θB + Lc sin θC) - origin; current = τ dir d_capstan / d_body / k_t).
    #[test]
    fn a_woodenhaptics_profile_constant_changes_position_and_current_as_predicted() {
        let profile = parse(
            "device = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.080, 0.250, 0.245]\n\
             torque_constant_n_m_per_a = [0.0518, 0.0259, 0.0259]\nencoder_home_counts = [0, 0, -5000]\n",
        )
        .unwrap();
        let mut config = WoodyConfig::default();
        profile.apply_woodenhaptics(&mut config);
        let published = WoodyModel::WoodenHaptics.config();
        let changed =
            config.model_constants[WoodyModel::WoodenHaptics.index()].applied_to(published);
        // Body B straight up (θB = π/2), C level (θC = 0), A at 0: x = Lb - origin_x.
        let theta = [0.0, std::f64::consts::FRAC_PI_2, 0.0];
        let before = published.position_m(theta).unwrap();
        let after = changed.position_m(theta).unwrap();
        assert!(
            (after.x - before.x - (0.250 - 0.205)).abs() < 1e-12,
            "{before} {after}"
        );
        assert!((after.y - before.y).abs() < 1e-12 && (after.z - before.z).abs() < 1e-12);
        // A sideways force of 1 N loads joint A only at this pose: τA = reach = Lb, and motor A's current is
        // τA · d_capstan / d_body / k_t (mA, truncated): 0.205 m and 0.0259 N m/A before, 0.250 m and
        // 0.0518 N m/A after.
        let force = DVec3::new(0.0, 1.0, 0.0);
        let ma_before = published.currents_ma(theta, force, 6000);
        let ma_after = changed.currents_ma(theta, force, 6000);
        let predicted = |reach: f64, k_t: f64| (reach * 0.010 / 0.160 / k_t * 1000.0) as i32;
        assert_eq!(ma_before, [predicted(0.205, 0.0259), 0, 0]);
        assert_eq!(ma_after, [predicted(0.250, 0.0518), 0, 0]);
        // The home count moves joint C by 1000 counts through the capstan: 2π·1000/2000 · 10/120 rad.
        let raw = [0, 0, 0];
        let dc = changed.joint_angles_rad(raw)[2] - published.joint_angles_rad(raw)[2];
        let expected = -2.0 * std::f64::consts::PI * 1000.0 / 2000.0 * 0.010 / 0.120;
        assert!((dc - expected).abs() < 1e-12, "{dc} vs {expected}");
        // The other models keep their published constants.
        assert_eq!(
            config.model_constants[WoodyModel::Polhem.index()],
            WoodenHapticsConstants::default()
        );
    }

    #[test]
    fn the_falcon_builtin_lists_libnifalcons_constants_and_a_change_moves_the_handle_as_predicted()
    {
        let mut config = FalconConfig::default();
        DeviceProfile::resolve("falcon")
            .unwrap()
            .apply_falcon(&mut config);
        assert_eq!(config.geometry, FalconGeometry::LIBNIFALCON);
        assert!(matches!(
            DeviceProfile::resolve("falcon").unwrap().kinematics,
            Kinematics::Falcon(_)
        ));
        // The leg angle is count · (π·shaft / (slots·4)) / (π·arm / 360) + offset (FalconKinematic.h:59-62):
        // doubling the shaft diameter doubles the angle per count; moving the offset moves every angle.
        let profile = parse(
            "device = \"falcon\"\n[kinematics]\nshaft_diameter_m = 0.0285\ntheta_offset_deg = 30\n",
        )
        .unwrap();
        let mut changed = FalconConfig::default();
        profile.apply_falcon(&mut changed);
        let (published, changed) = (FalconGeometry::LIBNIFALCON, changed.geometry);
        assert_eq!(
            changed.a_m, published.a_m,
            "keys not given keep libnifalcon's"
        );
        let per_count = |g: &FalconGeometry| g.leg_angle_rad(100) - g.leg_angle_rad(0);
        assert!((per_count(&changed) - 2.0 * per_count(&published)).abs() < 1e-12);
        assert!((changed.leg_angle_rad(0) - 30f64.to_radians()).abs() < 1e-12);
        // A longer thigh changes the inverse kinematics and so the torque for the same force.
        let longer = parse("device = \"falcon\"\n[kinematics]\na_m = 0.065\n").unwrap();
        let mut longer_config = FalconConfig::default();
        longer.apply_falcon(&mut longer_config);
        let p = DVec3::new(0.0, 0.0, 0.11);
        let up = DVec3::new(0.0, 0.0, 1.0);
        assert_ne!(
            longer_config.geometry.motor_commands(p, up),
            published.motor_commands(p, up)
        );
        // Round trip with the changed geometry: forward kinematics inverts its own inverse kinematics.
        let theta = longer_config.geometry.inverse_kinematics(p).theta1;
        let (found, converged) = longer_config
            .geometry
            .forward_kinematics(theta, DVec3::new(0.0, 0.0, 0.1));
        assert!(converged && (found - p).length() < 0.005, "{found}");
    }

    #[test]
    fn the_device_pages_example_profiles_parse() {
        // docs/devices/woodenhaptics.md: only the keys given change, the base's other keys and models stay.
        let profile = parse(
            "base = \"woodenhaptics\"\n[kinematics.woodenhaptics]\nlink_length_m = [0.080, 0.207, 0.245]\n\
             encoder_home_counts = [0, 0, -5980]\n",
        )
        .unwrap();
        let mut config = WoodyConfig::default();
        profile.apply_woodenhaptics(&mut config);
        let woody = config.model_constants[WoodyModel::WoodenHaptics.index()]
            .applied_to(WoodyModel::WoodenHaptics.config());
        assert_eq!(woody.link_length_m, [0.080, 0.207, 0.245]);
        assert_eq!(woody.encoder_home, [0, 0, -5980]);
        assert_eq!(woody.capstan_diameter_m, [0.010; 3]);
        let polhem = config.model_constants[WoodyModel::Polhem.index()]
            .applied_to(WoodyModel::Polhem.config());
        assert_eq!(polhem, WoodyModel::Polhem.config());
    }

    #[test]
    fn unknown_names_list_the_builtins_and_files_are_read() {
        let error = DeviceProfile::resolve("no-such-profile")
            .unwrap_err()
            .to_string();
        assert!(error.contains("haply-inverse"), "{error}");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lab.toml");
        std::fs::write(&path, "name = \"lab\"\n[mapping]\nscale = 2\n").unwrap();
        let profile = DeviceProfile::resolve(path.to_str().unwrap()).unwrap();
        assert_eq!(profile.name, "lab");
        std::fs::write(&path, vec![b'#'; MAX_PROFILE_BYTES as usize + 1]).unwrap();
        let error = DeviceProfile::read(&path).unwrap_err().to_string();
        assert!(error.contains("too long"), "{error}");
    }
}
