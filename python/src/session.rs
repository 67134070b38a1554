//! `voxhap._voxhap.NativeSession`: a live servo session with the simulated arm, driven from Python. The
//! Python class `voxhap.Session` (python/voxhap/session.py) wraps it with a context manager, state objects
//! and the trace as a DataFrame.
//!
//! Where it sits: the same library calls as `voxhap serve --device sim` without the HTTP server. The servo
//! loop runs on its own thread ([`voxhap_servo::Session`], real time, SCHED_FIFO where permitted); Python
//! reaches it only through [`SessionApi`]: the latest snapshot, the statistics, and control commands
//! (validated exactly as the HTTP API validates them: a hand target must be finite and inside the arm's
//! workspace). Every call that waits (starting, waiting for ticks, stopping) releases the GIL.

use pyo3::exceptions::{PyRuntimeError, PyTimeoutError, PyValueError};
use pyo3::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use voxhap_record::TraceFormat;
use voxhap_servo::api::{ControlCommand, ControlError, SessionApi};
use voxhap_servo::device::DeviceSpec;
use voxhap_servo::setup::{SceneSetup, BUILTIN_SCENE};
use voxhap_servo::{Session, SessionConfig, SessionShared};

/// How long one wait releases the GIL before it looks for Ctrl-C (a pending Python signal).
const SIGNAL_CHECK_INTERVAL: Duration = Duration::from_millis(50);
/// How often a wait looks at the servo's tick counter.
const POLL_INTERVAL: Duration = Duration::from_micros(500);

/// The Python exception for a refused control command: bad values are `ValueError`, the rest (not
/// possible now, servo gone) `RuntimeError`.
fn control_error(error: ControlError) -> PyErr {
    match error {
        ControlError::Invalid(_) | ControlError::NotFound(_) => {
            PyValueError::new_err(error.to_string())
        }
        ControlError::Conflict(_) | ControlError::Unavailable(_) => {
            PyRuntimeError::new_err(error.to_string())
        }
    }
}

/// Loads the scene: a scenario/scene TOML file (volumes relative to it) or, without one, the built-in
/// scene of `voxhap serve`; `overrides` (`key=value`, as `voxhap sim --set`) applied to its text first.
fn load_setup(scene: Option<&Path>, overrides: &[String]) -> PyResult<SceneSetup> {
    let (text, origin, base_dir) = match scene {
        Some(path) => (
            voxhap_io::read_text_file(path)
                .map_err(|e| PyValueError::new_err(format!("scene {}: {e}", path.display())))?,
            path.display().to_string(),
            path.parent().unwrap_or(Path::new("")).to_path_buf(),
        ),
        None => (
            BUILTIN_SCENE.to_owned(),
            "built-in scene sims/scenes/explore.toml".to_owned(),
            PathBuf::from("."),
        ),
    };
    let text = voxhap_servo::sim::overrides::apply_overrides(&text, overrides)
        .map_err(|e| PyValueError::new_err(format!("{origin}: {e}")))?;
    SceneSetup::parse(&text, &origin, &base_dir).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// A running session with the simulated arm (see the module header).
#[pyclass(module = "voxhap._voxhap")]
pub struct NativeSession {
    /// `None` once closed.
    session: Mutex<Option<Session>>,
    api: Arc<SessionShared>,
}

impl NativeSession {
    fn check_open(&self) -> PyResult<()> {
        let open = self.session.lock().map(|s| s.is_some()).unwrap_or(false);
        if open {
            Ok(())
        } else {
            Err(PyRuntimeError::new_err("the session is closed"))
        }
    }

    fn snapshot_json(&self) -> PyResult<Option<String>> {
        self.api
            .snapshot()
            .map(|snapshot| serde_json::to_string(&snapshot))
            .transpose()
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }
}

#[pymethods]
impl NativeSession {
    /// Starts the session: loads `scene` (None: the built-in scene) with `overrides`, starts the servo at
    /// `rate_hz` (default the scene's) and, with `trace_csv`, records every tick to that CSV file (which must
    /// not exist yet). With `external_force_timeout_s` the external force input is on, with that staleness
    /// timeout (`serve --external-force --external-force-timeout`).
    #[new]
    #[pyo3(signature = (scene = None, overrides = Vec::new(), rate_hz = None, trace_csv = None, external_force_timeout_s = None))]
    fn new(
        py: Python<'_>,
        scene: Option<PathBuf>,
        overrides: Vec<String>,
        rate_hz: Option<f64>,
        trace_csv: Option<PathBuf>,
        external_force_timeout_s: Option<f64>,
    ) -> PyResult<Self> {
        let setup = load_setup(scene.as_deref(), &overrides)?;
        let mut config = SessionConfig::new(DeviceSpec::Sim, setup);
        if let Some(rate_hz) = rate_hz {
            config.rate_hz = rate_hz;
        }
        if let Some(timeout_s) = external_force_timeout_s {
            let (min, max) = voxhap_servo::external_force::TIMEOUT_RANGE_S;
            if !(timeout_s.is_finite() && (min..=max).contains(&timeout_s)) {
                return Err(PyValueError::new_err(format!(
                    "external_force_timeout_s {timeout_s} is outside {min} ..= {max} s"
                )));
            }
            config.external_force_timeout = Some(Duration::from_secs_f64(timeout_s));
        }
        if let Some(path) = trace_csv {
            config.record_policy = voxhap_record::OutputPolicy {
                overwrite: false,
                inputs: scene.iter().cloned().collect(),
            };
            voxhap_record::check_output_path(&path, &config.record_policy)
                .map_err(|e| PyValueError::new_err(format!("trace {}: {e}", path.display())))?;
            config.record = Some((path, TraceFormat::Csv));
        }
        let session = py
            .detach(move || Session::start(config))
            .map_err(|e| match e {
                voxhap_servo::SessionError::Rate(_) | voxhap_servo::SessionError::Scene(_) => {
                    PyValueError::new_err(e.to_string())
                }
                other => PyRuntimeError::new_err(other.to_string()),
            })?;
        for notice in session.notices() {
            eprintln!("voxhap: notice: {notice}");
        }
        let api = session.api();
        Ok(NativeSession {
            session: Mutex::new(Some(session)),
            api,
        })
    }

    /// Pulls the simulated arm's virtual hand towards `position_m` ([x, y, z] in m), or back onto the scene's
    /// path with `None`. Refused (`ValueError`) when not finite or outside the arm's workspace.
    #[pyo3(signature = (position_m))]
    fn set_hand_target(&self, py: Python<'_>, position_m: Option<[f64; 3]>) -> PyResult<String> {
        self.check_open()?;
        let api = self.api.clone();
        py.detach(move || api.control(ControlCommand::SetHandTarget { position_m }))
            .map(|reply| reply.message)
            .map_err(control_error)
    }

    /// Sends an external force ([x, y, z] in N, scene frame), added to the rendered force before the safety
    /// pipeline for the staleness timeout. Refused (`ValueError`) when not finite or above 1000 N,
    /// `RuntimeError` when the session was started without the external force input.
    fn set_external_force(&self, py: Python<'_>, force_n: [f64; 3]) -> PyResult<String> {
        self.check_open()?;
        let api = self.api.clone();
        py.detach(move || api.control(ControlCommand::SetExternalForce { force_n }))
            .map(|reply| reply.message)
            .map_err(control_error)
    }

    /// Applies a control command given as the HTTP API's JSON (`{"command": "set_stiffness", "k": 400}`).
    fn control(&self, py: Python<'_>, command_json: &str) -> PyResult<String> {
        self.check_open()?;
        let command: ControlCommand = serde_json::from_str(command_json)
            .map_err(|e| PyValueError::new_err(format!("control command: {e}")))?;
        let api = self.api.clone();
        py.detach(move || api.control(command))
            .map(|reply| reply.message)
            .map_err(control_error)
    }

    /// The newest tick's state as JSON (the HTTP API's snapshot); `None` before the first tick.
    fn snapshot(&self) -> PyResult<Option<String>> {
        self.check_open()?;
        self.snapshot_json()
    }

    /// Waits (GIL released) until `ticks` more ticks have run, then returns that state as JSON. Raises
    /// `TimeoutError` after `timeout_s` and `RuntimeError` when the servo stopped.
    fn wait_ticks(&self, py: Python<'_>, ticks: u64, timeout_s: f64) -> PyResult<String> {
        self.check_open()?;
        if !(timeout_s.is_finite() && timeout_s > 0.0) {
            return Err(PyValueError::new_err(format!(
                "timeout_s {timeout_s} must be a finite number > 0"
            )));
        }
        let start_tick = self.api.snapshot().map_or(0, |s| s.tick);
        let target = start_tick.saturating_add(ticks);
        let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.min(1e6));
        loop {
            let api = self.api.clone();
            let session = &self.session;
            let reached = py.detach(move || {
                let until = (Instant::now() + SIGNAL_CHECK_INTERVAL).min(deadline);
                loop {
                    if api.snapshot().is_some_and(|s| s.tick >= target) {
                        return Some(true);
                    }
                    let running = session
                        .lock()
                        .map(|s| s.as_ref().is_some_and(Session::is_running))
                        .unwrap_or(false);
                    if !running {
                        return Some(false);
                    }
                    if Instant::now() >= until {
                        return None;
                    }
                    std::thread::sleep(POLL_INTERVAL);
                }
            });
            match reached {
                Some(true) => break,
                Some(false) => {
                    return Err(PyRuntimeError::new_err(
                        "the servo thread stopped while waiting for ticks",
                    ))
                }
                None if Instant::now() >= deadline => {
                    let now = self.api.snapshot().map_or(0, |s| s.tick);
                    return Err(PyTimeoutError::new_err(format!(
                        "waited {timeout_s} s for {ticks} ticks; {} ran",
                        now.saturating_sub(start_tick)
                    )));
                }
                None => py.check_signals()?,
            }
        }
        Ok(self.snapshot_json()?.unwrap_or_default())
    }

    /// The servo statistics so far as JSON (ticks, overruns, lateness, safety counters).
    fn stats(&self) -> PyResult<String> {
        serde_json::to_string(&self.api.stats()).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }

    /// The scene as configured now as JSON (k, damping, modes, volumes).
    fn scene(&self) -> PyResult<String> {
        serde_json::to_string(&self.api.scene()).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }

    /// True while the servo thread runs.
    fn running(&self) -> bool {
        self.session
            .lock()
            .map(|s| s.as_ref().is_some_and(Session::is_running))
            .unwrap_or(false)
    }

    /// The flag names, lowest bit first (bit n of `flags` is `flag_names()[n]`).
    #[staticmethod]
    fn flag_names() -> Vec<String> {
        voxhap_record::FLAG_DOCS
            .iter()
            .map(|doc| doc.name.to_string())
            .collect()
    }

    /// Stops the session (GIL released): the servo thread stops, zero force goes to the arm, the device is
    /// disabled and closed, the trace is finished. Returns the final statistics and the trace's summary as
    /// JSON; `None` when it was already closed.
    fn close(&self, py: Python<'_>) -> PyResult<Option<String>> {
        let session = match self.session.lock() {
            Ok(mut slot) => slot.take(),
            Err(poisoned) => poisoned.into_inner().take(),
        };
        let Some(session) = session else {
            return Ok(None);
        };
        let summary = py.detach(move || session.stop());
        let json = serde_json::json!({
            "stats": summary.stats,
            "trace_samples": summary.trace.as_ref().map(|t| t.sample_count),
            "recorder_error": summary.recorder_error,
        });
        Ok(Some(json.to_string()))
    }
}
