//! The harness of the spec-device tests (tests/device_spec/): it runs the real host (`voxhap serve --device
//! serial:PTY`) against a [`SpecDevice`](crate::util::spec_device::SpecDevice) written from protocol/SPEC.md alone,
//! waits for what a test checks, and asserts the host behaviour that protocol/SPEC.md section 7.1 ("Host behaviour
//! a firmware can rely on") promises, on what the device received.
//!
//! The tests take turns (one `serve` at a time, [`take_turn`]) so that timing on a loaded 2-core machine stays
//! reasonable; every bound is count-based and generous.
//!
//! Nothing waits a fixed time and hopes. A loaded machine makes the host late: it enables the device only once its
//! servo loop ran on time for 50 ticks, drops the link when States come late, and starts engagement over after a
//! late tick, so the moment force flows can come seconds later than on a quiet machine. So a test that needs force
//! before its event (a fault, a reset, silence, a stop) fires the event on what the device sees
//! ([`Trigger::ForceAbove`]: an applied force above 1 N), the device thread itself signals `serve` where the
//! event is a signal (`call_at`), and `serve` runs until what the test checks has happened (then SIGTERM), up to
//! [`PATIENCE`]. Only the `--duration` test has to guess a length, and it guesses long.
//!
//! Scenes: most tests use a small scene file (a ball of radius 3 cm felt as a surface with k = 500 N/m, nothing
//! else), so that the handle is in free space (zero rendered force) at x = 4.5 cm and 1 cm inside the wall at
//! x = 2 cm, and the force the host renders there is known (about 5 N before any cap).

use crate::util::serve_headless;
use crate::util::spec_device::{
    Callback, ForceRecord, HandleFn, HandleTime, HostMessage, MessageRecord, SpecDevice,
    SpecDeviceConfig, SpecDeviceHandle, Trigger, TriggerRecord,
};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ExitStatus, Stdio};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The host's slew limit (SPEC section 7.1), N per ms, and a margin for f32 rounding.
pub(crate) const SLEW_LIMIT_N_PER_MS: f32 = 0.5;
pub(crate) const SLEW_MARGIN_N_PER_MS: f32 = 0.01;

/// The longest a test waits for what it needs (force flowing, an event and what follows it, serve's stop) before
/// it fails. Generous on purpose: on a saturated 2-core machine the pseudo-terminal itself can hold bytes back for
/// seconds, at worst minutes (a pty's buffer work runs on a kernel worker thread, and poll and read on the pty wait
/// for it; with two busy loops running, the kernel logged "workqueue lockup ... stuck for" 30 to 120 s with that
/// work pending), so the host may time out, drop the link and start over many times before force flows. A
/// condition that is met ends the wait at once, so a quiet machine never comes near it.
pub(crate) const PATIENCE: Duration = Duration::from_secs(120);

/// Force is flowing: the device applied a SetForce above this (N) while Enabled. The checks before an event ask for
/// more than 0.5 N in the last SetForce before it; an event on this trigger comes in the device's control cycle
/// right after that SetForce, so they hold by construction and stay as a record of it.
pub(crate) const FLOWING: Trigger = Trigger::ForceAbove(1.0);

/// One `serve` at a time.
static SERIAL: Mutex<()> = Mutex::new(());

pub(crate) fn take_turn() -> MutexGuard<'static, ()> {
    SERIAL
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Where the free-space handle rests (outside the ball) and where it is 1 cm inside the wall.
pub(crate) const FREE_X_M: f32 = 0.045;
pub(crate) const INSIDE_X_M: f32 = 0.02;
pub(crate) const BALL_RADIUS_M: f32 = 0.03;

/// A scene with one ball (radius 3 cm) felt as a surface at k = 500 N/m, with damping `damping_n_s_per_m`.
pub(crate) fn ball_scene(dir: &Path, damping_n_s_per_m: f64) -> PathBuf {
    let path = dir.join("ball.toml");
    let text = format!(
        "name = \"ball\"\nk_n_per_m = 500.0\ndamping_n_s_per_m = {damping_n_s_per_m:?}\nstart_m = [0.045, 0.0, 0.0]\n\
         [[volumes]]\nname = \"ball\"\nbuiltin = \"sphere\"\n\
         [[modes]]\nkind = \"surface\"\nvolume = \"ball\"\ntransfer = [[0.45, 0.0], [0.5, 20.0]]\n"
    );
    std::fs::write(&path, text).unwrap();
    path
}

/// A handle at rest in free space.
pub(crate) fn free_space() -> HandleFn {
    Arc::new(|_| [FREE_X_M, 0.0, 0.0])
}

/// A handle in free space until `after_enable_s` after the first Enable, then moving into the ball over 0.2 s
/// (ending 1 cm inside the wall) and held there.
pub(crate) fn into_the_wall(after_enable_s: f64) -> HandleFn {
    Arc::new(move |t: HandleTime| {
        let s = t
            .since_first_enable_s
            .map_or(0.0, |e| ((e - after_enable_s) / 0.2).clamp(0.0, 1.0)) as f32;
        [FREE_X_M + (INSIDE_X_M - FREE_X_M) * s, 0.0, 0.0]
    })
}

/// A hand that presses into the ball and backs out, over and over: in free space for 0.15 s, in over 0.1 s (ending
/// 1 cm inside the wall), held there 0.35 s, out over 0.1 s, and again. The host engages only while the force it
/// renders is small (SPEC section 7.1, step 5), and a loaded machine can make it start over at any moment (a late
/// servo tick, a dropped link, a new Enable): a hand held in the wall would then never feel force again, while this
/// one gives the host a moment in free space every 0.7 s (short, because on a loaded machine the link may stay up
/// for well under a second at a time). Tests stop it (`handle_hold`) once force flows, so that what follows their
/// event happens with the handle in the wall, as on a quiet machine. [`tapping_until`] presses in to `end_x_m`
/// instead.
pub(crate) fn tapping_to(end_x_m: f32) -> HandleFn {
    Arc::new(move |t: HandleTime| {
        let phase = t.since_spawn_s % 0.7;
        let s = if phase < 0.15 {
            0.0
        } else if phase < 0.25 {
            (phase - 0.15) / 0.1
        } else if phase < 0.6 {
            1.0
        } else {
            1.0 - (phase - 0.6) / 0.1
        } as f32;
        [FREE_X_M + (end_x_m - FREE_X_M) * s, 0.0, 0.0]
    })
}

/// A device config whose handle taps (ending at `end_x_m`) until `trigger`, then stays where it is.
pub(crate) fn tapping_until(end_x_m: f32, trigger: Trigger) -> SpecDeviceConfig {
    SpecDeviceConfig {
        handle: tapping_to(end_x_m),
        handle_hold: Some(trigger),
        ..SpecDeviceConfig::default()
    }
}

/// A handle in free space until `after_spawn_s` after the device started (whether or not it was ever enabled),
/// then moving into the ball as [`into_the_wall`] does.
pub(crate) fn into_the_wall_after_spawn(after_spawn_s: f64) -> HandleFn {
    Arc::new(move |t: HandleTime| {
        let s = ((t.since_spawn_s - after_spawn_s) / 0.2).clamp(0.0, 1.0) as f32;
        [FREE_X_M + (INSIDE_X_M - FREE_X_M) * s, 0.0, 0.0]
    })
}

/// A `serve` process with its output collected in the background.
pub(crate) struct Serve {
    child: Child,
    output: Arc<Mutex<String>>,
    readers: Vec<std::thread::JoinHandle<()>>,
    /// Where a device-thread action ([`signaller`]) finds the pid; cleared before this process is killed.
    pid_cell: Option<Arc<AtomicI32>>,
}

impl Serve {
    pub(crate) fn start(
        device: &SpecDeviceHandle,
        scene: Option<&Path>,
        duration_s: Option<f64>,
    ) -> Serve {
        Serve::start_on(device.path(), scene, duration_s, &[])
    }

    /// `serve --device serial:PATH` with `extra` flags, on any port (a [`SpecDevice`]'s or a silent pty).
    pub(crate) fn start_on(
        path: &str,
        scene: Option<&Path>,
        duration_s: Option<f64>,
        extra: &[&str],
    ) -> Serve {
        let mut command = serve_headless(&format!("serial:{path}"));
        command.args(extra);
        if let Some(scene) = scene {
            command.arg("--scene").arg(scene);
        }
        if let Some(duration_s) = duration_s {
            command.arg("--duration").arg(duration_s.to_string());
        }
        Serve::spawn(command)
    }

    /// Runs `command` (a `voxhap serve` built by the caller), its output collected in the background.
    pub(crate) fn spawn(mut command: std::process::Command) -> Serve {
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start voxhap serve");
        let output = Arc::new(Mutex::new(String::new()));
        let mut readers = Vec::new();
        let stdout: Box<dyn Read + Send> = Box::new(child.stdout.take().unwrap());
        let stderr: Box<dyn Read + Send> = Box::new(child.stderr.take().unwrap());
        for mut stream in [stdout, stderr] {
            let output = Arc::clone(&output);
            readers.push(std::thread::spawn(move || {
                let mut text = String::new();
                let _ = stream.read_to_string(&mut text);
                output.lock().unwrap().push_str(&text);
            }));
        }
        Serve {
            child,
            output,
            readers,
            pid_cell: None,
        }
    }

    /// Puts the pid where a [`signaller`] looks for it.
    pub(crate) fn share_pid(&mut self, cell: &Arc<AtomicI32>) {
        cell.store(self.child.id() as i32, Ordering::Release);
        self.pid_cell = Some(Arc::clone(cell));
    }

    /// Kills the process, first taking its pid from any [`signaller`] (so that none can signal a reused pid).
    pub(crate) fn kill(&mut self) {
        if let Some(cell) = &self.pid_cell {
            cell.store(0, Ordering::Release);
        }
        let _ = self.child.kill();
    }

    /// Sends `signal` to the process.
    pub(crate) fn signal(&self, signal: libc::c_int) {
        // SAFETY: plain kill(2) on our own child's pid.
        let sent = unsafe { libc::kill(self.child.id() as libc::pid_t, signal) };
        assert_eq!(sent, 0, "kill: {}", std::io::Error::last_os_error());
    }

    /// Polls until `done` holds for the device. Panics, naming `what` it waited for, with the device's forces and
    /// everything serve said, if serve exits first or [`PATIENCE`] runs out (then serve gets SIGTERM first, so
    /// that its statistics, lateness and device times included, show what held it up).
    pub(crate) fn wait_for(
        &mut self,
        device: &SpecDeviceHandle,
        what: &str,
        done: impl Fn(&SpecDeviceHandle) -> bool,
    ) {
        let start = Instant::now();
        loop {
            if done(device) {
                return;
            }
            let problem = if let Some(status) = self.child.try_wait().unwrap() {
                format!("serve exited ({status})")
            } else if start.elapsed() > PATIENCE {
                self.signal(libc::SIGTERM);
                let stopping = Instant::now();
                while self.child.try_wait().unwrap().is_none()
                    && stopping.elapsed() < Duration::from_secs(20)
                {
                    std::thread::sleep(Duration::from_millis(20));
                }
                self.kill();
                let _ = self.child.wait();
                format!("{PATIENCE:?} passed")
            } else {
                std::thread::sleep(Duration::from_millis(5));
                continue;
            };
            let output = self.collect();
            panic!(
                "{problem} before {what}: {}; serve said:\n{output}",
                summary(&device.forces())
            );
        }
    }

    /// Waits for the process to exit (killing it after `limit`), and returns its status and all its output.
    pub(crate) fn finish(mut self, limit: Duration) -> (ExitStatus, String) {
        let start = Instant::now();
        let status = loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                break status;
            }
            if start.elapsed() > limit {
                self.kill();
                let status = self.child.wait().unwrap();
                let output = self.collect();
                panic!("serve did not stop within {limit:?} ({status}); it said:\n{output}");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        (status, self.collect())
    }

    pub(crate) fn collect(&mut self) -> String {
        for reader in self.readers.drain(..) {
            let _ = reader.join();
        }
        self.output.lock().unwrap().clone()
    }
}

impl Drop for Serve {
    fn drop(&mut self) {
        self.kill();
        let _ = self.child.wait();
    }
}

/// Runs `serve` for `duration_s` against a device with `config` on the ball scene; returns the device (stopped)
/// and serve's status and output. Only for what needs `--duration` itself; the other tests use [`run_until`].
pub(crate) fn run(
    config: SpecDeviceConfig,
    damping_n_s_per_m: f64,
    duration_s: f64,
) -> (SpecDeviceHandle, ExitStatus, String) {
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), damping_n_s_per_m);
    let mut device = SpecDevice::spawn(config);
    let serve = Serve::start(&device, Some(&scene), Some(duration_s));
    let (status, output) = serve.finish(Duration::from_secs_f64(duration_s) + PATIENCE);
    // Let the last frames in flight arrive before the logs are read.
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    (device, status, output)
}

/// Runs `serve` against a device with `config` on the ball scene until `done` holds for the device (see
/// [`Serve::wait_for`]), then stops it with SIGTERM; returns the device (stopped) and serve's status and output.
pub(crate) fn run_until(
    config: SpecDeviceConfig,
    damping_n_s_per_m: f64,
    what: &str,
    done: impl Fn(&SpecDeviceHandle) -> bool,
) -> (SpecDeviceHandle, ExitStatus, String) {
    run_on_scene_until(config, damping_n_s_per_m, "", what, done)
}

/// [`run_until`] on the ball scene with `scene_tail` appended to its file (a `[device]` table, say).
pub(crate) fn run_on_scene_until(
    config: SpecDeviceConfig,
    damping_n_s_per_m: f64,
    scene_tail: &str,
    what: &str,
    done: impl Fn(&SpecDeviceHandle) -> bool,
) -> (SpecDeviceHandle, ExitStatus, String) {
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), damping_n_s_per_m);
    if !scene_tail.is_empty() {
        let text = std::fs::read_to_string(&scene).unwrap();
        std::fs::write(&scene, format!("{text}{scene_tail}")).unwrap();
    }
    let mut device = SpecDevice::spawn(config);
    let mut serve = Serve::start(&device, Some(&scene), None);
    serve.wait_for(&device, what, done);
    serve.signal(libc::SIGTERM);
    let (status, output) = serve.finish(PATIENCE);
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    (device, status, output)
}

/// [`run_until`], asserting that serve exited successfully; returns the (stopped) device.
pub(crate) fn run_until_ok(
    config: SpecDeviceConfig,
    damping_n_s_per_m: f64,
    what: &str,
    done: impl Fn(&SpecDeviceHandle) -> bool,
) -> SpecDeviceHandle {
    let (device, status, output) = run_until(config, damping_n_s_per_m, what, done);
    assert!(status.success(), "serve failed: {output}");
    device
}

/// `trigger` has fired and the device has received `forces` SetForce frames since (the host's ticks after it).
pub(crate) fn forces_after_trigger(
    trigger: Trigger,
    forces: usize,
) -> impl Fn(&SpecDeviceHandle) -> bool {
    move |device| {
        device
            .fired(trigger)
            .is_some_and(|fired| device.force_count_after_index(fired.index) >= forces)
    }
}

/// The first Enable received after the event with this `index`.
pub(crate) fn enable_after(device: &SpecDeviceHandle, index: u64) -> Option<MessageRecord> {
    device
        .messages()
        .into_iter()
        .find(|m| m.index > index && matches!(m.message, HostMessage::Enable { .. }))
}

/// Whether the host has enabled the device again after the event with this `index` and sent at least `forces`
/// SetForce after that Enable.
pub(crate) fn enabled_again_after(device: &SpecDeviceHandle, index: u64, forces: usize) -> bool {
    enable_after(device, index)
        .is_some_and(|enable| device.force_count_after_index(enable.index) >= forces)
}

/// A `run_until` condition: `trigger` fired, then a new Enable, then `forces` SetForce after it.
pub(crate) fn enabled_again_after_trigger(
    trigger: Trigger,
    forces: usize,
) -> impl Fn(&SpecDeviceHandle) -> bool {
    move |device| {
        device
            .fired(trigger)
            .is_some_and(|fired| enabled_again_after(device, fired.index, forces))
    }
}

/// An action for `call_at` that sends `signal` to the serve whose pid is in `pid` ([`Serve::share_pid`]; a
/// trigger that needs force cannot fire before serve runs).
pub(crate) fn signaller(pid: &Arc<AtomicI32>, signal: libc::c_int) -> Callback {
    let pid = Arc::clone(pid);
    Arc::new(move || {
        let pid = pid.load(Ordering::Acquire);
        if pid > 0 {
            // SAFETY: plain kill(2) on our own child's pid, which the cell holds only while the child runs or
            // has exited because of this very signal (Serve clears it before killing the child itself).
            unsafe { libc::kill(pid, signal) };
        }
    })
}

pub(crate) fn summary(forces: &[ForceRecord]) -> String {
    let nonzero = forces.iter().filter(|f| !f.is_zero()).count();
    let max = forces
        .iter()
        .map(ForceRecord::magnitude_n)
        .fold(0.0f32, f32::max);
    format!("{} SetForce, {nonzero} non-zero, max {max} N", forces.len())
}

/// The invariants every run must keep (SPEC section 7.1): finite, never above `max_force_n`, zero while the device
/// is not Enabled. When the device drops out by itself (its watchdog, a fault) the SetForce already on its way
/// cannot know: at most one non-zero SetForce may follow, in lockstep ("zero within one period").
pub(crate) fn assert_force_invariants(device: &SpecDeviceHandle, max_force_n: f32) {
    assert_finite_and_bounded(device, max_force_n);
    let forces = device.forces();
    let run = longest_nonzero_run_while_not_enabled(&forces);
    assert!(
        run <= 1,
        "{run} non-zero SetForce in a row while the device was not Enabled (first: {:?}); {}",
        nonzero_while_not_enabled(&forces).first(),
        summary(&forces)
    );
}

/// [`assert_force_invariants`] for a device that reset (`reset`, the trigger's event) while force flowed: finite
/// and never above `max_force_n` throughout. The host cannot know at once that the device reset: the forces in
/// flight, and at most 3 periods on the last State (SPEC section 7.1), may still be non-zero; none once 40 ms
/// have passed. Before the reset, as everywhere, at most the one SetForce already in flight to a device that is
/// not enabled.
pub(crate) fn assert_force_invariants_across_a_reset(
    device: &SpecDeviceHandle,
    reset: &TriggerRecord,
    max_force_n: f32,
) {
    let forces = device.forces();
    let reset_at = reset.at;
    assert_finite_and_bounded(device, max_force_n);
    let (before, after): (Vec<_>, Vec<_>) = nonzero_while_not_enabled(&forces)
        .into_iter()
        .partition(|f| f.index < reset.index);
    let late = after
        .iter()
        .filter(|f| f.at > reset_at + Duration::from_millis(40))
        .count();
    assert!(
        after.len() <= 5 && late == 0,
        "{} non-zero SetForce to the reset device, {late} of them more than 40 ms after; {}",
        after.len(),
        summary(&forces)
    );
    // Before the reset the device can only have dropped out by itself (its watchdog, when a loaded machine made
    // the host late): then at most the one SetForce already in flight, as everywhere (assert_force_invariants).
    let before_reset: Vec<_> = forces
        .iter()
        .filter(|f| f.index < reset.index)
        .copied()
        .collect();
    let run = longest_nonzero_run_while_not_enabled(&before_reset);
    assert!(
        run <= 1,
        "{run} non-zero SetForce in a row to the device before it reset (first: {:?}); {}",
        before.first(),
        summary(&forces)
    );
}

pub(crate) fn assert_finite_and_bounded(device: &SpecDeviceHandle, max_force_n: f32) {
    assert_eq!(
        device.non_finite_forces(),
        0,
        "non-finite SetForce received"
    );
    assert!(
        device.max_force_n() <= max_force_n * (1.0 + 1e-6),
        "force above max_force_n {max_force_n}: {}",
        summary(&device.forces())
    );
}

pub(crate) fn nonzero_while_not_enabled(forces: &[ForceRecord]) -> Vec<ForceRecord> {
    forces
        .iter()
        .filter(|f| !f.enabled && !f.is_zero())
        .copied()
        .collect()
}

pub(crate) fn assert_slew_limited(device: &SpecDeviceHandle) {
    let slew = device.max_slew_n_per_ms();
    assert!(
        slew <= SLEW_LIMIT_N_PER_MS + SLEW_MARGIN_N_PER_MS,
        "|force| rose by {slew} N in one tick (limit {SLEW_LIMIT_N_PER_MS} N/ms); {}",
        summary(&device.forces())
    );
}

/// The longest run of consecutive non-zero SetForce frames received while the device was not Enabled.
pub(crate) fn longest_nonzero_run_while_not_enabled(forces: &[ForceRecord]) -> usize {
    let mut longest = 0;
    let mut run = 0;
    for f in forces {
        run = if !f.enabled && !f.is_zero() {
            run + 1
        } else {
            0
        };
        longest = longest.max(run);
    }
    longest
}
