//! The WoodenHaptics kinematic and motor constants a device profile may replace: one type for both
//! WoodenHaptics drivers, the Teensy serial firmware's ([`super::woodenhaptics_serial`], one table per model:
//! `[kinematics.woodenhaptics]`, `.polhem`, `.vintage`) and the legacy HID firmware's
//! ([`super::woodenhaptics`], `[kinematics]` with `device = "woodenhaptics-hid"`).
//!
//! Where it sits: read from a profile and checked by `device::profile`, then laid over the driver's published
//! constants, key by key, before the device opens ([`WoodenHapticsConstants::applied_to`] for the serial
//! firmware's model constants, [`WoodenHapticsConstants::apply_to_hid`] for the HID driver's configuration).
//! Never on the servo path.

use super::woodenhaptics_kinematics::WoodyKinematics;

/// Constants that replace a WoodenHaptics driver's published ones; `None` keeps the published value. Checked
/// by `device::profile` (diameters, torque constants and counts finite and > 0, link lengths finite and > 0,
/// or >= 0 for the serial firmware's models, whose published constants set one to zero; origins finite).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WoodenHapticsConstants {
    /// Capstan diameters A, B, C (m).
    pub capstan_diameter_m: Option<[f64; 3]>,
    /// Body (drum) diameters A, B, C (m).
    pub body_diameter_m: Option<[f64; 3]>,
    /// Link lengths A, B, C (m); the serial chain only (Polhem's closed chain has its own lengths).
    pub link_length_m: Option<[f64; 3]>,
    /// Workspace origin subtracted from the position (m).
    pub workspace_origin_m: Option<[f64; 3]>,
    /// Motor torque constants (N m / A).
    pub torque_constant_n_m_per_a: Option<[f64; 3]>,
    /// Encoder counts per revolution.
    pub counts_per_revolution: Option<[f64; 3]>,
    /// Encoder counts at the home pose, added to every reading (hfab_api.cpp:103-106). The serial firmware's
    /// models only: the legacy HID driver has no home offset, and a profile for it may not set this.
    pub encoder_home_counts: Option<[i32; 3]>,
}

fn set<T: Copy>(target: &mut T, value: Option<T>) {
    if let Some(value) = value {
        *target = value;
    }
}

impl WoodenHapticsConstants {
    /// Replaces the shared constants, in the order capstan diameters, body diameters, link lengths,
    /// workspace origin, torque constants, counts per revolution.
    fn replace_shared(&self, targets: [&mut [f64; 3]; 6]) {
        let values = [
            self.capstan_diameter_m,
            self.body_diameter_m,
            self.link_length_m,
            self.workspace_origin_m,
            self.torque_constant_n_m_per_a,
            self.counts_per_revolution,
        ];
        for (target, value) in targets.into_iter().zip(values) {
            set(target, value);
        }
    }

    /// The legacy HID driver's kinematics with the constants given here replaced (`encoder_home_counts` is
    /// not taken: that firmware's home offset is fixed, and `device::profile` refuses it there).
    pub fn apply_to_hid(&self, kinematics: &mut WoodyKinematics) {
        *kinematics = WoodenHapticsConstants {
            encoder_home_counts: None,
            ..*self
        }
        .applied_to(*kinematics);
    }

    /// A serial-firmware model's `kinematics` with the constants given here replaced.
    pub fn applied_to(&self, mut kinematics: WoodyKinematics) -> WoodyKinematics {
        self.replace_shared([
            &mut kinematics.capstan_diameter_m,
            &mut kinematics.body_diameter_m,
            &mut kinematics.link_length_m,
            &mut kinematics.workspace_origin_m,
            &mut kinematics.torque_constant_n_m_per_a,
            &mut kinematics.counts_per_revolution,
        ]);
        set(&mut kinematics.encoder_home, self.encoder_home_counts);
        kinematics
    }
}
