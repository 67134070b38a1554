//! The device profile's schema: the file as written (sections deserialised with unknown keys refused), the
//! checked profile ([`DeviceProfile`]) and its parts, the built-in profiles' texts and the profile error.

use super::super::drivers::falcon::FalconGeometry;
use super::super::drivers::woodenhaptics_constants::WoodenHapticsConstants;
use super::super::mapping::WorkspaceMapping;
use glam::{DMat3, DVec3};
use serde::Deserialize;

/// The built-in profiles: name, file text (contrib/profiles/).
pub const BUILTIN_PROFILES: &[(&str, &str)] = &[
    ("sim", include_str!("../../../../contrib/profiles/sim.toml")),
    (
        "haply-inverse",
        include_str!("../../../../contrib/profiles/haply-inverse.toml"),
    ),
    (
        "haply2diy",
        include_str!("../../../../contrib/profiles/haply2diy.toml"),
    ),
    (
        "woodenhaptics",
        include_str!("../../../../contrib/profiles/woodenhaptics.toml"),
    ),
    (
        "woodenhaptics-hid",
        include_str!("../../../../contrib/profiles/woodenhaptics-hid.toml"),
    ),
    (
        "falcon",
        include_str!("../../../../contrib/profiles/falcon.toml"),
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
pub(super) struct MappingSection {
    pub(super) scale: Option<f64>,
    pub(super) translation_m: Option<[f64; 3]>,
    pub(super) rotation_deg: Option<[f64; 3]>,
    pub(super) rotation_matrix: Option<[[f64; 3]; 3]>,
    pub(super) fit_volume: Option<bool>,
}

/// `[workspace]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct WorkspaceSection {
    pub(super) min_m: Option<[f64; 3]>,
    pub(super) max_m: Option<[f64; 3]>,
}

/// `[velocity_filter]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct VelocityFilterSection {
    pub(super) cutoff_hz: Option<f64>,
}

/// A profile file as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ProfileFile {
    pub(super) name: Option<String>,
    pub(super) device: Option<String>,
    /// Read from the table before deserialising (the built-in underneath).
    #[serde(rename = "base")]
    pub(super) _base: Option<String>,
    #[serde(default)]
    pub(super) mapping: MappingSection,
    #[serde(default)]
    pub(super) limits: ProfileLimits,
    #[serde(default)]
    pub(super) velocity_filter: VelocityFilterSection,
    #[serde(default)]
    pub(super) workspace: WorkspaceSection,
    pub(super) kinematics: Option<toml::Table>,
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

/// Limits that can only lower the device's own (`None`: the device's); `[limits]` as written, each value then
/// checked.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
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
