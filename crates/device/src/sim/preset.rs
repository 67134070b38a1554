//! `[arm] preset = "inverse3" | "falcon" | "touch" | "woodenhaptics"`: a simulated arm's figures taken from a
//! vendor's documents or a published measurement, each with its source ([`ArmPreset::figures`]).
//!
//! Where it sits: read with the `[arm]` table (super::arm's `ArmTable`); a key written in the table wins over
//! the preset's figure. A figure no document gives is left out, not guessed: the table must then give it
//! (`arm: missing field mass_kg (preset "falcon" has no sourced figure for it; give it)`). That is the
//! honest state of public data: vendors publish position resolution, force and workspace, rarely the moving
//! mass, and practically never the damping or the transport latency.

use serde::{Deserialize, Serialize};

/// A device whose published figures a simulated arm can take.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArmPreset {
    /// Haply Inverse3.
    Inverse3,
    /// Novint Falcon.
    Falcon,
    /// 3D Systems Touch (formerly SensAble Phantom Omni).
    Touch,
    /// WoodenHaptics (Forsslund et al., TEI 2015).
    Woodenhaptics,
}

/// A preset's figures: `None` where no source was found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PresetFigures {
    /// Apparent moving mass at the handle (kg).
    pub mass_kg: Option<f64>,
    /// Viscous damping (N s/m).
    pub damping_n_s_per_m: Option<f64>,
    /// Position resolution (m).
    pub position_resolution_m: Option<f64>,
    /// Transport latency (s).
    pub latency_s: Option<f64>,
    /// Where the figures come from, and which are missing.
    pub source: &'static str,
}

impl ArmPreset {
    /// The name written in a scene file.
    pub fn name(self) -> &'static str {
        match self {
            ArmPreset::Inverse3 => "inverse3",
            ArmPreset::Falcon => "falcon",
            ArmPreset::Touch => "touch",
            ArmPreset::Woodenhaptics => "woodenhaptics",
        }
    }

    /// The preset's figures and their sources.
    pub fn figures(self) -> PresetFigures {
        match self {
            // Haply's public documentation (docs.haply.co, Inverse Service 3.5; "Developing with Inverse3":
            // frames, control modes, filters) describes the API; no mass, damping, resolution, latency, servo
            // rate or force figure was found in it or in a published measurement, so none is set
            // (docs/stability.md, "The presets' figures").
            ArmPreset::Inverse3 => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: None,
                latency_s: None,
                source: "no sourced figure (Haply's documentation gives none of mass, damping, \
                         resolution or latency)",
            },
            // Position resolution: Novint's product specification, "> 400 dpi" (25.4 mm / 400 = 0.0635 mm).
            // Latency: libnifalcon (FalconCommLibUSB.cpp) sets the FTDI USB latency timer to 1 ms after the
            // firmware load, a lower bound on the transport delay. Mass and damping: not sourced.
            ArmPreset::Falcon => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: Some(25.4e-3 / 400.0),
                latency_s: Some(1e-3),
                source: "position resolution: Novint Falcon specification (> 400 dpi); latency: \
                         libnifalcon's 1 ms USB latency timer; mass and damping not sourced",
            },
            // 3D Systems Touch specification sheet: nominal position resolution > 450 dpi (about 0.055 mm),
            // apparent mass at the tip about 45 g. Both as recorded when the preset was written: no copy of
            // the sheet was found to re-check them against. Damping, latency and servo rate: not published.
            ArmPreset::Touch => PresetFigures {
                mass_kg: Some(0.045),
                damping_n_s_per_m: None,
                position_resolution_m: Some(0.055e-3),
                latency_s: None,
                source: "3D Systems Touch specification sheet (> 450 dpi, apparent mass at tip ~45 g); \
                         damping and latency not sourced",
            },
            // Forsslund, Yip and Sallnäs, "WoodenHaptics: a starting kit for crafting force-reflecting
            // spatial haptic devices", TEI 2015: the paper compares the device with a Phantom Desktop but no
            // mass, damping, resolution or latency figure was found in what could be read; nor in the
            // repository (forsslund/woodenhaptics 6b9ad8a: README, parts list, firmware), whose Teensy
            // firmware README gives only the link's rate, about 1 kHz. None is set.
            ArmPreset::Woodenhaptics => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: None,
                latency_s: None,
                source: "no sourced figure (Forsslund et al., TEI 2015, gives none that could be checked)",
            },
        }
    }
}
