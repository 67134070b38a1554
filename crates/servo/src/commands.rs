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

/// `set_transfer`: replaces the transfer function of the mode named `mode`; returns the reply's message.
pub fn set_transfer(
    modes: &mut [ModeConfig],
    mode: &str,
    transfer: TransferFunction,
) -> Result<String, ControlError> {
    let index = mode_index(modes, mode)?;
    if modes[index].transfer.is_none() {
        return Err(invalid(format!("mode {mode:?} has no transfer function")));
    }
    modes[index].transfer = Some(transfer);
    Ok(format!("transfer function of {mode:?} replaced"))
}

/// `set_mode_enabled`: switches the mode named `mode` on or off; returns the reply's message.
pub fn set_mode_enabled(
    modes: &mut [ModeConfig],
    mode: &str,
    enabled: bool,
) -> Result<String, ControlError> {
    let index = mode_index(modes, mode)?;
    modes[index].enabled = (!enabled).then_some(false);
    let state = if enabled { "on" } else { "off" };
    Ok(format!("mode {mode:?} switched {state}"))
}
