//! The control-command interpreter: turns a client's [`ControlCommand`] (CLI, REST, WebSocket) into a
//! checked change of the session's scene setup and the [`ServoCommand`] that carries it to the servo thread
//! through the command ring, and waits until the servo thread has applied it (or withdraws it, so a command
//! the client was told failed is never applied later). Runs on the control side, never on the servo thread.

use super::commands::{self, ModeEdit};
use super::device::HandTargetInput;
use super::external_force::ExternalForceSender;
use super::recorder::{RecorderError, RecorderRequest};
use super::runner::{
    CommandEnvelope, ServoCommand, CLEAR_FAULT_NOTHING, CLEAR_FAULT_NO_DEVICE,
    CLEAR_FAULT_REQUESTED,
};
use super::setup::{load_volume_arg, ReplaceVolumeError, SceneBundle, SceneSetup};
use super::stats::ServoStats;
use glam::DVec3;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};
use voxhap_api::{ControlCommand, ControlError, ControlReply, SessionApi, Snapshot};
use voxhap_device::mapping::WorkspaceMapping;
use voxhap_record::foxglove_scene::SceneChange;
use voxhap_record::{create_trace_writer, TraceFormat, TraceMeta};

/// How long a control command waits for the servo thread to apply it.
pub const APPLY_TIMEOUT: Duration = Duration::from_secs(2);

/// The farthest a hand target may be from the origin (m), for an unbounded workspace.
pub const MAX_HAND_TARGET_M: f64 = 10.0;

/// The part of a session that any thread may share (`Arc`); implements [`SessionApi`].
pub struct SessionShared {
    pub(super) stats: Arc<ServoStats>,
    pub(super) snapshot: Mutex<triple_buffer::Output<Option<Snapshot>>>,
    pub(super) control: Mutex<Control>,
    pub(super) hand_target: Mutex<Option<DVec3>>,
    /// The external force input's control end (`None`: off); its own lock, never the servo thread's.
    pub(super) external_force: Mutex<Option<ExternalForceSender>>,
    pub(super) external_force_timeout: Option<Duration>,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) servo_running: Arc<AtomicBool>,
    pub(super) device_label: String,
    pub(super) simulated: bool,
    pub(super) max_stiffness_n_per_m: f64,
    /// The device's coupling caps at this rate: the largest damping the control API accepts at a stiffness.
    pub(super) coupling_caps: voxhap_device::safety::CouplingCaps,
    pub(super) rate_hz: f64,
    pub(super) period_ns: u64,
    pub(super) solver_budget_fraction: f64,
    pub(super) recorder_error: RecorderError,
}

pub(super) struct Control {
    pub(super) commands: rtrb::Producer<CommandEnvelope>,
    /// The id of the last command decided (applied by the servo thread or cancelled here).
    pub(super) claim: Arc<AtomicU64>,
    pub(super) retired: rtrb::Consumer<Box<SceneBundle>>,
    pub(super) sent: u64,
    pub(super) setup: SceneSetup,
    pub(super) generation: u64,
    pub(super) recorder: mpsc::Sender<RecorderRequest>,
    pub(super) recording: Option<PathBuf>,
    /// The recorder's failure count (`ServoStats::recorder_errors`) when `recording` started: a higher count
    /// means a write error ended it.
    pub(super) recorder_errors_at_start: u64,
    pub(super) hand: Option<HandTargetInput>,
    /// Device frame -> scene frame of the session (a hand target is given in the scene, moved in the device).
    pub(super) hand_mapping: WorkspaceMapping,
}

fn invalid(message: impl Into<String>) -> ControlError {
    ControlError::Invalid(message.into())
}

pub(super) fn trace_meta(setup: &SceneSetup, rate_hz: f64, device: &str) -> TraceMeta {
    let mode_names = setup
        .modes
        .iter()
        .map(|m| m.display_name().to_owned())
        .collect();
    let scenario = serde_json::json!({
        "session": setup.label,
        "device": device,
        "k_n_per_m": setup.stiffness_n_per_m,
        "damping_n_s_per_m": setup.damping_n_s_per_m,
        "modes": setup.modes,
    });
    let volume = setup
        .volumes
        .iter()
        .map(|v| v.source.clone())
        .collect::<Vec<_>>()
        .join(", ");
    TraceMeta::new(
        mode_names,
        rate_hz,
        scenario,
        volume,
        setup.solver_kind().name(),
    )
}

impl SessionShared {
    /// `set_external_force`: checks the force and hands it to the servo thread (crate::external_force).
    pub(super) fn set_external_force(
        &self,
        force_n: [f64; 3],
    ) -> Result<ControlReply, ControlError> {
        let mut slot = match self.external_force.lock() {
            Ok(slot) => slot,
            Err(poisoned) => poisoned.into_inner(),
        };
        let (Some(sender), Some(timeout)) = (slot.as_mut(), self.external_force_timeout) else {
            return Err(ControlError::Conflict(
                "the external force input is off; start serve with --external-force".to_owned(),
            ));
        };
        if !self.servo_running.load(Ordering::Acquire) {
            return Err(ControlError::Unavailable(
                "the servo loop is not running".to_owned(),
            ));
        }
        let force = sender.send(force_n).map_err(|e| invalid(e.to_string()))?;
        Ok(ControlReply {
            message: format!(
                "external force {:?} N for {} s",
                force.to_array(),
                timeout.as_secs_f64()
            ),
            scene_generation: 0,
        })
    }

    fn drain_retired(control: &mut Control) {
        while let Ok(old) = control.retired.pop() {
            drop(old);
        }
    }

    /// Pushes `command` and waits until the servo thread has applied it.
    fn send(&self, control: &mut Control, command: ServoCommand) -> Result<(), ControlError> {
        if !self.servo_running.load(Ordering::Acquire) {
            return Err(ControlError::Unavailable(
                "the servo loop is not running".to_owned(),
            ));
        }
        let id = control.sent + 1;
        if control
            .commands
            .push(CommandEnvelope { id, command })
            .is_err()
        {
            return Err(ControlError::Unavailable(
                "the servo command queue is full; try again".to_owned(),
            ));
        }
        control.sent = id;
        let started = Instant::now();
        loop {
            if control.claim.load(Ordering::Acquire) >= id {
                // Decided by the servo thread (this side cancels only below, and then returns).
                break;
            }
            if started.elapsed() > APPLY_TIMEOUT || !self.servo_running.load(Ordering::Acquire) {
                // Cancel: whoever moves the claim from id - 1 to id decides. If the servo thread got there
                // first the command was applied after all, and that is what the caller is told.
                if control
                    .claim
                    .compare_exchange(id - 1, id, Ordering::AcqRel, Ordering::Acquire)
                    .is_ok()
                {
                    return Err(ControlError::Unavailable(
                        "the servo loop did not take the command in time; it was withdrawn and will not be \
                         applied"
                            .to_owned(),
                    ));
                }
                break;
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        Self::drain_retired(control);
        Ok(())
    }

    /// Waits briefly (at most 100 ms) until the servo thread's snapshot shows scene `generation`. The servo
    /// thread takes a command at the start of a tick and publishes that tick's snapshot at its end, so without
    /// this a client reading the snapshot right after the reply could still see the old values.
    fn wait_for_snapshot(&self, generation: u64) {
        let deadline = Instant::now() + Duration::from_millis(100);
        while Instant::now() < deadline && self.servo_running.load(Ordering::Acquire) {
            if self
                .snapshot()
                .is_some_and(|s| s.scene_generation >= generation)
            {
                return;
            }
            std::thread::sleep(Duration::from_micros(100));
        }
    }

    /// Builds `setup` into a bundle, swaps it in, and keeps `setup` as the current one.
    fn swap(
        &self,
        control: &mut Control,
        setup: SceneSetup,
        message: String,
    ) -> Result<ControlReply, ControlError> {
        let generation = control.generation + 1;
        let bundle = setup
            .bundle(self.period_ns, self.solver_budget_fraction, generation)
            .map_err(|e| invalid(e.to_string()))?;
        // While recording, the recording redraws the volume: meshed here, before the swap, so the recorder
        // thread never stalls on it.
        let redraw = control.recording.as_ref().and_then(|_| {
            SceneChange::between(
                (&control.setup.volumes[..], &control.setup.modes[..]),
                (&setup.volumes[..], &setup.modes[..]),
                generation,
            )
        });
        self.send(control, ServoCommand::SwapScene(Box::new(bundle)))?;
        self.wait_for_snapshot(generation);
        if let Some(redraw) = redraw {
            // A recorder that stopped has nothing to draw it in.
            let _ = control
                .recorder
                .send(RecorderRequest::SceneChanged(Box::new(redraw)));
        }
        control.setup = setup;
        control.generation = generation;
        Ok(ControlReply {
            message,
            scene_generation: generation,
        })
    }

    /// `set_stiffness` (`k`), `set_damping` (`damping`) or `set_coupling` (both), checked against the device's
    /// stiffness and the passivity bound ([`commands::set_coupling`]).
    fn coupling(
        &self,
        control: &mut Control,
        k: Option<f64>,
        damping: Option<f64>,
    ) -> Result<ControlReply, ControlError> {
        let now = (
            control.setup.stiffness_n_per_m,
            control.setup.damping_n_s_per_m,
        );
        let (k, damping, message) = commands::set_coupling(
            k,
            damping,
            now,
            |k| commands::check_stiffness(k, self.max_stiffness_n_per_m, "the device's"),
            |damping, k| self.check_damping_at(damping, k),
        )?;
        let generation = control.generation + 1;
        self.send(
            control,
            ServoCommand::SetCoupling {
                stiffness_n_per_m: k,
                damping_n_s_per_m: damping,
                generation,
            },
        )?;
        self.wait_for_snapshot(generation);
        control.setup.stiffness_n_per_m = k;
        control.setup.damping_n_s_per_m = damping;
        control.generation = generation;
        Ok(ControlReply {
            message,
            scene_generation: generation,
        })
    }

    /// `damping` if it is valid and within the passivity bound at stiffness `k` (N/m).
    fn check_damping_at(&self, damping: f64, k: f64) -> Result<f64, ControlError> {
        let damping = commands::check_damping(damping)?;
        let cap = self.coupling_caps.max_damping_n_s_per_m(k);
        if damping > cap {
            let caps = &self.coupling_caps;
            return Err(invalid(format!(
                "damping must be at most {cap} N s/m with the stiffness in use ({k} N/m): the \
                 passivity bound b - k T/2 with the device's b = {} N s/m and T = {} s, got {damping}",
                caps.device_damping_n_s_per_m, caps.period_s
            )));
        }
        Ok(damping)
    }

    fn refuse_while_recording(control: &Control, what: &str) -> Result<(), ControlError> {
        match &control.recording {
            Some(path) => Err(ControlError::Conflict(format!(
                "cannot {what} while recording to {} (a trace has a fixed set of mode columns); stop recording first",
                path.display()
            ))),
            None => Ok(()),
        }
    }

    pub(super) fn apply(
        &self,
        control: &mut Control,
        command: ControlCommand,
    ) -> Result<ControlReply, ControlError> {
        Self::drain_retired(control);
        match command {
            ControlCommand::SetStiffness { k } => self.coupling(control, Some(k), None),
            ControlCommand::SetDamping { damping } => self.coupling(control, None, Some(damping)),
            ControlCommand::SetCoupling { k, damping } => {
                self.coupling(control, Some(k), Some(damping))
            }
            ControlCommand::SetTransfer { mode, transfer } => {
                let mut setup = control.setup.clone();
                let edit = ModeEdit::Transfer(transfer);
                let message = commands::edit_mode(&mut setup.modes, &mode, edit)?;
                self.swap(control, setup, message)
            }
            ControlCommand::SetModeEnabled { mode, enabled } => {
                let mut setup = control.setup.clone();
                let edit = ModeEdit::Enabled(enabled);
                let message = commands::edit_mode(&mut setup.modes, &mode, edit)?;
                self.swap(control, setup, message)
            }
            ControlCommand::AddMode { mode } => {
                Self::refuse_while_recording(control, "add a mode")?;
                let mut setup = control.setup.clone();
                let name = mode.display_name().to_owned();
                setup.modes.push(mode);
                self.swap(control, setup, format!("mode {name:?} added"))
            }
            ControlCommand::RemoveMode { name } => {
                Self::refuse_while_recording(control, "remove a mode")?;
                let mut setup = control.setup.clone();
                let index = commands::mode_index(&setup.modes, &name)?;
                setup.modes.remove(index);
                self.swap(control, setup, format!("mode {name:?} removed"))
            }
            ControlCommand::LoadVolume { path, name } => {
                let text = path.to_str().ok_or_else(|| {
                    invalid(format!("volume path {} is not UTF-8", path.display()))
                })?;
                // `builtin:NAME` is not a file; `load_volume_arg` checks the name.
                if !text.starts_with("builtin:") && !path.exists() {
                    return Err(ControlError::NotFound(format!(
                        "volume file {} does not exist",
                        path.display()
                    )));
                }
                let (volume, source) = load_volume_arg(text).map_err(|e| invalid(e.to_string()))?;
                let mut setup = control.setup.clone();
                setup
                    .replace_volume(name.as_deref(), volume, source)
                    .map_err(|error| match error {
                        ReplaceVolumeError::NoSuchVolume { .. } => {
                            ControlError::NotFound(error.to_string())
                        }
                        ReplaceVolumeError::NoVolume | ReplaceVolumeError::Modes(_) => {
                            invalid(error.to_string())
                        }
                    })?;
                self.swap(control, setup, format!("volume {} loaded", path.display()))
            }
            ControlCommand::StartRecording { path, format } => {
                // A recording that a write error ended (a full disk) is over: a new one may start at once.
                let failures = self.stats.recorder_errors.load(Ordering::Acquire);
                if let Some(current) = &control.recording {
                    if failures == control.recorder_errors_at_start {
                        return Err(ControlError::Conflict(format!(
                            "already recording to {}",
                            current.display()
                        )));
                    }
                }
                let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
                if let Some(parent) = parent {
                    if !parent.is_dir() {
                        return Err(ControlError::NotFound(format!(
                            "directory {} does not exist",
                            parent.display()
                        )));
                    }
                }
                let format = format.unwrap_or_else(|| TraceFormat::from_path(&path));
                let mut meta = trace_meta(&control.setup, self.rate_hz, &self.device_label);
                // Ticks count from the session's start: date the trace's t_s = 0 there.
                if let Some(snapshot) = self.snapshot() {
                    meta.start_utc_ns -= (snapshot.t_s * 1e9).round() as i64;
                }
                let writer = create_trace_writer(&path, format, &meta)
                    .map_err(|e| invalid(e.to_string()))?;
                let first_tick = self.snapshot().map_or(0, |s| s.tick + 1);
                control
                    .recorder
                    .send(RecorderRequest::Start { writer, first_tick })
                    .map_err(|_| {
                        ControlError::Unavailable("the recorder thread has stopped".to_owned())
                    })?;
                control.recording = Some(path.clone());
                control.recorder_errors_at_start = failures;
                Ok(ControlReply {
                    message: format!("recording to {} ({format})", path.display()),
                    scene_generation: 0,
                })
            }
            ControlCommand::StopRecording => {
                let Some(path) = control.recording.clone() else {
                    return Err(ControlError::Conflict("not recording".to_owned()));
                };
                let (reply_tx, reply_rx) = mpsc::channel();
                control
                    .recorder
                    .send(RecorderRequest::Stop { reply: reply_tx })
                    .map_err(|_| {
                        ControlError::Unavailable("the recorder thread has stopped".to_owned())
                    })?;
                control.recording = None;
                match reply_rx.recv_timeout(Duration::from_secs(10)) {
                    Ok(Ok(Some(summary))) => Ok(ControlReply {
                        message: format!(
                            "recording stopped: {} samples in {}",
                            summary.sample_count,
                            summary.trace_path.display()
                        ),
                        scene_generation: 0,
                    }),
                    Ok(Ok(None)) => Err(ControlError::Conflict(format!(
                        "the recording to {} had already stopped: {}",
                        path.display(),
                        self.recorder_error
                            .lock()
                            .ok()
                            .and_then(|e| e.clone())
                            .unwrap_or_default()
                    ))),
                    Ok(Err(error)) => Err(ControlError::Unavailable(format!(
                        "finishing {}: {error}",
                        path.display()
                    ))),
                    Err(_) => Err(ControlError::Unavailable(
                        "the recorder did not answer in time".to_owned(),
                    )),
                }
            }
            ControlCommand::ClearFault => {
                self.send(control, ServoCommand::ClearFault)?;
                let message = match self.stats.clear_fault_outcome.load(Ordering::Acquire) {
                    CLEAR_FAULT_REQUESTED => {
                        "ClearFault sent; the device is enabled again once the link is healthy, and forces ramp in"
                    }
                    CLEAR_FAULT_NOTHING => "no fault to clear",
                    CLEAR_FAULT_NO_DEVICE => "no device connected",
                    _ => "clear_fault applied",
                };
                Ok(ControlReply {
                    message: message.to_owned(),
                    scene_generation: 0,
                })
            }
            // Taken before the control lock (SessionApi::control); here for other callers of `apply`.
            ControlCommand::SetExternalForce { force_n } => self.set_external_force(force_n),
            ControlCommand::SetHandTarget { position_m } => {
                let Some(hand) = control.hand.as_mut() else {
                    return Err(ControlError::Conflict(format!(
                        "the device {} is not the simulated arm; only its hand can be moved",
                        self.device_label
                    )));
                };
                // `position_m` is in the scene frame; the hand moves in the device frame.
                let (scene_target, device_target) = match position_m {
                    Some([x, y, z]) => {
                        let scene = DVec3::new(x, y, z);
                        if !scene.is_finite() {
                            return Err(invalid("position_m must be three finite numbers"));
                        }
                        let device = control.hand_mapping.to_device_position_m(scene);
                        // Inside the arm's workspace, and (for an unbounded one) within 10 m: a
                        // far target (1e308) would overflow the hand spring into NaN.
                        let workspace = &control.setup.arm.arm.workspace;
                        if !device.is_finite()
                            || !workspace.contains_m(device, 0.0)
                            || device.length() > MAX_HAND_TARGET_M
                        {
                            let frame = if control.hand_mapping.is_identity() {
                                String::new()
                            } else {
                                format!(
                                    " (scene position; {:?} m in the device frame under the workspace mapping)",
                                    device.to_array()
                                )
                            };
                            return Err(invalid(format!(
                                "position_m {:?} m{frame} is outside the simulated arm's workspace ({workspace:?}, and at most {MAX_HAND_TARGET_M} m from the device origin)",
                                scene.to_array()
                            )));
                        }
                        (Some(scene), Some(device))
                    }
                    None => (None, None),
                };
                let target = scene_target;
                hand.write(device_target);
                if let Ok(mut slot) = self.hand_target.lock() {
                    *slot = scene_target;
                }
                Ok(ControlReply {
                    message: match target {
                        Some(t) => format!("hand target set to {:?} m", t.to_array()),
                        None => "hand follows its path again".to_owned(),
                    },
                    scene_generation: 0,
                })
            }
        }
    }
}
