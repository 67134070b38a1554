//! `[[events]]` in a sim scenario: control commands at given times, spelt as the control API spells them
//! (`{"command": "set_stiffness", "k": 4000}` becomes `command = "set_stiffness"` and `k = 4000.0` beside
//! `t_s`), and checked as the control API checks them (crate::commands), so a scripted change mid-contact is
//! tested deterministically.
//!
//! Off the servo path: the events are read with the scenario, then [`plan`] applies them in order to the
//! scenario's coupling and modes and builds each resulting scene once, before the run; the runner swaps the
//! prepared scene in at the start of the event's tick, as `voxhap serve`'s servo thread does with a command.
//! The commands that change a scene are accepted: `set_stiffness` (to the scene file's stiffness range; the
//! simulated arm has no device cap in `sim`), `set_damping`, `set_transfer`, `set_mode_enabled`. The others
//! (`add_mode` and `remove_mode`, which would change a trace's mode columns, recording, hand targets, volumes,
//! `clear_fault`) are refused with a message naming the event.

use crate::commands::{self, ModeEdit};
use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use voxhap_api::{ControlCommand, ControlError};
use voxhap_core::haptics::modes::{ModeConfig, ModeError, RenderScene};
use voxhap_io::scene::STIFFNESS_RANGE_N_PER_M;

/// One `[[events]]` table: when, and what.
#[derive(Debug, Clone, PartialEq)]
pub struct SimEvent {
    /// Simulated time of the change (s): applied at the start of the first tick at or after it.
    pub t_s: f64,
    /// The command, as the control API spells it.
    pub command: ControlCommand,
}

impl<'de> Deserialize<'de> for SimEvent {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let mut table = toml::Table::deserialize(deserializer)?;
        let t_s = match table.remove("t_s") {
            Some(toml::Value::Float(t)) => t,
            Some(toml::Value::Integer(t)) => t as f64,
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "t_s: must be a number of seconds, got {other}"
                )))
            }
            None => return Err(D::Error::missing_field("t_s")),
        };
        if !table.contains_key("command") {
            return Err(D::Error::missing_field("command"));
        }
        let command = toml::Value::Table(table)
            .try_into::<ControlCommand>()
            .map_err(|err| D::Error::custom(err.message().trim_end()))?;
        Ok(SimEvent { t_s, command })
    }
}

impl Serialize for SimEvent {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::Error as _;
        // The command's fields beside `t_s`, as written (fields left out stay out).
        let mut fields = match serde_json::to_value(&self.command).map_err(S::Error::custom)? {
            serde_json::Value::Object(fields) => fields,
            _ => return Err(S::Error::custom("a control command is a table")),
        };
        fields.retain(|_, value| !value.is_null());
        fields.insert("t_s".to_owned(), serde_json::Value::from(self.t_s));
        fields.serialize(serializer)
    }
}

/// Why an event cannot be run: the event's index and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EventError {
    #[error("events[{index}].t_s: must be a finite number from 0 to duration_s = {duration_s} s, got {t_s}")]
    Time {
        index: usize,
        t_s: f64,
        duration_s: f64,
    },
    #[error("events[{index}].t_s: {t_s} s is before the previous event's {previous_s} s; list events in time order")]
    Order {
        index: usize,
        t_s: f64,
        previous_s: f64,
    },
    #[error("events[{index}]: {source}")]
    Command { index: usize, source: ControlError },
    #[error("events[{index}]: command {command:?} is not available in `voxhap sim` ({why})")]
    Unavailable {
        index: usize,
        command: &'static str,
        why: &'static str,
    },
    #[error("events[{index}]: damping must be at most a local model's {max} N s/m ([local_model]), got {damping}", max = super::local::MAX_LOCAL_DAMPING_N_S_PER_M)]
    LocalDamping { index: usize, damping: f64 },
    #[error("events[{index}]: the scene after it does not build: {source}")]
    Scene { index: usize, source: ModeError },
}

/// The coupling and modes after an event, and the scene built from them.
#[derive(Debug, Clone)]
pub struct PlannedEvent {
    /// The tick at whose start it applies.
    pub tick: u64,
    pub stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    /// The scene from this event on (its stiffness included).
    pub scene: RenderScene,
    /// What the control API would have replied (`stiffness set to 4000 N/m`).
    pub message: String,
}

/// Checks the events' times (finite, from 0 to `duration_s`, in order).
pub fn check_times(events: &[SimEvent], duration_s: f64) -> Result<(), EventError> {
    let mut previous_s = 0.0;
    for (index, event) in events.iter().enumerate() {
        let t_s = event.t_s;
        if !(t_s.is_finite() && t_s >= 0.0 && t_s <= duration_s) {
            return Err(EventError::Time {
                index,
                t_s,
                duration_s,
            });
        }
        if t_s < previous_s {
            return Err(EventError::Order {
                index,
                t_s,
                previous_s,
            });
        }
        previous_s = t_s;
    }
    Ok(())
}

/// Applies the events in order to the coupling (`stiffness_n_per_m`, `damping_n_s_per_m`) and `modes` over
/// `scene`'s volumes, checking each as the control API does, and builds the scene after each (off the servo
/// path). `rate_hz` places each on its tick. With `local_model` the coupling must also fit a local model
/// (super::local: at most 65535 N/m and 65.535 N s/m).
pub fn plan(
    events: &[SimEvent],
    scene: &RenderScene,
    modes: &[ModeConfig],
    mut stiffness_n_per_m: f64,
    mut damping_n_s_per_m: f64,
    rate_hz: f64,
    local_model: bool,
) -> Result<Vec<PlannedEvent>, EventError> {
    let mut modes = modes.to_vec();
    let (max_k, whose) = if local_model {
        (super::local::MAX_LOCAL_STIFFNESS_N_PER_M, "a local model's")
    } else {
        (STIFFNESS_RANGE_N_PER_M.1, "the scene file's")
    };
    let check_damping = |index, damping| {
        let damping = commands::check_damping(damping)
            .map_err(|source| EventError::Command { index, source })?;
        if local_model && damping > super::local::MAX_LOCAL_DAMPING_N_S_PER_M {
            return Err(EventError::LocalDamping { index, damping });
        }
        Ok(damping)
    };
    let mut planned = Vec::with_capacity(events.len());
    for (index, event) in events.iter().enumerate() {
        let command = |source| EventError::Command { index, source };
        let unavailable = |command, why| EventError::Unavailable {
            index,
            command,
            why,
        };
        let mut coupling = |k, damping| {
            let now = (stiffness_n_per_m, damping_n_s_per_m);
            let check_k = |k| commands::check_stiffness(k, max_k, whose).map_err(command);
            let (k, damping, message) =
                commands::set_coupling(k, damping, now, check_k, |damping, _| {
                    check_damping(index, damping)
                })?;
            stiffness_n_per_m = k;
            damping_n_s_per_m = damping;
            Ok::<_, EventError>(message)
        };
        let message = match &event.command {
            ControlCommand::SetStiffness { k } => coupling(Some(*k), None)?,
            ControlCommand::SetDamping { damping } => coupling(None, Some(*damping))?,
            ControlCommand::SetCoupling { k, damping } => coupling(Some(*k), Some(*damping))?,
            ControlCommand::SetTransfer { mode, transfer } => {
                let edit = ModeEdit::Transfer(transfer.clone());
                commands::edit_mode(&mut modes, mode, edit).map_err(command)?
            }
            ControlCommand::SetModeEnabled { mode, enabled } => {
                let edit = ModeEdit::Enabled(*enabled);
                commands::edit_mode(&mut modes, mode, edit).map_err(command)?
            }
            ControlCommand::AddMode { .. } => {
                return Err(unavailable("add_mode", "a trace has a fixed set of mode columns: give the mode with enabled = false and switch it on with set_mode_enabled"))
            }
            ControlCommand::RemoveMode { .. } => {
                return Err(unavailable("remove_mode", "a trace has a fixed set of mode columns: switch it off with set_mode_enabled"))
            }
            ControlCommand::LoadVolume { .. } => {
                return Err(unavailable("load_volume", "list the volumes in [[volumes]]"))
            }
            ControlCommand::StartRecording { .. } | ControlCommand::StopRecording => {
                return Err(unavailable("start_recording/stop_recording", "a sim records every tick to --out"))
            }
            ControlCommand::SetHandTarget { .. } => {
                return Err(unavailable("set_hand_target", "script the hand with [path]"))
            }
            ControlCommand::ClearFault => {
                return Err(unavailable("clear_fault", "the simulated arm of a sim has no faults"))
            }
            ControlCommand::SetExternalForce { .. } => {
                return Err(unavailable("set_external_force", "a sim has no external force input; it is voxhap serve --external-force's"))
            }
        };
        let scene = RenderScene::new(stiffness_n_per_m, scene.volumes().to_vec(), &modes)
            .map_err(|source| EventError::Scene { index, source })?;
        planned.push(PlannedEvent {
            tick: (event.t_s * rate_hz - 1e-9).ceil().max(0.0) as u64,
            stiffness_n_per_m,
            damping_n_s_per_m,
            scene,
            message,
        });
    }
    Ok(planned)
}
