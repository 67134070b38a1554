//! The arms the stability measurements cover: the simulated arm's default and each `[arm] preset`, with the
//! figures a preset lacks given here and where each comes from.

use voxhap_device::sim::ArmPreset;

/// One arm: a preset (or the default arm), its mass and damping, and where those figures come from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmCase {
    /// The `[arm] preset`, `None` for the default arm.
    pub preset: Option<ArmPreset>,
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Where the mass comes from.
    pub mass_source: &'static str,
    /// The arm's own damping, N s/m.
    pub damping_n_s_per_m: f64,
    /// Where the damping comes from.
    pub damping_source: &'static str,
}

impl ArmCase {
    /// The name in tables and on the command line: `default`, or the preset's name.
    pub fn name(&self) -> &'static str {
        self.preset.map_or("default", ArmPreset::name)
    }
}

/// No vendor publishes a damping figure for any of these arms (voxhap_device::sim::preset); the value used is
/// the one voxhap's own drivers imply: the Falcon, Inverse3 and WoodenHaptics drivers declare 1 000 N/m at
/// 1 kHz, passive by the bound when `b = K T / 2 = 0.5 N s/m`.
pub const DAMPING_ESTIMATE: &str =
    "estimate (none published; 1 000 N/m at 1 kHz, voxhap's driver cap, implies 0.5)";

/// Where no mass is published (voxhap_device::sim::preset) the simulated arm's default, 0.1 kg, is used: the
/// exact boundary falls towards `2 b / T` as the mass grows and rises above it for a light, heavily damped
/// arm, so a mass on the heavy side errs towards the lower limit; it changes the boundary by well under 1 %
/// at these rates.
pub const MASS_ESTIMATE: &str = "estimate (none published; the simulated arm's default)";

/// The arms, the default first.
pub const ARMS: [ArmCase; 5] = [
    ArmCase {
        preset: None,
        mass_kg: 0.1,
        mass_source: "the simulated arm's default",
        damping_n_s_per_m: 1.0,
        damping_source: "the simulated arm's default",
    },
    ArmCase {
        preset: Some(ArmPreset::Touch),
        mass_kg: 0.1,
        mass_source: MASS_ESTIMATE,
        damping_n_s_per_m: 0.5,
        damping_source: DAMPING_ESTIMATE,
    },
    ArmCase {
        preset: Some(ArmPreset::Falcon),
        mass_kg: 0.1,
        mass_source: MASS_ESTIMATE,
        damping_n_s_per_m: 0.5,
        damping_source: DAMPING_ESTIMATE,
    },
    ArmCase {
        preset: Some(ArmPreset::Inverse3),
        mass_kg: 0.1,
        mass_source: MASS_ESTIMATE,
        damping_n_s_per_m: 0.5,
        damping_source: DAMPING_ESTIMATE,
    },
    ArmCase {
        preset: Some(ArmPreset::Woodenhaptics),
        mass_kg: 0.1205,
        mass_source: "preset (computed from the link masses of the WoodenHaptics chai3d extension)",
        damping_n_s_per_m: 0.5,
        damping_source: DAMPING_ESTIMATE,
    },
];

/// The arm called `name` (`default` or a preset's name).
pub fn arm_named(name: &str) -> Option<&'static ArmCase> {
    ARMS.iter().find(|arm| arm.name() == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A preset added to `voxhap_device::sim::ArmPreset` must be given its figures here.
    #[test]
    fn every_preset_is_an_arm() {
        for name in ArmPreset::NAMES {
            let arm = arm_named(name).unwrap_or_else(|| panic!("no arm case for preset {name:?}"));
            assert_eq!(arm.preset.map(ArmPreset::name), Some(name));
        }
        assert_eq!(
            ARMS.len(),
            ArmPreset::NAMES.len() + 1,
            "one default arm, then the presets"
        );
        assert_eq!(ARMS[0].name(), "default");
    }
}
