//! `[arm] preset = "inverse3" | "falcon" | "touch" | "woodenhaptics"`: a simulated arm's figures taken from a
//! vendor's documents or a published measurement, each with its source ([`ArmPreset::figures`]).
//!
//! Where it sits: read with the `[arm]` table (super::arm's `ArmTable`); a key written in the table wins over
//! the preset's figure. A figure no document gives is left out, not guessed: the table must then give it
//! (``missing field `mass_kg` (preset "falcon" has no sourced figure for it: …; give it)``). That is the
//! honest state of public data: vendors publish position resolution, force and workspace, rarely the moving
//! mass, and practically never the damping or the transport latency. A figure computed from published parts
//! (encoder counts and capstan ratios, link masses) shows its calculation beside it. The stiffness sweeps
//! (voxhap_servo::sim::stability::arms) fill what a preset lacks with stated estimates.

use serde::{Deserialize, Serialize};

/// Declares [`ArmPreset`] with each preset's scene-file name written once: serde reads and writes that name,
/// [`ArmPreset::name`] returns it, [`ArmPreset::NAMES`] lists them all and [`ArmPreset::ALL`] lists the presets.
macro_rules! arm_presets {
    ($($(#[$doc:meta])* $variant:ident = $name:literal,)+) => {
        /// A device whose published figures a simulated arm can take.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
        pub enum ArmPreset {
            $($(#[$doc])* #[serde(rename = $name)] $variant,)+
        }

        impl ArmPreset {
            /// Every preset's scene-file name, in declaration order.
            pub const NAMES: [&'static str; [$($name),+].len()] = [$($name),+];

            /// Every preset, in declaration order.
            pub const ALL: [ArmPreset; [$($name),+].len()] = [$(ArmPreset::$variant),+];

            /// The name written in a scene file.
            pub fn name(self) -> &'static str {
                match self {
                    $(ArmPreset::$variant => $name,)+
                }
            }
        }
    };
}

arm_presets! {
    /// Haply Inverse3.
    Inverse3 = "inverse3",
    /// Novint Falcon.
    Falcon = "falcon",
    /// 3D Systems Touch (formerly SensAble Phantom Omni).
    Touch = "touch",
    /// WoodenHaptics (Forsslund et al., TEI 2015).
    Woodenhaptics = "woodenhaptics",
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
    /// The preset's figures and their sources. Every figure set here comes from a document that was read
    /// (listed in docs/stability.md, "The presets' figures"); no vendor or paper read gives a viscous
    /// damping for any of the four, so `damping_n_s_per_m` is never set.
    pub fn figures(self) -> PresetFigures {
        match self {
            // Haply's public documentation (docs.haply.co, "Developing with Inverse3": frames, control modes,
            // filters) describes the API; no mass, damping, resolution or latency figure was found in it nor
            // in a published measurement, so none is set.
            ArmPreset::Inverse3 => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: None,
                latency_s: None,
                source: "none of mass, damping, position resolution or latency is sourced: Haply's \
                         documentation gives none of them",
            },
            // Position resolution: Novint's specification, "Position Resolution > 400 dpi" (as reproduced in
            // the H3D API wiki's Novint Falcon page, SenseGraphics/h3dapi): 25.4 mm / 400 = 0.0635 mm.
            // Latency: libnifalcon sets the FTDI chip's USB latency timer to 1 ms once the firmware is loaded
            // (include/falcon/core/FalconComm.h; src/comm/FalconCommFTD2XX.cpp, FT_SetLatencyTimer(.., 1)),
            // a lower bound on the transport delay. Mass and damping: no published figure was found (Forsslund
            // et al., TEI 2015, Table 1, measured its back-drive friction, 1.2 / 3.6 / 1.3 N sideways /
            // inwards / upwards, a Coulomb force, not a viscous damping).
            ArmPreset::Falcon => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: Some(25.4e-3 / 400.0),
                latency_s: Some(1e-3),
                source: "position resolution: Novint Falcon specification (> 400 dpi); latency: \
                         libnifalcon's 1 ms USB latency timer; mass and damping not published",
            },
            // No copy of 3D Systems' Touch specification sheet could be read, so none of its figures is set.
            // Forsslund et al., TEI 2015, Table 1, measured the Phantom Omni's back-drive
            // friction (0.2 / 0.4 / 1.1 N) and continuous force (0.88 N), neither of which is one of these keys.
            ArmPreset::Touch => PresetFigures {
                mass_kg: None,
                damping_n_s_per_m: None,
                position_resolution_m: None,
                latency_s: None,
                source: "none of mass, damping, position resolution or latency is sourced: no copy of 3D \
                         Systems' Touch specification could be read",
            },
            // Computed from the parts of the published design: the chai3d 3.0 WoodenHaptics extension in
            // forsslund/woodenhaptics (Software/chai3d-3.0.0-woodenhaptics-extension.zip,
            // src/devices/CWoodenDevice.cpp lines 90-98, default_woody()): capstans 10 mm, bodies A 160 mm and
            // B, C 120 mm across (ratios 16, 12, 12), encoders 4096 (A) and 2000 (B, C) "quadrupled counts per
            // revolution" (CWoodenDevice.h), links Lb = 0.205 m and Lc = 0.200 m, link masses mB = 0.170 kg and
            // mC = 0.110 kg with centres 0.051 m and 0.091 m from their joints (its gravity compensation's
            // figures). The 2000 counts agree with the kit's parts list (the repository's TEI-2015 bill of
            // materials: "Maxon 40mm (148877) & 500 CPR Encoder (110514) combination", three of them) and the
            // encoder's data sheet in the repository (Docs/Encoder_Maxon_HEDL_5540.pdf: HEDL 5540, order number
            // 110514, 500 counts per turn): 4 x 500 = 2000 quadrature counts per motor turn.
            // - Resolution: one count of B's or C's encoder turns the link 2 pi / (2000 x 12) = 2.618e-4 rad,
            //   at the home pose (B upright, C level) Lb x 2.618e-4 = 0.0537 mm in/out and Lc x 2.618e-4 =
            //   0.0524 mm up/down (A: 0.200 x 2 pi / (4096 x 16) = 0.0192 mm sideways, or 0.0393 mm with the
            //   parts list's 500-count encoder); the coarsest is set.
            // - Mass: the links as point masses at their centres, at the home pose: in/out the tip moves with
            //   B swinging and C carried, mB (0.051 / 0.205)^2 + mC = 0.0105 + 0.110 = 0.1205 kg; up/down with C
            //   swinging, mC (0.091 / 0.200)^2 = 0.023 kg. The larger is set. It leaves out the Maxon RE40
            //   rotors reflected through the capstans (x 12^2) and body A: no rotor inertia was read (the
            //   encoder's code wheel, <= 0.6 g cm^2 by its data sheet, adds at most 0.6e-7 x 144 / 0.205^2 =
            //   0.2 g), so it is a lower bound on the true apparent mass.
            // Damping and latency: not published. The paper (Forsslund, Yip and Sallnäs, TEI 2015, Table 1)
            // gives its back-drive friction, 0.6 / 0.7 / 0.9 N, a Coulomb force; the extension's
            // max_linear_damping (8.0 N s/m) is the most virtual damping chai3d may render, not the arm's own;
            // and the paper's "the delay has to be less than 1 ms" is a requirement, not a measured latency.
            ArmPreset::Woodenhaptics => PresetFigures {
                mass_kg: Some(0.1205),
                damping_n_s_per_m: None,
                position_resolution_m: Some(0.0537e-3),
                latency_s: None,
                source: "mass and position resolution computed from the WoodenHaptics chai3d extension's \
                         link masses, encoder counts and capstan ratios; damping and latency not published",
            },
        }
    }
}

#[cfg(test)]
#[path = "preset_tests.rs"]
mod tests;
