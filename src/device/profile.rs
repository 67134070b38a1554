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

use super::drivers::haply::Haply2DiyConfig;
use super::drivers::woodenhaptics::WoodenHapticsConfig;
use super::mapping::{matrix_from_rows, rotation_from_degrees, MappingError, WorkspaceMapping};
use super::supervisor::SupervisorConfig;
use super::DeviceInfo;
use glam::{DMat3, DVec3};
use serde::Deserialize;
use std::path::Path;

/// The built-in profiles: name, file text (contrib/profiles/).
pub const BUILTIN_PROFILES: &[(&str, &str)] = &[
    ("sim", include_str!("../../contrib/profiles/sim.toml")),
    (
        "haply-inverse",
        include_str!("../../contrib/profiles/haply-inverse.toml"),
    ),
    (
        "haply2diy",
        include_str!("../../contrib/profiles/haply2diy.toml"),
    ),
    (
        "woodenhaptics",
        include_str!("../../contrib/profiles/woodenhaptics.toml"),
    ),
    (
        "woodenhaptics-hid",
        include_str!("../../contrib/profiles/woodenhaptics-hid.toml"),
    ),
    ("falcon", include_str!("../../contrib/profiles/falcon.toml")),
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

/// WoodenHaptics (legacy HID) kinematics constants (see `drivers::woodenhaptics`); each replaces the default.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WoodenHapticsHidKinematics {
    pub capstan_diameter_m: Option<[f64; 3]>,
    pub body_diameter_m: Option<[f64; 3]>,
    pub link_length_m: Option<[f64; 3]>,
    pub workspace_origin_m: Option<[f64; 3]>,
    pub torque_constant_n_m_per_a: Option<[f64; 3]>,
    pub counts_per_revolution: Option<[f64; 3]>,
}

/// Kinematics constants for the drivers that compute kinematics on the host.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum Kinematics {
    /// None given: the driver's published defaults.
    #[default]
    Default,
    Haply2Diy(Haply2DiyKinematics),
    WoodenHapticsHid(WoodenHapticsHidKinematics),
}

/// Where the workspace goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MappingChoice {
    /// This mapping.
    Fixed(WorkspaceMapping),
    /// Fit the loaded volume's bounds into the device's workspace, keeping this rotation.
    FitVolume { rotation: DMat3 },
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
        file.check(origin)
    }

    /// The mapping for a device with the workspace box `[min, max]` (replaced by the profile's measured
    /// `[workspace]` when it has one) and a volume with the bounds given (when one is loaded): the fixed one,
    /// or the fitted one.
    pub fn mapping_for(
        &self,
        device_min_m: DVec3,
        device_max_m: DVec3,
        volume_bounds_m: Option<(DVec3, DVec3)>,
    ) -> Result<WorkspaceMapping, MappingError> {
        match self.mapping {
            MappingChoice::Fixed(mapping) => Ok(mapping),
            MappingChoice::FitVolume { rotation } => {
                let (device_min_m, device_max_m) =
                    self.workspace_m.unwrap_or((device_min_m, device_max_m));
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

    /// Applies the WoodenHaptics (HID) kinematics constants (where given) to a driver config.
    pub fn apply_woodenhaptics_hid(&self, config: &mut WoodenHapticsConfig) {
        if let Kinematics::WoodenHapticsHid(k) = &self.kinematics {
            set(&mut config.capstan_diameter_m, k.capstan_diameter_m);
            set(&mut config.body_diameter_m, k.body_diameter_m);
            set(&mut config.link_length_m, k.link_length_m);
            set(&mut config.workspace_origin_m, k.workspace_origin_m);
            set(
                &mut config.torque_constant_n_m_per_a,
                k.torque_constant_n_m_per_a,
            );
            set(&mut config.counts_per_revolution, k.counts_per_revolution);
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
                let parse = |table: toml::Table| -> Result<toml::Value, ProfileError> {
                    for (key, value) in &table {
                        let all_positive_finite = match value {
                            toml::Value::Float(_) | toml::Value::Integer(_) => true,
                            toml::Value::Array(items) => items.iter().all(|v| {
                                matches!(v, toml::Value::Float(_) | toml::Value::Integer(_))
                            }),
                            _ => false,
                        };
                        if !all_positive_finite {
                            return Err(key_error(
                                &format!("kinematics.{key}"),
                                "must be a number or an array of numbers".to_owned(),
                            ));
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
                    other => {
                        return Err(key_error(
                            "kinematics",
                            format!(
                                "device {} takes no kinematics constants from a profile (haply2diy and \
                                 woodenhaptics-hid do; set device = \"...\")",
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
        })
    }
}

/// Lengths, diameters, constants and resolutions must be finite and > 0; offsets finite.
fn check_kinematics(kinematics: &Kinematics) -> Result<(), (&'static str, String)> {
    let positive = |key: &'static str, values: &[f64]| {
        if values.iter().all(|v| v.is_finite() && *v > 0.0) {
            Ok(())
        } else {
            Err((key, format!("{values:?} must be finite and > 0")))
        }
    };
    let finite = |key: &'static str, values: &[f64]| {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err((key, format!("{values:?} must be finite")))
        }
    };
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
                if !(v.is_finite() && v >= 0.0) {
                    return Err(("base_distance_m", format!("{v} must be finite and >= 0")));
                }
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
            for (key, value) in [
                ("capstan_diameter_m", k.capstan_diameter_m),
                ("body_diameter_m", k.body_diameter_m),
                ("link_length_m", k.link_length_m),
                ("torque_constant_n_m_per_a", k.torque_constant_n_m_per_a),
                ("counts_per_revolution", k.counts_per_revolution),
            ] {
                if let Some(v) = value {
                    positive(key, &v)?;
                }
            }
            if let Some(v) = k.workspace_origin_m {
                finite("workspace_origin_m", &v)?;
            }
            Ok(())
        }
    }
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
            ("[limits]\nmax_force = 1\n", "limits"),
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
                "kinematics",
            ),
            (
                "device = \"woodenhaptics-hid\"\n[kinematics]\nlink_length_m = [0.08, 0.2]\n",
                "kinematics.link_length_m",
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
