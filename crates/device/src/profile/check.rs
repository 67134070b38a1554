//! Checking a profile file as written ([`ProfileFile`]) into a [`DeviceProfile`]: every value finite and in range,
//! each kinematics table for the family it names; errors name the profile and the key.

use super::super::drivers::woodenhaptics_constants::WoodenHapticsConstants;
use super::super::mapping::{
    matrix_from_rows, rotation_from_degrees, MappingError, WorkspaceMapping,
};
use super::schema::*;
use glam::{DMat3, DVec3};

impl ProfileFile {
    pub(super) fn check(self, origin: &str) -> Result<DeviceProfile, ProfileError> {
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
                let kinematics = kinematics_of(self.device.as_deref(), table)
                    .map_err(|(key, problem)| key_error(&key, problem))?;
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
            limits: self.limits,
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
/// The kinematics constants in `table` for the `device` family (haply2diy, woodenhaptics-hid, falcon: one table
/// of numbers; woodenhaptics: one such table per model); errors name the key under `kinematics.`.
fn kinematics_of(device: Option<&str>, table: toml::Table) -> Result<Kinematics, (String, String)> {
    fn numbers_only(table: &toml::Table, prefix: &str) -> Result<(), (String, String)> {
        for (key, value) in table {
            let numbers = match value {
                toml::Value::Float(_) | toml::Value::Integer(_) => true,
                toml::Value::Array(items) => items
                    .iter()
                    .all(|v| matches!(v, toml::Value::Float(_) | toml::Value::Integer(_))),
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
    fn constants<T: serde::de::DeserializeOwned>(
        table: toml::Table,
    ) -> Result<T, (String, String)> {
        serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(
            |err: serde_path_to_error::Error<toml::de::Error>| {
                (
                    format!("kinematics.{}", err.path()),
                    err.into_inner().to_string().trim_end().to_owned(),
                )
            },
        )
    }
    let numbers = |table: toml::Table| numbers_only(&table, "kinematics.").map(|()| table);
    // One table per model: each holds numbers only.
    let per_model = |table: toml::Table| -> Result<toml::Table, (String, String)> {
        for (model, value) in &table {
            if let toml::Value::Table(inner) = value {
                numbers_only(inner, &format!("kinematics.{model}."))?;
            }
        }
        Ok(table)
    };
    Ok(match device {
        Some("haply2diy") => Kinematics::Haply2Diy(constants(numbers(table)?)?),
        Some("woodenhaptics-hid") => Kinematics::WoodenHapticsHid(constants(numbers(table)?)?),
        Some("falcon") => Kinematics::Falcon(constants(numbers(table)?)?),
        Some("woodenhaptics") => Kinematics::WoodenHaptics(constants(per_model(table)?)?),
        other => {
            return Err((
                "kinematics".to_owned(),
                format!(
                    "device {} takes no kinematics constants from a profile (haply2diy, \
                     woodenhaptics, woodenhaptics-hid and falcon do; set device = \"...\")",
                    other.map_or("(not set)".to_owned(), |d| format!("{d:?}"))
                ),
            ))
        }
    })
}

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
