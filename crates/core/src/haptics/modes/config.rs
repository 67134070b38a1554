//! Mode settings as written in a scenario file ([`ModeConfig`]), and their validation into built
//! [`Mode`]s.
//!
//! Off the servo thread: a scenario (or, later, a server command) gives a list of `ModeConfig`s; the
//! scene builder ([`super::RenderScene::new`]) resolves volume names to indices, checks that each mode
//! reads the kind of volume it needs and that every key is one the mode uses, and produces the `Mode`s
//! the tick runs. Every error names the key, e.g. `modes[1].transfer: x must increase (...)` or
//! `modes[2].mu: a surface mode does not use this key`.

use super::limits::{
    readable, DEFAULT_POWER_BUDGET_W, MAX_COORDINATE_M, MAX_FRICTION_MU, MAX_POWER_BUDGET_W,
    MAX_STRENGTH_N,
};
use super::mode::{Mode, ModeError, SurfaceSide};
use super::transfer::TransferFunction;
use crate::haptics::Primitive;
use crate::volume::AnyVolume;
use glam::DVec3;
use serde::{Deserialize, Serialize};

crate::named_enum! {
    /// What a mode does; the `kind` key of a mode table.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    pub enum ModeKind {
        Surface => "surface",
        Friction => "friction",
        Viscosity => "viscosity",
        CoulombDrag => "coulomb_drag",
        VectorFollow => "vector_follow",
        Vortex => "vortex",
        VectorForce => "vector_force",
        GradientForce => "gradient_force",
        SupportPlane => "support_plane",
    }
}

impl ModeKind {
    /// True for the active (directed-force) modes, whose work on the hand is intended and bounded by their
    /// power budget: `vector_force` and `gradient_force`.
    pub fn is_active(self) -> bool {
        matches!(self, ModeKind::VectorForce | ModeKind::GradientForce)
    }

    /// The volume kind the mode reads, if any.
    fn volume_kind(self) -> Option<&'static str> {
        match self {
            ModeKind::Surface
            | ModeKind::Viscosity
            | ModeKind::CoulombDrag
            | ModeKind::GradientForce => Some("scalar"),
            ModeKind::VectorFollow | ModeKind::Vortex | ModeKind::VectorForce => Some("vector"),
            ModeKind::Friction | ModeKind::SupportPlane => None,
        }
    }
}

/// One mode as written in a scenario (`[[modes]]` table). Which keys a kind takes:
///
/// | kind | keys |
/// |---|---|
/// | `surface` | `volume`, `transfer`, optional `side` (`"outward"`, default, or `"inward"`) |
/// | `friction` | `surface` (the name of a surface mode), `mu` |
/// | `viscosity` | `volume`, `transfer` (value -> damping in N s/m) |
/// | `coulomb_drag`, `vector_follow`, `vortex` | `volume`, `transfer` |
/// | `vector_force`, `gradient_force` | `volume`, `transfer`, optional `power_budget_w` (default [`DEFAULT_POWER_BUDGET_W`]) |
/// | `support_plane` | `point_m`, `normal`, `strength_n` |
///
/// Every mode takes an optional `name` (default: its kind), unique within the scene; it labels the
/// mode's column in traces, and an optional `enabled` (default `true`): a mode with `enabled = false` keeps
/// its settings (breakpoints, `mu`, `strength_n`) and its trace column but renders no force (its strengths
/// are taken as 0 N). A key a kind does not use is an error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeConfig {
    pub kind: ModeKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Name of the volume the mode samples.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<String>,
    /// Data value -> strength (N).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transfer: Option<TransferFunction>,
    /// Surface: which way the plane faces.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub side: Option<SurfaceSide>,
    /// Friction: the name of the surface mode whose normal force it scales.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface: Option<String>,
    /// Friction: coefficient (dimensionless, 0 to [`MAX_FRICTION_MU`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mu: Option<f64>,
    /// Active modes (`vector_force`, `gradient_force`): the most power the mode may put into the hand (W,
    /// 0 to [`MAX_POWER_BUDGET_W`]; default [`DEFAULT_POWER_BUDGET_W`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub power_budget_w: Option<f64>,
    /// Support plane: a point on the plane (m, each coordinate within [`MAX_COORDINATE_M`] of 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point_m: Option<[f64; 3]>,
    /// Support plane: the side the plane pushes towards (any non-zero length).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal: Option<[f64; 3]>,
    /// Support plane: strength (N, 0 to [`MAX_STRENGTH_N`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub strength_n: Option<f64>,
    /// `Some(false)`: the mode is switched off (renders no force) but keeps every other setting. `None`
    /// and `Some(true)` both mean on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub enabled: Option<bool>,
}

impl ModeConfig {
    /// A mode of `kind` with no keys set (builders fill the rest).
    pub fn new(kind: ModeKind) -> Self {
        Self {
            kind,
            name: None,
            volume: None,
            transfer: None,
            side: None,
            surface: None,
            mu: None,
            power_budget_w: None,
            point_m: None,
            normal: None,
            strength_n: None,
            enabled: None,
        }
    }

    /// A volume-driven mode reading `volume` through `transfer`.
    pub fn sampled(kind: ModeKind, volume: &str, transfer: TransferFunction) -> Self {
        Self {
            volume: Some(volume.to_owned()),
            transfer: Some(transfer),
            ..Self::new(kind)
        }
    }

    /// Friction on the surface mode named `surface`.
    pub fn friction(surface: &str, mu: f64) -> Self {
        Self {
            surface: Some(surface.to_owned()),
            mu: Some(mu),
            ..Self::new(ModeKind::Friction)
        }
    }

    /// A fixed plane through `point_m` pushing along `normal`.
    pub fn support_plane(point_m: DVec3, normal: DVec3, strength_n: f64) -> Self {
        Self {
            point_m: Some(point_m.to_array()),
            normal: Some(normal.to_array()),
            strength_n: Some(strength_n),
            ..Self::new(ModeKind::SupportPlane)
        }
    }

    /// Sets a surface mode's side.
    pub fn with_side(mut self, side: SurfaceSide) -> Self {
        self.side = Some(side);
        self
    }

    /// Sets the mode's name.
    pub fn named(mut self, name: &str) -> Self {
        self.name = Some(name.to_owned());
        self
    }

    /// False when the mode is switched off (`enabled = false`).
    pub fn is_enabled(&self) -> bool {
        self.enabled != Some(false)
    }

    /// The mode's name: `name`, or the kind's name.
    pub fn display_name(&self) -> &str {
        self.name.as_deref().unwrap_or(self.kind.name())
    }

    /// Keys that are set, for the "does not use this key" check.
    fn set_keys(&self) -> [(&'static str, bool); 9] {
        [
            ("volume", self.volume.is_some()),
            ("transfer", self.transfer.is_some()),
            ("side", self.side.is_some()),
            ("surface", self.surface.is_some()),
            ("mu", self.mu.is_some()),
            ("power_budget_w", self.power_budget_w.is_some()),
            ("point_m", self.point_m.is_some()),
            ("normal", self.normal.is_some()),
            ("strength_n", self.strength_n.is_some()),
        ]
    }

    fn used_keys(&self) -> &'static [&'static str] {
        match self.kind {
            ModeKind::Surface => &["volume", "transfer", "side"],
            ModeKind::Friction => &["surface", "mu"],
            ModeKind::SupportPlane => &["point_m", "normal", "strength_n"],
            ModeKind::VectorForce | ModeKind::GradientForce => {
                &["volume", "transfer", "power_budget_w"]
            }
            _ => &["volume", "transfer"],
        }
    }

    /// Builds mode `index` of a scene. `volumes` are the scene's named volumes, `names` the display names
    /// of all its modes and `kinds` their kinds (to resolve a friction mode's surface).
    pub(super) fn build(
        &self,
        index: usize,
        volumes: &[(String, AnyVolume)],
        names: &[&str],
        kinds: &[ModeKind],
    ) -> Result<Mode, ModeError> {
        let invalid = |key: &'static str, problem: String| ModeError::Invalid {
            index,
            key,
            problem,
        };
        for (key, set) in self.set_keys() {
            if set && !self.used_keys().contains(&key) {
                return Err(invalid(
                    key,
                    format!("a {} mode does not use this key", self.kind.name()),
                ));
            }
        }
        let missing =
            |key: &'static str| invalid(key, format!("a {} mode needs this key", self.kind.name()));
        let out_of_range = |key: &'static str, value: f64, max: f64, unit: &str| {
            invalid(
                key,
                format!(
                    "must be a finite number from 0 to {}{unit}, got {}",
                    readable(max),
                    readable(value)
                ),
            )
        };
        let volume_index = || -> Result<usize, ModeError> {
            let name = self.volume.as_deref().ok_or_else(|| missing("volume"))?;
            let wanted = self.kind.volume_kind().unwrap_or("scalar");
            let found = volumes.iter().position(|(n, _)| n == name).ok_or_else(|| {
                let known: Vec<&str> = volumes.iter().map(|(n, _)| n.as_str()).collect();
                invalid(
                    "volume",
                    format!("no volume named {name:?} (known: {})", known.join(", ")),
                )
            })?;
            let kind = volumes[found].1.kind();
            if kind != wanted {
                return Err(invalid(
                    "volume",
                    format!(
                        "a {} mode needs a {wanted} volume, but {name:?} is a {kind} volume",
                        self.kind.name()
                    ),
                ));
            }
            Ok(found)
        };
        // A switched-off mode keeps its breakpoints in the configuration; the built mode gets the same
        // breakpoints with 0 N everywhere (so it emits nothing and its trace column stays).
        let enabled = self.is_enabled();
        let transfer = || {
            let transfer = self.transfer.clone().ok_or_else(|| missing("transfer"))?;
            if enabled {
                Ok(transfer)
            } else {
                Ok(transfer.scaled(0.0))
            }
        };
        let power_budget_w = || -> Result<f64, ModeError> {
            let budget = self.power_budget_w.unwrap_or(DEFAULT_POWER_BUDGET_W);
            if !(0.0..=MAX_POWER_BUDGET_W).contains(&budget) {
                return Err(out_of_range(
                    "power_budget_w",
                    budget,
                    MAX_POWER_BUDGET_W,
                    " W",
                ));
            }
            Ok(budget)
        };
        Ok(match self.kind {
            ModeKind::Surface => Mode::Surface {
                volume: volume_index()?,
                transfer: transfer()?,
                side: self.side.unwrap_or_default(),
            },
            ModeKind::Viscosity => Mode::Viscosity {
                volume: volume_index()?,
                transfer: transfer()?,
            },
            ModeKind::CoulombDrag => Mode::CoulombDrag {
                volume: volume_index()?,
                transfer: transfer()?,
            },
            ModeKind::GradientForce => Mode::GradientForce {
                volume: volume_index()?,
                transfer: transfer()?,
                power_budget_w: power_budget_w()?,
            },
            ModeKind::VectorFollow => Mode::VectorFollow {
                volume: volume_index()?,
                transfer: transfer()?,
            },
            ModeKind::Vortex => Mode::Vortex {
                volume: volume_index()?,
                transfer: transfer()?,
            },
            ModeKind::VectorForce => Mode::VectorForce {
                volume: volume_index()?,
                transfer: transfer()?,
                power_budget_w: power_budget_w()?,
            },
            ModeKind::Friction => {
                let surface = self.surface.as_deref().ok_or_else(|| missing("surface"))?;
                let mu = self.mu.ok_or_else(|| missing("mu"))?;
                if !(0.0..=MAX_FRICTION_MU).contains(&mu) {
                    return Err(out_of_range("mu", mu, MAX_FRICTION_MU, ""));
                }
                let surface_mode = names
                    .iter()
                    .position(|n| *n == surface)
                    .ok_or_else(|| invalid("surface", format!("no mode named {surface:?}")))?;
                if kinds[surface_mode] != ModeKind::Surface {
                    return Err(invalid(
                        "surface",
                        format!(
                            "mode {surface:?} is a {} mode, not a surface mode",
                            kinds[surface_mode].name()
                        ),
                    ));
                }
                let mu = if enabled { mu } else { 0.0 };
                Mode::Friction { surface_mode, mu }
            }
            ModeKind::SupportPlane => {
                let point = self.point_m.ok_or_else(|| missing("point_m"))?;
                let normal = self.normal.ok_or_else(|| missing("normal"))?;
                let strength = self.strength_n.ok_or_else(|| missing("strength_n"))?;
                if !(0.0..=MAX_STRENGTH_N).contains(&strength) {
                    return Err(out_of_range("strength_n", strength, MAX_STRENGTH_N, " N"));
                }
                if !point.iter().all(|c| c.abs() <= MAX_COORDINATE_M) {
                    return Err(invalid(
                        "point_m",
                        format!(
                            "must be three finite numbers, each from -{0} to {0} m, got [{1}]",
                            readable(MAX_COORDINATE_M),
                            point.map(readable).join(", ")
                        ),
                    ));
                }
                let strength = if enabled { strength } else { 0.0 };
                let plane = Primitive::plane(
                    DVec3::from_array(point),
                    DVec3::from_array(normal),
                    strength,
                )
                .map_err(|err| {
                    let key = match err {
                        crate::haptics::PrimitiveError::BadStrength(_) => "strength_n",
                        crate::haptics::PrimitiveError::BadPosition(_) => "point_m",
                        _ => "normal",
                    };
                    invalid(key, err.to_string())
                })?;
                Mode::SupportPlane { plane }
            }
        })
    }
}
