//! The checks and scene edits of the control commands that change the coupling or the modes, shared by the
//! control-command interpreter of a running session (`crate::control`) and the `[[events]]` of a sim
//! scenario (`crate::sim::events`), so a command is validated the same way wherever it is given.

use voxhap_api::ControlError;
use voxhap_core::haptics::modes::{ModeConfig, TransferFunction};

fn invalid(message: String) -> ControlError {
    ControlError::Invalid(message)
}

fn finite(name: &str, value: f64) -> Result<f64, ControlError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(invalid(format!(
            "{name} must be a finite number, got {value}"
        )))
    }
}

/// `set_stiffness`: `k` finite, > 0 and at most `max` (`limit` names where the maximum comes from, e.g.
/// "the device's").
pub fn check_stiffness(k: f64, max: f64, limit: &str) -> Result<f64, ControlError> {
    let k = finite("k", k)?;
    if k <= 0.0 || k > max {
        return Err(invalid(format!(
            "k must be > 0 and at most {limit} {max} N/m, got {k}"
        )));
    }
    Ok(k)
}

/// `set_damping`: finite and >= 0.
pub fn check_damping(damping: f64) -> Result<f64, ControlError> {
    let damping = finite("damping", damping)?;
    if damping < 0.0 {
        return Err(invalid(format!(
            "damping must be >= 0 N s/m, got {damping}"
        )));
    }
    Ok(damping)
}

/// `set_stiffness` (`k`), `set_damping` (`damping`) and `set_coupling` (both): the coupling `(k, damping)`
/// after the command, from the coupling in use `now`, and the reply's message. `check_k` checks a stiffness,
/// `check_damping` a damping at the stiffness it will be used with; the whole request is checked before
/// anything changes, so a refused damping leaves the stiffness as it was.
pub fn set_coupling<E>(
    k: Option<f64>,
    damping: Option<f64>,
    (k_now, damping_now): (f64, f64),
    check_k: impl FnOnce(f64) -> Result<f64, E>,
    check_damping: impl FnOnce(f64, f64) -> Result<f64, E>,
) -> Result<(f64, f64, String), E> {
    let new_k = k.map_or(Ok(k_now), check_k)?;
    let new_damping = match damping {
        Some(damping) => check_damping(damping, new_k)?,
        None => damping_now,
    };
    let message = match (k, damping) {
        (Some(_), None) => format!("stiffness set to {new_k} N/m"),
        (None, Some(_)) => format!("damping set to {new_damping} N s/m"),
        _ => format!("stiffness set to {new_k} N/m; damping set to {new_damping} N s/m"),
    };
    Ok((new_k, new_damping, message))
}

/// The index of the mode named `name`.
pub fn mode_index(modes: &[ModeConfig], name: &str) -> Result<usize, ControlError> {
    modes
        .iter()
        .position(|m| m.display_name() == name)
        .ok_or_else(|| {
            let names: Vec<&str> = modes.iter().map(|m| m.display_name()).collect();
            ControlError::NotFound(format!("no mode named {name:?} (modes: {names:?})"))
        })
}

/// `set_transfer` and `set_mode_enabled`: what they change in the mode they name.
#[derive(Debug, Clone, PartialEq)]
pub enum ModeEdit {
    /// `set_transfer`: a new transfer function (the mode must have one).
    Transfer(TransferFunction),
    /// `set_mode_enabled`: on or off.
    Enabled(bool),
}

/// Applies `edit` to the mode named `mode`; returns the reply's message.
pub fn edit_mode(
    modes: &mut [ModeConfig],
    mode: &str,
    edit: ModeEdit,
) -> Result<String, ControlError> {
    let index = mode_index(modes, mode)?;
    let config = &mut modes[index];
    match edit {
        ModeEdit::Transfer(transfer) => {
            if config.transfer.is_none() {
                return Err(invalid(format!("mode {mode:?} has no transfer function")));
            }
            config.transfer = Some(transfer);
            Ok(format!("transfer function of {mode:?} replaced"))
        }
        ModeEdit::Enabled(enabled) => {
            config.enabled = (!enabled).then_some(false);
            let state = if enabled { "on" } else { "off" };
            Ok(format!("mode {mode:?} switched {state}"))
        }
    }
}
