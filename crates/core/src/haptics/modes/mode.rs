//! What a mode is (its kind and settings), the most modes a scene holds, and why a scene is refused.

use super::transfer::TransferFunction;
use crate::haptics::Primitive;
use serde::{Deserialize, Serialize};

/// The most modes a scene holds: the width of the per-mode primitive counts in a tick's output and in
/// traces (the trace format's limit).
pub const MAX_MODES: usize = 8;

/// Smallest gradient, vector or curl magnitude (in the data's unit per metre, or its unit) that defines a
/// direction. Below it the mode emits nothing.
pub const MIN_DIRECTION_MAGNITUDE: f64 = 1e-9;

/// Which way a surface plane faces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SurfaceSide {
    /// Normal `-grad V/abs(grad V)`: the plane pushes towards lower values. For a density (dense inside)
    /// this is out of the material, so the proxy stays outside.
    #[default]
    Outward,
    /// Normal `+grad V/abs(grad V)`: the plane pushes towards higher values (keeps the proxy inside).
    Inward,
}

/// A built mode: volume names resolved to indices into [`RenderScene::volumes`], settings validated.
#[derive(Debug, Clone, PartialEq)]
pub enum Mode {
    Surface {
        volume: usize,
        transfer: TransferFunction,
        side: SurfaceSide,
    },
    Friction {
        /// Index of the surface mode in the scene.
        surface_mode: usize,
        mu: f64,
    },
    /// Viscous drag: `transfer` maps the value to a damping coefficient `b` in N s/m.
    Viscosity {
        volume: usize,
        transfer: TransferFunction,
    },
    /// Constant-magnitude (Coulomb) drag: a point at the proxy of strength `transfer(V)` N.
    CoulombDrag {
        volume: usize,
        transfer: TransferFunction,
    },
    VectorFollow {
        volume: usize,
        transfer: TransferFunction,
    },
    Vortex {
        volume: usize,
        transfer: TransferFunction,
    },
    VectorForce {
        volume: usize,
        transfer: TransferFunction,
        /// The most power (W) the mode may put into the hand.
        power_budget_w: f64,
    },
    GradientForce {
        volume: usize,
        transfer: TransferFunction,
        /// The most power (W) the mode may put into the hand.
        power_budget_w: f64,
    },
    SupportPlane {
        plane: Primitive,
    },
}

/// Why a scene could not be built. Mode errors name the key: `modes[1].transfer: x must increase ...`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModeError {
    #[error("modes[{index}].{key}: {problem}")]
    Invalid {
        index: usize,
        key: &'static str,
        problem: String,
    },
    #[error("k: stiffness must be a finite number > 0 N/m, got {0}")]
    BadStiffness(f64),
    #[error("modes: {0} modes is more than the {MAX_MODES} a scene can hold")]
    TooManyModes(usize),
    #[error("modes[{index}].name: {name:?} is used by another mode; give each mode a unique name")]
    DuplicateModeName { index: usize, name: String },
    #[error("modes[{index}].name: {name:?} must be non-empty ASCII letters, digits, '_' or '-'")]
    BadModeName { index: usize, name: String },
    #[error("volumes: the name {0:?} is used twice")]
    DuplicateVolumeName(String),
}
