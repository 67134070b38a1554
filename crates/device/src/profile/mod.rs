//! Device profiles: a small TOML file (or a `[device]` table in a scene file) saying how one arm is used in
//! this lab: where its workspace lands in the scene ([`WorkspaceMapping`]), limits that may only lower the
//! device's own, the velocity filter, and kinematics calibration constants for drivers that compute kinematics.
//!
//! Where it sits: read off the real-time path when `voxhap serve` starts (`--device-profile NAME|FILE`, or the
//! scene's `[device]` table); its limits are folded into the supervisor's settings before the device opens, its
//! mapping and coupling caps go into `servo::mapped::MappedDevice`, its kinematics into the driver's config.
//! `voxhap calibrate` writes one. docs/workspace.md is the user's reference; every key is listed there.
//!
//! Parts: `schema` holds the file as written and the checked [`DeviceProfile`], `check` turns one into the other
//! (every error names the profile and the key); this module finds a profile by name or file, lays it over a
//! built-in, and applies it to the supervisor's and the drivers' configurations.
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

mod check;
mod schema;

use super::drivers::falcon::FalconConfig;
use super::drivers::haply::Haply2DiyConfig;
use super::drivers::woodenhaptics_kinematics::WoodyKinematics;
use super::drivers::woodenhaptics_serial::{WoodyConfig, WoodyModel};
use super::mapping::{MappingError, WorkspaceMapping};
use super::supervisor::SupervisorConfig;
use super::DeviceInfo;
use glam::DVec3;
use schema::ProfileFile;
pub use schema::{
    DeviceProfile, Haply2DiyKinematics, Kinematics, MappingChoice, ProfileError, ProfileLimits,
    WoodenHapticsKinematics, BUILTIN_PROFILES, DEVICE_FAMILIES, MAX_PROFILE_BYTES,
};
use std::path::Path;

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

    /// Applies the WoodenHaptics (HID) kinematics constants (where given) to the driver's kinematics.
    pub fn apply_woodenhaptics_hid(&self, config: &mut WoodyKinematics) {
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

#[cfg(test)]
mod tests;
