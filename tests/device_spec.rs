//! The real host (`voxhap serve --device serial:PTY`) against a device written from protocol/SPEC.md alone
//! (tests/util/spec_device.rs), checked from the device's side: every assertion is on what the device received.
//!
//! Each test runs `serve` against a [`SpecDevice`] that may misbehave (refuse Enable, fault, go silent, glitch,
//! corrupt its replies) and asserts the host behaviour that protocol/SPEC.md section 7.1 ("Host behaviour a
//! firmware can rely on") promises. The tests take turns (one `serve` at a time) so that timing on a loaded 2-core
//! machine stays reasonable; every bound is count-based and generous.
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

use crate::util::spec_device::{
    fault, reject, types, Callback, ForceRecord, HandleFn, HandleTime, HostMessage, MessageRecord,
    SpecDevice, SpecDeviceConfig, SpecDeviceHandle, Trigger, TriggerRecord,
};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The host's slew limit (SPEC section 7.1), N per ms, and a margin for f32 rounding.
const SLEW_LIMIT_N_PER_MS: f32 = 0.5;
const SLEW_MARGIN_N_PER_MS: f32 = 0.01;

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
const FREE_X_M: f32 = 0.045;
pub(crate) const INSIDE_X_M: f32 = 0.02;
const BALL_RADIUS_M: f32 = 0.03;

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
fn free_space() -> HandleFn {
    Arc::new(|_| [FREE_X_M, 0.0, 0.0])
}

/// A handle in free space until `after_enable_s` after the first Enable, then moving into the ball over 0.2 s
/// (ending 1 cm inside the wall) and held there.
fn into_the_wall(after_enable_s: f64) -> HandleFn {
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
fn tapping_to(end_x_m: f32) -> HandleFn {
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
fn into_the_wall_after_spawn(after_spawn_s: f64) -> HandleFn {
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
    fn start(device: &SpecDeviceHandle, scene: Option<&Path>, duration_s: Option<f64>) -> Serve {
        Serve::start_on(device.path(), scene, duration_s, &[])
    }

    /// `serve --device serial:PATH` with `extra` flags, on any port (a [`SpecDevice`]'s or a silent pty).
    pub(crate) fn start_on(
        path: &str,
        scene: Option<&Path>,
        duration_s: Option<f64>,
        extra: &[&str],
    ) -> Serve {
        let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
        command
            .args([
                "serve",
                "--no-http",
                "--no-foxglove",
                "--rt",
                "off",
                "--device",
            ])
            .arg(format!("serial:{path}"))
            .args(extra);
        if let Some(scene) = scene {
            command.arg("--scene").arg(scene);
        }
        if let Some(duration_s) = duration_s {
            command.arg("--duration").arg(duration_s.to_string());
        }
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
    fn share_pid(&mut self, cell: &Arc<AtomicI32>) {
        cell.store(self.child.id() as i32, Ordering::Release);
        self.pid_cell = Some(Arc::clone(cell));
    }

    /// Kills the process, first taking its pid from any [`signaller`] (so that none can signal a reused pid).
    fn kill(&mut self) {
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

    fn collect(&mut self) -> String {
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
fn run(
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
fn run_on_scene_until(
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
fn run_until_ok(
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
fn forces_after_trigger(trigger: Trigger, forces: usize) -> impl Fn(&SpecDeviceHandle) -> bool {
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
fn enabled_again_after(device: &SpecDeviceHandle, index: u64, forces: usize) -> bool {
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
fn signaller(pid: &Arc<AtomicI32>, signal: libc::c_int) -> Callback {
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

fn assert_finite_and_bounded(device: &SpecDeviceHandle, max_force_n: f32) {
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

fn nonzero_while_not_enabled(forces: &[ForceRecord]) -> Vec<ForceRecord> {
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

// ---------------------------------------------------------------------------------------------------------------
// The double's own codec against the vectors (it must agree with the SPEC before it can judge the host).

fn vector_files() -> Vec<(String, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("protocol/vectors");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hex"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path).unwrap();
            let line = text
                .lines()
                .find_map(|l| l.strip_prefix("serial: "))
                .unwrap_or_else(|| panic!("{} has no serial line", path.display()));
            let bytes = line
                .split_whitespace()
                .map(|h| u8::from_str_radix(h, 16).unwrap())
                .collect();
            (
                path.file_name().unwrap().to_string_lossy().into_owned(),
                bytes,
            )
        })
        .collect()
}

#[test]
fn spec_device_codec_matches_the_vectors() {
    use crate::util::spec_device::{crc16, decode_frame, encode_frame, payload_len};
    assert_eq!(crc16(b"123456789"), 0x29B1, "SPEC section 4.2 check value");
    assert_eq!(crc16(&[]), 0xFFFF);
    let files = vector_files();
    assert!(files.len() >= 12, "only {} vectors", files.len());
    for (name, wire) in files {
        let (last, stuffed) = wire.split_last().unwrap();
        assert_eq!(*last, 0, "{name}: the delimiter ends the frame");
        assert!(!stuffed.contains(&0), "{name}: no 0x00 inside a frame");
        let (message_type, payload) =
            decode_frame(stuffed).unwrap_or_else(|e| panic!("{name}: {e:?}"));
        let expected_len = payload_len(message_type).unwrap();
        assert_eq!(payload.len(), expected_len, "{name}");
        // SPEC section 4.2 "Sizes": payload + 3 unstuffed, + 1 stuffed, + 1 with the delimiter.
        assert_eq!(wire.len(), expected_len + 5, "{name}: wire length");
        assert_eq!(
            encode_frame(message_type, &payload),
            wire,
            "{name}: re-encoding"
        );
    }
    // The SPEC's own examples.
    assert_eq!(
        encode_frame(types::HELLO, &[1, 0]),
        [0x03, 0x01, 0x01, 0x03, 0x9d, 0xc8, 0x00]
    );
    assert_eq!(encode_frame(types::SET_FORCE, &[0; 18]).len(), 23);
    assert_eq!(encode_frame(types::STATE, &[0; 46]).len(), 51);
    assert_eq!(encode_frame(types::DEVICE_INFO, &[0; 62]).len(), 67);
}

/// A host written with the reference crate, to check the double's state machine (SPEC section 6) before the
/// double judges voxhap's host: two independent readings of the SPEC must agree.
struct ReferenceHost {
    port: std::fs::File,
    decoder: voxhap_protocol::FrameDecoder<voxhap_protocol::DeviceToHost>,
}

impl ReferenceHost {
    fn open(path: &str) -> ReferenceHost {
        use std::os::fd::AsRawFd;
        use std::os::unix::fs::OpenOptionsExt;
        let port = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(path)
            .unwrap();
        // SAFETY: termios is plain data, filled by tcgetattr and applied to our own fd.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(port.as_raw_fd(), &mut t), 0);
            libc::cfmakeraw(&mut t);
            assert_eq!(libc::tcsetattr(port.as_raw_fd(), libc::TCSANOW, &t), 0);
        }
        ReferenceHost {
            port,
            decoder: voxhap_protocol::FrameDecoder::new(),
        }
    }

    fn send(&mut self, message: voxhap_protocol::HostToDevice) {
        use std::io::Write;
        let mut frame = [0u8; voxhap_protocol::MAX_WIRE_FRAME_LEN];
        let len = voxhap_protocol::encode_frame(&message, &mut frame).unwrap();
        self.port.write_all(&frame[..len]).unwrap();
    }

    /// Every message decoded until `expected` have come (or [`PATIENCE`] passed), and for 100 ms after, so that
    /// an unexpected extra reply shows too. The wait is for a count, not a time, because a loaded machine can hold
    /// the pty's bytes back far longer than the double takes to answer.
    fn receive(&mut self, expected: usize) -> Vec<voxhap_protocol::DeviceToHost> {
        let mut deadline = Instant::now() + PATIENCE;
        let mut complete = false;
        let mut messages = Vec::new();
        let mut buffer = [0u8; 256];
        while Instant::now() < deadline {
            if !complete && messages.len() >= expected {
                complete = true;
                deadline = Instant::now() + Duration::from_millis(100);
            }
            match self.port.read(&mut buffer) {
                Ok(n) if n > 0 => {
                    for &byte in &buffer[..n] {
                        if let Some(decoded) = self.decoder.push(byte) {
                            messages
                                .push(decoded.expect("the double sent a frame the crate rejects"));
                        }
                    }
                }
                _ => std::thread::sleep(Duration::from_millis(1)),
            }
        }
        messages
    }
}

#[test]
fn spec_device_follows_section_6_as_the_reference_crate_reads_it() {
    use voxhap_protocol::{
        DeviceToHost, Enable, FaultCode, Heartbeat, Hello, HostToDevice, RejectReason, SetForce,
        StatusFlags, PROTOCOL_VERSION,
    };
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        max_force_n: 4.0,
        ..SpecDeviceConfig::default()
    });
    let mut host = ReferenceHost::open(device.path());
    let set_force = |sequence, force_n| {
        HostToDevice::SetForce(SetForce {
            sequence,
            force_n,
            flags: voxhap_protocol::ForceFlags::EMPTY,
        })
    };

    // Before Hello: Enable is refused for want of a session; SetForce is ignored silently.
    host.send(HostToDevice::Enable(Enable {
        watchdog_timeout_us: 0,
    }));
    host.send(set_force(1, [1.0, 0.0, 0.0]));
    match host.receive(1).as_slice() {
        [DeviceToHost::Rejected(r)] => assert_eq!(r.reason, RejectReason::NO_SESSION),
        other => panic!("before Hello: {other:?}"),
    }

    host.send(HostToDevice::Hello(Hello {
        version: PROTOCOL_VERSION,
    }));
    match host.receive(1).as_slice() {
        [DeviceToHost::DeviceInfo(info)] => {
            assert_eq!(info.max_force_n, 4.0);
            assert_eq!(info.model.as_str(), "spec-device");
        }
        other => panic!("Hello: {other:?}"),
    }
    host.send(HostToDevice::Heartbeat(Heartbeat { counter: 7 }));
    host.send(set_force(1, [0.0; 3]));
    let replies = host.receive(2);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::Heartbeat(h), DeviceToHost::State(s)]
            if h.counter == 7 && s.last_force_sequence == 1
                && s.status.contains(StatusFlags::SESSION_OPEN | StatusFlags::LOCKSTEP)
                && !s.status.contains(StatusFlags::ENABLED)),
        "Heartbeat and lockstep State: {replies:?}"
    );

    // Enabled: a force above max_force_n is applied clamped, and the State says so. Then no SetForce for the 50 ms
    // default: the watchdog fires once, 50 ms (plus at most a few control periods) later.
    host.send(HostToDevice::Enable(Enable {
        watchdog_timeout_us: 0,
    }));
    host.send(set_force(2, [30.0, 40.0, 0.0]));
    let replies = host.receive(2);
    match replies.as_slice() {
        [DeviceToHost::State(s), DeviceToHost::Fault(f)] => {
            assert_eq!(s.last_force_sequence, 2);
            assert!(
                s.status
                    .contains(StatusFlags::ENABLED | StatusFlags::FORCE_CLAMPED),
                "{s:?}"
            );
            assert_eq!(f.code, FaultCode::WATCHDOG_EXPIRED);
            let after_us = f.device_time_us - s.device_time_us;
            assert!(
                (50_000..=80_000).contains(&after_us),
                "watchdog after {after_us} us"
            );
        }
        other => panic!("enabled, then silent: {other:?}"),
    }
    let logged = device.forces();
    assert_eq!(logged.len(), 3, "{logged:?}");
    assert!(!logged[0].enabled && !logged[1].enabled && logged[2].enabled);

    host.send(HostToDevice::Heartbeat(Heartbeat { counter: 8 }));
    let replies = host.receive(1);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::Heartbeat(h)]
            if h.status.contains(StatusFlags::WATCHDOG_TRIPPED) && !h.status.contains(StatusFlags::ENABLED)),
        "after the watchdog: {replies:?}"
    );
    device.stop();
    let messages: Vec<_> = device.messages().iter().map(|m| m.message).collect();
    assert_eq!(
        messages,
        [
            HostMessage::Enable {
                watchdog_timeout_us: 0
            },
            HostMessage::Hello { major: 1, minor: 0 },
            HostMessage::Heartbeat { counter: 7 },
            HostMessage::Enable {
                watchdog_timeout_us: 0
            },
            HostMessage::Heartbeat { counter: 8 },
        ]
    );
}

// ---------------------------------------------------------------------------------------------------------------
// A clean session.

#[test]
fn a_clean_session_keeps_every_force_invariant() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        // Below the host's own 3 N limit, so that only the device's maximum can bound the force.
        max_force_n: 2.0,
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "force flowing, then 500 host ticks",
        forces_after_trigger(FLOWING, 500),
    );
    let forces = device.forces();
    assert!(forces.len() > 500, "too few SetForce: {}", summary(&forces));
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 1.0),
        "the wall was never felt: {}",
        summary(&forces)
    );
    assert_force_invariants(&device, 3.0);
    assert_eq!(
        device.dropped_frames(),
        0,
        "the host sent frames a SPEC reader drops"
    );
}

#[test]
fn enable_comes_only_after_the_servo_runs() {
    let _turn = take_turn();
    let device = run_until_ok(SpecDeviceConfig::default(), 0.0, "an Enable", |device| {
        !device
            .messages_like(HostMessage::Enable {
                watchdog_timeout_us: 0,
            })
            .is_empty()
    });
    let messages = device.messages();
    let hello = messages
        .iter()
        .find(|m| matches!(m.message, HostMessage::Hello { .. }))
        .expect("a Hello");
    assert_eq!(hello.message, HostMessage::Hello { major: 1, minor: 0 });
    let enable = messages
        .iter()
        .find(|m| matches!(m.message, HostMessage::Enable { .. }))
        .expect("an Enable");
    let forces = device.forces();
    let first = forces.first().expect("a SetForce");
    assert_eq!(
        first.sequence, 1,
        "SetForce sequence starts at 1 after Hello"
    );
    assert!(
        first.is_zero(),
        "the first SetForce reads the handle with zero force"
    );
    let before_enable = forces.iter().filter(|f| f.index < enable.index).count();
    assert!(
        before_enable >= 25,
        "Enable after only {before_enable} SetForce (the host enables once its servo ran on time ~50 ticks)"
    );
}

/// The one test that cannot wait for a condition: `--duration` is fixed when serve starts. The handle taps until
/// force flows and then stays in the wall, so the stop comes while force is rendered if force flowed at all. 10 s
/// is several times what force took to flow under the loads this file was tried with; if it did not flow, the
/// check on it below fails and says so.
#[test]
fn the_end_of_duration_sends_zero_then_disable_before_closing() {
    let _turn = take_turn();
    let (device, status, output) = run(tapping_until(INSIDE_X_M, FLOWING), 0.0, 10.0);
    assert!(status.success(), "serve failed: {output}");
    assert_stop_sequence(&device);
}

/// The stop sequence (SPEC section 7.1, "Stop"): the last SetForce is zero, a Disable follows it, and both come
/// before the port is closed.
fn assert_stop_sequence(device: &SpecDeviceHandle) {
    let forces = device.forces();
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 0.5),
        "no force was being rendered before the stop: {}",
        summary(&forces)
    );
    let messages = device.messages();
    let disable = messages
        .iter()
        .rev()
        .find(|m| m.message == HostMessage::Disable)
        .unwrap_or_else(|| panic!("no Disable received; messages: {messages:?}"));
    let last_force = forces
        .iter()
        .rev()
        .find(|f| f.index < disable.index)
        .unwrap();
    assert!(
        last_force.is_zero(),
        "the last SetForce before Disable was {:?}",
        last_force.force_n
    );
    assert_eq!(
        device.nonzero_forces_after_index(disable.index),
        0,
        "non-zero SetForce after Disable"
    );
    if let Some(closed) = messages
        .iter()
        .find(|m| m.message == HostMessage::PortClosed)
    {
        assert!(
            disable.index < closed.index,
            "Disable arrived after the port closed"
        );
    }
}

// ---------------------------------------------------------------------------------------------------------------
// Faults and refusals.

/// After the Fault frame went out, at most one non-zero SetForce (already in flight), and none after the next
/// State, until the host sends Enable again.
/// The Fault frame is the first with `code` after the event with index `injected` (the trigger that raised it: on
/// a loaded machine the device's own watchdog may have tripped before, with the same code).
fn assert_zero_within_one_period_of(device: &SpecDeviceHandle, code: u8, injected: u64) {
    let sent = device.sent();
    let fault_frame = sent
        .iter()
        .find(|s| {
            s.index > injected && s.message_type == types::FAULT && s.detail == u16::from(code)
        })
        .unwrap_or_else(|| panic!("the device never sent Fault({code})"));
    let next_state = sent
        .iter()
        .find(|s| s.index > fault_frame.index && s.message_type == types::STATE)
        .expect("a State after the Fault");
    let forces = device.forces();
    let re_enable = enable_after(device, fault_frame.index).map_or(u64::MAX, |m| m.index);
    let before_fault = forces
        .iter()
        .rfind(|f| f.index < fault_frame.index)
        .expect("forces before the fault");
    assert!(
        before_fault.magnitude_n() > 0.5,
        "no force was being rendered when the fault came: {:?}",
        before_fault.force_n
    );
    let after_fault = forces
        .iter()
        .filter(|f| f.index > fault_frame.index && f.index < re_enable && !f.is_zero())
        .count();
    let after_state = forces
        .iter()
        .filter(|f| f.index > next_state.index && f.index < re_enable && !f.is_zero())
        .count();
    assert!(
        after_fault <= 1 && after_state == 0,
        "after Fault({code}): {after_fault} non-zero SetForce after the Fault frame, {after_state} after the next \
         State (allowed: 1 and 0); {}",
        summary(&forces)
    );
}

#[test]
fn a_watchdog_fault_brings_zero_within_one_period_then_a_new_enable() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        fault: Some((FLOWING, fault::WATCHDOG_EXPIRED)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the fault, and 50 host ticks after it",
        enabled_again_after_trigger(FLOWING, 50),
    );
    let injected = device.fired(FLOWING).unwrap().index;
    assert_zero_within_one_period_of(&device, fault::WATCHDOG_EXPIRED, injected);
    let enables = device.messages_like(HostMessage::Enable {
        watchdog_timeout_us: 0,
    });
    assert!(
        enables.len() >= 2,
        "the host did not enable again after a watchdog fault (Enables: {})",
        enables.len()
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn a_latching_fault_brings_zero_within_one_period_and_is_never_cleared_by_the_host() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        fault: Some((FLOWING, fault::OVER_CURRENT)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "500 host ticks after the fault",
        forces_after_trigger(FLOWING, 500),
    );
    let injected = device.fired(FLOWING).unwrap().index;
    assert_zero_within_one_period_of(&device, fault::OVER_CURRENT, injected);
    assert!(
        device.messages_like(HostMessage::ClearFault).is_empty(),
        "the host sent ClearFault by itself"
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_refused_enable_gets_only_zero_forces() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        handle: into_the_wall_after_spawn(0.8),
        refuse_enable: Some(reject::INVALID_ARGUMENT),
        ..SpecDeviceConfig::default()
    };
    // Past the refused Enable, and 300 host ticks with the handle in the wall.
    let in_the_wall = Instant::now() + Duration::from_millis(1200);
    let (device, _status, output) = run_until(
        config,
        0.0,
        "a refused Enable and 300 SetForce with the handle in the wall",
        |device| {
            device.force_count_after(in_the_wall) >= 300
                && !device
                    .messages_like(HostMessage::Enable {
                        watchdog_timeout_us: 0,
                    })
                    .is_empty()
        },
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        !device
            .messages_like(HostMessage::Enable {
                watchdog_timeout_us: 0
            })
            .is_empty(),
        "the host never tried Enable"
    );
    assert_eq!(
        device.max_force_while_not_enabled(),
        0.0,
        "{}",
        summary(&forces)
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_faulted_device_gets_only_zero_forces_and_no_clear_fault() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        handle: into_the_wall_after_spawn(0.8),
        start_faulted: Some(fault::EMERGENCY_STOP),
        ..SpecDeviceConfig::default()
    };
    let in_the_wall = Instant::now() + Duration::from_millis(1200);
    let (device, _status, output) = run_until(
        config,
        0.0,
        "300 SetForce with the handle in the wall",
        |device| device.force_count_after(in_the_wall) >= 300,
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        device.messages_like(HostMessage::ClearFault).is_empty(),
        "the host cleared an e-stop by itself"
    );
    assert_eq!(
        device.max_force_while_not_enabled(),
        0.0,
        "{}",
        summary(&forces)
    );
    assert_force_invariants(&device, 8.0);
}

// ---------------------------------------------------------------------------------------------------------------
// Handshake.

#[test]
fn corrupted_device_info_is_answered_by_another_hello() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        corrupt_device_infos: 2,
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(config, 0.0, "force flowing", |device| {
        device.fired(FLOWING).is_some()
    });
    let hellos = device.messages_like(HostMessage::Hello { major: 0, minor: 0 });
    assert!(
        hellos.len() >= 3,
        "{} Hello for 2 corrupted DeviceInfo",
        hellos.len()
    );
    assert!(
        !device
            .messages_like(HostMessage::Enable {
                watchdog_timeout_us: 0
            })
            .is_empty(),
        "the session never enabled"
    );
    assert!(
        device
            .forces()
            .iter()
            .any(|f| f.enabled && f.magnitude_n() > 0.5),
        "no force rendered: {}",
        summary(&device.forces())
    );
}

#[test]
fn a_version_mismatch_names_both_versions_and_sends_no_force() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        version: (2, 0),
        ..SpecDeviceConfig::default()
    };
    // No --duration: serve must end by itself.
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), 0.0);
    let mut device = SpecDevice::spawn(config);
    let (status, output) = Serve::start(&device, Some(&scene), None).finish(PATIENCE);
    device.stop();
    assert!(!status.success(), "serve accepted a 2.0 device: {output}");
    assert!(
        output.contains("2.0") && output.contains("1.0"),
        "the error does not name both versions: {output}"
    );
    assert_eq!(device.max_force_n(), 0.0);
    assert!(device
        .messages_like(HostMessage::Enable {
            watchdog_timeout_us: 0
        })
        .is_empty());
}

// ---------------------------------------------------------------------------------------------------------------
// Link health.

#[test]
fn a_silent_device_gets_no_stale_force_beyond_the_link_window_then_hello() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        silence: Some((FLOWING, Duration::from_millis(400))),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the silence",
        enabled_again_after_trigger(FLOWING, 0),
    );
    let silence = device.fired(FLOWING).unwrap();
    let silence_start = silence.at;
    let forces = device.forces();
    let messages = device.messages();
    // Forces stay legitimate again once the host has enabled the device anew after the silence.
    let re_enabled = enable_after(&device, silence.index).unwrap().index;
    let stale: Vec<_> = forces
        .iter()
        .filter(|f| f.index > silence.index && f.index < re_enabled && !f.is_zero())
        .collect();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < silence.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the device fell silent: {}",
        summary(&forces)
    );
    // The link window is 20 ms at 1 kHz: 20 forces, and nothing non-zero after it (40 ms allowed for a late servo).
    let late = stale
        .iter()
        .filter(|f| f.at > silence_start + Duration::from_millis(40))
        .count();
    assert!(device.nonzero_forces_after_index(silence.index) >= stale.len());
    assert!(
        stale.len() <= 25 && late == 0,
        "{} non-zero SetForce after the device fell silent, {late} of them more than 40 ms after; {}",
        stale.len(),
        summary(&forces)
    );
    assert!(
        messages
            .iter()
            .any(|m| m.index > silence.index && matches!(m.message, HostMessage::Hello { .. })),
        "no Hello after the link was lost"
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_noisy_link_keeps_every_force_invariant() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        corrupt_fraction: 0.002,
        partial_frame_every: Some(97),
        seed: 12,
        noise_from: Some(Trigger::AfterFirstEnable(Duration::ZERO)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let (device, _status, output) = run_until(
        config,
        0.0,
        "force flowing through the noise, then 500 host ticks",
        forces_after_trigger(FLOWING, 500),
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        device.sent().iter().any(|s| !s.intact),
        "the device corrupted nothing (the test needs noise)"
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn replies_two_periods_late_keep_every_force_invariant() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        reply_delay: Duration::from_millis(2),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "force flowing, then 500 host ticks",
        forces_after_trigger(FLOWING, 500),
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn a_device_that_resets_is_handshaken_again_and_re_enabled() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        reset: Some(FLOWING),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the reset, and 50 host ticks after it",
        enabled_again_after_trigger(FLOWING, 50),
    );
    let messages = device.messages();
    let reset = device.fired(FLOWING).unwrap();
    let reset_at = reset.at;
    let hello_again = messages
        .iter()
        .find(|m| m.index > reset.index && matches!(m.message, HostMessage::Hello { .. }))
        .unwrap_or_else(|| panic!("no Hello after the device reset: {messages:?}"));
    assert!(
        hello_again.at < reset_at + Duration::from_secs(1),
        "Hello only {:?} after the reset",
        hello_again.at - reset_at
    );
    assert!(
        enable_after(&device, hello_again.index).is_some(),
        "never enabled again after the reset"
    );
    // The handle is still in the wall, so after the new Enable the engage rule may keep the force at zero; the
    // session works again when the device applies SetForce frames.
    let forces = device.forces();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < reset.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the device reset: {}",
        summary(&forces)
    );
    assert!(
        forces
            .iter()
            .any(|f| f.index > hello_again.index && f.enabled),
        "the device applied no SetForce after the reset: {}",
        summary(&forces)
    );
    assert_force_invariants_across_a_reset(&device, &reset, 8.0);
}

/// SIGSTOP freezes the whole host (servo, monitor and all): only the device's watchdog can act. After SIGCONT the
/// host must not resume with its stale force: zero until it has enabled the device again, then a ramp. The device
/// thread sends SIGSTOP itself, at the cycle it sees force flowing.
#[test]
fn a_frozen_host_is_caught_by_the_device_watchdog_and_resumes_from_zero() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), 0.0);
    let pid = Arc::new(AtomicI32::new(0));
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        call_at: Some((FLOWING, signaller(&pid, libc::SIGSTOP))),
        ..tapping_until(INSIDE_X_M, FLOWING)
    });
    let mut serve = Serve::start(&device, Some(&scene), None);
    serve.share_pid(&pid);
    serve.wait_for(&device, "force flowing (and SIGSTOP)", |device| {
        device.fired(FLOWING).is_some()
    });
    // Frozen for at least 200 ms (four times the device's watchdog); longer if this thread wakes late.
    let frozen = device.fired(FLOWING).unwrap();
    std::thread::sleep(
        (frozen.at + Duration::from_millis(200)).saturating_duration_since(Instant::now()),
    );
    serve.signal(libc::SIGCONT);
    serve.wait_for(
        &device,
        "a new Enable after the freeze, and 50 host ticks after it",
        |device| enabled_again_after(device, frozen.index, 50),
    );
    serve.signal(libc::SIGTERM);
    let (_status, output) = serve.finish(PATIENCE);
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    // A loaded machine may trip the device's watchdog before the freeze too (a late host): the one that counts
    // is the first after SIGSTOP.
    let watchdog = device
        .sent()
        .into_iter()
        .find(|s| {
            s.index > frozen.index
                && s.message_type == types::FAULT
                && s.detail == u16::from(fault::WATCHDOG_EXPIRED)
        })
        .unwrap_or_else(|| panic!("the device watchdog never fired; serve said {output}"));
    let forces = device.forces();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < frozen.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the host froze: {}",
        summary(&forces)
    );
    let enable = enable_after(&device, watchdog.index)
        .expect("the host did not enable again after the device watchdog tripped");
    // One SetForce computed before the freeze may still go out after it; then zero until the new Enable.
    assert_force_invariants(&device, 8.0);
    let stale: Vec<_> = nonzero_while_not_enabled(&forces)
        .into_iter()
        .filter(|f| f.index > watchdog.index && f.index < enable.index)
        .collect();
    assert!(
        stale.len() <= 1,
        "{} non-zero SetForce to the Idle device after the freeze; {}",
        stale.len(),
        summary(&forces)
    );
    assert_slew_limited(&device);
}

// ---------------------------------------------------------------------------------------------------------------
// Plausibility and limits.

#[test]
fn a_position_glitch_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    // In light contact (3 mm inside the wall, about 1.5 N), then the encoder jumps 1 cm deeper: the coupling would
    // jump to the host's limit in one tick.
    let config = SpecDeviceConfig {
        position_glitch: Some((FLOWING, [-0.01, 0.0, 0.0])),
        ..tapping_until(BALL_RADIUS_M - 0.003, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "contact, the glitch, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    let forces = device.forces();
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 0.5),
        "no contact before the glitch (the test needs one): {}",
        summary(&forces)
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

/// The handle for the velocity tests: it taps into light contact (3 mm inside the wall, about 1.5 N) and stays
/// there once force flows, so the velocity comes while the host renders force (in free space the device could not
/// tell whether the host had engaged yet).
fn light_contact_until_force_flows() -> SpecDeviceConfig {
    tapping_until(BALL_RADIUS_M - 0.003, FLOWING)
}

#[test]
fn an_absurd_velocity_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        velocity_override: Some((FLOWING, [1e30, 0.0, 0.0])),
        ..light_contact_until_force_flows()
    };
    let device = run_until_ok(
        config,
        5.0,
        "force flowing, the velocity, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

#[test]
fn an_inconsistent_velocity_never_steps_the_force_above_the_slew_limit() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        velocity_override: Some((FLOWING, [0.5, 0.0, 0.0])),
        ..light_contact_until_force_flows()
    };
    let device = run_until_ok(
        config,
        5.0,
        "force flowing, the velocity, then 300 host ticks",
        forces_after_trigger(FLOWING, 300),
    );
    assert_slew_limited(&device);
    assert_force_invariants(&device, 8.0);
}

#[test]
fn the_devices_stiffness_cap_holds_from_the_first_tick() {
    let _turn = take_turn();
    let cap_n_per_m = 50.0f32;
    // 0.3 N is 60 % of what the cap allows 1 cm inside the wall, and a tenth of what k = 500 N/m would give there.
    let contact = Trigger::ForceAbove(0.3);
    let config = SpecDeviceConfig {
        max_stiffness_n_per_m: cap_n_per_m,
        ..tapping_until(INSIDE_X_M, contact)
    };
    let device = run_until_ok(
        config,
        0.0,
        "contact, then 500 host ticks (the ramp done)",
        forces_after_trigger(contact, 500),
    );
    let forces = device.forces();
    // 1 cm inside the wall, plus the smooth edge of the ball (two voxels of 1.6 mm) as margin.
    let penetration_m = BALL_RADIUS_M - INSIDE_X_M + 0.0035;
    let bound_n = cap_n_per_m * penetration_m;
    assert!(
        forces.iter().any(|f| f.magnitude_n() > 0.2),
        "the wall was never felt (the test needs contact): {}",
        summary(&forces)
    );
    assert!(
        device.max_force_n() <= bound_n,
        "force above {cap_n_per_m} N/m x {penetration_m} m = {bound_n} N: {}",
        summary(&forces)
    );
}

// ---------------------------------------------------------------------------------------------------------------
// Degrees of freedom (SPEC 6.8): a 2-DOF device uses x and y, a 1-DOF device x alone; the host ignores the other
// components of State and sends them as 0 in SetForce. What such a device should feel is the part of the scene's
// 3-D coupling force along its axes, at a probe on its plane or line (docs/devices/README.md).

/// A scene `[device]` table that puts the device's origin at `translation_m` in the scene (no rotation, scale 1):
/// a 2-DOF device's plane z = 0 becomes the scene plane z = `translation_m[2]`, a 1-DOF device's x axis the scene
/// line through `translation_m` along x.
fn device_offset(translation_m: [f64; 3]) -> String {
    format!("[device]\nname = \"offset\"\n[device.mapping]\ntranslation_m = {translation_m:?}\n")
}

/// The device's declared box for `dof` (SPEC 6.8: the unused axes have no extent).
fn workspace_for(dof: u8) -> ([f32; 3], [f32; 3]) {
    let default = SpecDeviceConfig::default();
    let flat = |v: [f32; 3]| {
        let mut v = v;
        for component in v.iter_mut().skip(usize::from(dof)) {
            *component = 0.0;
        }
        v
    };
    (flat(default.workspace_min_m), flat(default.workspace_max_m))
}

/// A `dof`-DOF device (position and force) declaring `max_force_n`, its handle tapping into the ball to `end_x_m`.
fn device_with_dof(dof: u8, max_force_n: f32, end_x_m: f32) -> SpecDeviceConfig {
    let (workspace_min_m, workspace_max_m) = workspace_for(dof);
    SpecDeviceConfig {
        position_dof: dof,
        force_dof: dof,
        workspace_min_m,
        workspace_max_m,
        max_force_n,
        handle: tapping_to(end_x_m),
        ..SpecDeviceConfig::default()
    }
}

/// Runs `serve` on the ball scene plus `scene_tail` until the device has received a SetForce with x of at least
/// `x_target_n`, or 3 000 SetForce after a light contact (0.3 N applied; a host that never gets there fails the
/// checks after it). The handle keeps tapping, so that a host that starts engagement over gets free space again.
fn run_for_x_force(
    config: SpecDeviceConfig,
    scene_tail: &str,
    x_target_n: f32,
) -> SpecDeviceHandle {
    let contact = Trigger::ForceAbove(0.3);
    let after_contact = forces_after_trigger(contact, 3_000);
    let config = SpecDeviceConfig {
        // A no-op at contact: it makes the device watch for (and log) the trigger.
        call_at: Some((contact, Arc::new(|| {}))),
        ..config
    };
    let (device, status, output) = run_on_scene_until(
        config,
        0.0,
        scene_tail,
        "a SetForce with the expected x, or 3000 host ticks after contact",
        move |device| {
            after_contact(device) || device.forces().iter().any(|f| f.force_n[0] >= x_target_n)
        },
    );
    assert!(status.success(), "serve failed: {output}");
    device
}

/// The SetForce frames whose components beyond the first `dof` are not exactly +0.0.
fn with_unused_components(forces: &[ForceRecord], dof: u8) -> Vec<ForceRecord> {
    forces
        .iter()
        .filter(|f| {
            f.force_n[usize::from(dof)..]
                .iter()
                .any(|c| c.to_bits() != 0)
        })
        .copied()
        .collect()
}

/// The device-side checks every DOF test makes: unused components exactly +0.0 in every SetForce, finite, never
/// above `max_force_n`, slew-limited, zero while not Enabled; and x reached `x_target_n` (the force along the
/// device's axes is what the clamp limits, not the 3-D force it was part of).
fn assert_dof_invariants(device: &SpecDeviceHandle, dof: u8, max_force_n: f32, x_target_n: f32) {
    let forces = device.forces();
    let bad = with_unused_components(&forces, dof);
    assert!(
        bad.is_empty(),
        "{} SetForce with a non-zero component beyond the first {dof} to a {dof}-DOF device (first {:?}); {}",
        bad.len(),
        bad.first(),
        summary(&forces)
    );
    assert_force_invariants(device, max_force_n);
    assert_slew_limited(device);
    let best_x = forces.iter().map(|f| f.force_n[0]).fold(0.0f32, f32::max);
    assert!(
        best_x >= x_target_n,
        "the largest force along x was {best_x} N, expected at least {x_target_n} N; {}",
        summary(&forces)
    );
}

/// A well-behaved 2-DOF device whose plane cuts the ball 1.5 cm above its centre, pressed in to x = 1.5 cm (8.8 mm
/// inside the wall; the 3-D force, about 4.4 N, points 45 degrees out of the plane). It receives x and y only,
/// z exactly 0, and the clamp to its 2 N acts on that in-plane force: x reaches 2 N (clamping the 3-D force first
/// and dropping z afterwards left it at 1.57 N).
#[test]
fn a_two_dof_device_receives_x_and_y_only_clamped_as_sent() {
    receives_its_axes_only_clamped_as_sent(2, [0.0, 0.0, 0.015]);
}

/// A well-behaved 1-DOF device whose line runs 1 cm off the ball's centre in y and in z, pressed in to x = 1.5 cm:
/// the 3-D force (about 4.7 N) has large y and z parts; the device receives x only, y and z exactly 0, and x
/// reaches its 2 N clamp.
#[test]
fn a_one_dof_device_receives_x_only_clamped_as_sent() {
    receives_its_axes_only_clamped_as_sent(1, [0.0, 0.01, 0.01]);
}

/// A `dof`-DOF device of 2 N, its axes mapped `offset_m` from the scene's origin, pressed in to x = 1.5 cm: x
/// reaches 1.9 N, with [`assert_dof_invariants`] on everything it received.
fn receives_its_axes_only_clamped_as_sent(dof: u8, offset_m: [f64; 3]) {
    let _turn = take_turn();
    let (max_force_n, target_n) = (2.0, 1.9);
    let device = run_for_x_force(
        device_with_dof(dof, max_force_n, 0.015),
        &device_offset(offset_m),
        target_n,
    );
    assert_dof_invariants(&device, dof, max_force_n, target_n);
}

/// A device that breaks SPEC 6.8 and reports garbage in the State components its DOF leaves unused (a constant
/// 2 cm of position and 0.5 m/s of velocity) is rendered as if they were 0: pressed 1 cm into the wall on the
/// ball's equator it renders about 5 N along x (k = 500 N/m) and gets its full 3 N, not the 0.63 N of the upper
/// slope at z = 2 cm (2-DOF), nor nothing at (2, 2, 2) cm outside the ball (1-DOF).
fn garbage_in_unused_state_components_is_ignored(dof: u8) {
    let _turn = take_turn();
    let (max_force_n, target_n) = (3.0, 2.9);
    let config = SpecDeviceConfig {
        unused_components: Some(([0.02; 3], [0.5; 3])),
        ..device_with_dof(dof, max_force_n, INSIDE_X_M)
    };
    let device = run_for_x_force(config, "", target_n);
    assert_dof_invariants(&device, dof, max_force_n, target_n);
}

#[test]
fn a_two_dof_devices_garbage_z_in_state_is_ignored() {
    garbage_in_unused_state_components_is_ignored(2);
}

#[test]
fn a_one_dof_devices_garbage_y_and_z_in_state_are_ignored() {
    garbage_in_unused_state_components_is_ignored(1);
}

// ---------------------------------------------------------------------------------------------------------------
// Signals.

/// Starts serve without a duration; the device thread sends `signal` at the cycle it sees force flowing; checks
/// the stop sequence.
fn stops_cleanly_on(signal: libc::c_int) {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), 0.0);
    let pid = Arc::new(AtomicI32::new(0));
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        call_at: Some((FLOWING, signaller(&pid, signal))),
        ..tapping_until(INSIDE_X_M, FLOWING)
    });
    let mut serve = Serve::start(&device, Some(&scene), None);
    serve.share_pid(&pid);
    serve.wait_for(&device, "force flowing (and the signal)", |device| {
        device.fired(FLOWING).is_some()
    });
    let (_status, _output) = serve.finish(PATIENCE);
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    assert_stop_sequence(&device);
    assert_force_invariants(&device, 8.0);
}

#[test]
fn sigint_stops_with_zero_then_disable() {
    stops_cleanly_on(libc::SIGINT);
}

#[test]
fn sigterm_stops_with_zero_then_disable() {
    stops_cleanly_on(libc::SIGTERM);
}

#[test]
fn sighup_stops_with_zero_then_disable() {
    stops_cleanly_on(libc::SIGHUP);
}

#[test]
fn sigquit_stops_with_zero_then_disable() {
    stops_cleanly_on(libc::SIGQUIT);
}

#[test]
fn sigusr1_stops_with_zero_then_disable() {
    stops_cleanly_on(libc::SIGUSR1);
}

// ---------------------------------------------------------------------------------------------------------------
// Random misbehaviour.

/// The longest run of consecutive non-zero SetForce frames received while the device was not Enabled.
fn longest_nonzero_run_while_not_enabled(forces: &[ForceRecord]) -> usize {
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

/// A device with a random mix of faults, delays, glitches, absurd velocities, noise and silence (seeded, so a
/// failure names its scenario), checked for the device-side invariants: finite, never above `max_force_n`, never
/// rising faster than the slew limit, and zero while not enabled (up to 3 frames in flight after the device left
/// Enabled, the host's 3-period staleness bound).
#[test]
fn random_misbehaviour_keeps_the_device_side_invariants() {
    let mut seed = 0x5eed_u64;
    let mut next = move |below: u64| {
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (seed >> 33) % below
    };
    for scenario in 0..3 {
        let at = |ms: u64| Trigger::AfterFirstEnable(Duration::from_millis(300 + ms));
        let max_force_n = 1.0 + next(7) as f32;
        let mut config = SpecDeviceConfig {
            max_force_n,
            handle: into_the_wall(0.3 + next(5) as f64 * 0.1),
            reply_delay: Duration::from_micros(next(3000)),
            seed: next(1000) + 1,
            ..SpecDeviceConfig::default()
        };
        if next(2) == 0 {
            config.fault = Some((at(next(1200)), next(8) as u8));
        }
        if next(2) == 0 {
            let jump = (next(2001) as f32 - 1000.0) * 1e-5;
            config.position_glitch = Some((at(next(1200)), [jump, 0.0, 0.0]));
        }
        if next(2) == 0 {
            let speed = [0.5, 10.0, 1e30][next(3) as usize];
            config.velocity_override = Some((at(next(1200)), [speed, 0.0, 0.0]));
        }
        if next(2) == 0 {
            config.corrupt_fraction = next(30) as f64 * 1e-4;
            config.noise_from = Some(at(0));
        }
        if next(2) == 0 {
            config.silence = Some((at(next(1200)), Duration::from_millis(next(100))));
        }
        let description = format!(
            "scenario {scenario}: max {max_force_n} N, delay {:?}, fault {:?}, glitch {:?}, velocity {:?}, \
             noise {}, silence {:?}",
            config.reply_delay,
            config.fault,
            config.position_glitch,
            config.velocity_override,
            config.corrupt_fraction,
            config.silence
        );
        let _turn = take_turn();
        let reply_delay = config.reply_delay;
        // Every misbehaviour has come, and the host has been watched for 300 of its ticks after the last one.
        let triggers: Vec<Trigger> = [
            config.fault.map(|(t, _)| t),
            config.position_glitch.map(|(t, _)| t),
            config.velocity_override.map(|(t, _)| t),
            config.noise_from,
            config.silence.map(|(t, _)| t),
        ]
        .into_iter()
        .flatten()
        .collect();
        let (device, _status, output) = run_until(
            config,
            2.0,
            "every misbehaviour, then 300 host ticks",
            move |device| {
                let fired: Option<Vec<_>> = triggers.iter().map(|&t| device.fired(t)).collect();
                let Some(fired) = fired else {
                    return false;
                };
                let last = fired.iter().map(|f| f.index).max();
                device.force_count() >= 300
                    && last.is_none_or(|index| device.force_count_after_index(index) >= 300)
            },
        );
        let forces = device.forces();
        assert!(
            forces.len() > 200,
            "{description}: too few SetForce ({}); serve said {output}",
            forces.len()
        );
        assert_eq!(device.non_finite_forces(), 0, "{description}");
        assert!(
            device.max_force_n() <= max_force_n * (1.0 + 1e-6),
            "{description}: {}",
            summary(&forces)
        );
        let slew = device.max_slew_n_per_ms();
        assert!(
            slew <= SLEW_LIMIT_N_PER_MS + SLEW_MARGIN_N_PER_MS,
            "{description}: |force| rose by {slew} N in one tick"
        );
        // Forces already on their way when the device dropped out: one per period of reply delay, plus one.
        let in_flight = 2 + reply_delay.as_micros() as usize / 1000;
        let run = longest_nonzero_run_while_not_enabled(&forces);
        assert!(
            run <= in_flight,
            "{description}: {run} non-zero SetForce in a row while the device was not Enabled (at most \
             {in_flight} may be in flight)"
        );
    }
}

// ---------------------------------------------------------------------------------------------------------------
// A watchdog that acts.

/// The stall monitor, from the device's side: a servo thread (this test thread, exchanging through the same
/// reconnecting wrapper, protocol driver and stop channel `serve` uses) renders a force, then stops ticking. The
/// real monitor thread must bring the device to zero force and Disable on its own, within its stated time (20
/// periods, 20 ms at 1 kHz) plus a margin for a loaded machine, and before the device's own 50 ms watchdog fires.
/// When the thread ticks again, force comes back only after a new Enable.
#[test]
fn a_stalled_servo_thread_is_brought_to_zero_by_the_monitor() {
    use glam::DVec3;
    use std::sync::atomic::{AtomicBool, Ordering};
    use voxhap::device::supervisor::{SupervisorConfig, TickInput};
    use voxhap::servo::device::{open_device, DeviceSpec};
    use voxhap::servo::monitor::{Monitor, MonitorConfig, StopSlot, EVENT_RING};
    use voxhap::servo::setup::SceneSetup;
    use voxhap::servo::stats::ServoStats;

    /// Scheduling slack on a shared 2-core machine, on top of the monitor's stated time.
    const MARGIN: Duration = Duration::from_millis(25);
    let _turn = take_turn();
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        handle: free_space(),
        ..SpecDeviceConfig::default()
    });
    let setup = SceneSetup::builtin().unwrap();
    let mut servo = open_device(
        &DeviceSpec::Serial(device.path().into()),
        SupervisorConfig::default(),
        (setup.arm.clone(), setup.start_m),
        1e-3,
    )
    .unwrap()
    .device;
    let slot = StopSlot::new();
    servo.set_stop_slot(slot.clone());
    servo.connect(0).unwrap();
    let stats = Arc::new(ServoStats::new(1000.0));
    let running = Arc::new(AtomicBool::new(true));
    let config = MonitorConfig {
        period: Duration::from_millis(1),
        stall_periods: 20,
    };
    let (_events_tx, events_rx) = rtrb::RingBuffer::new(EVENT_RING);
    let mut monitor = Monitor::spawn(config, stats.clone(), running, slot, events_rx).unwrap();

    // The servo thread: a 0.8 N rendered force (below the engage threshold, so it engages and ramps in).
    let start = Instant::now();
    let mut tick = 0u64;
    // Ticks until `done` holds for the device (checked every 10 ticks), for at most PATIENCE.
    let mut tick_until = |servo: &mut Box<dyn voxhap::servo::device::ServoDevice>,
                          what: &str,
                          done: &dyn Fn(&SpecDeviceHandle) -> bool| {
        let since = Instant::now();
        while !done(&device) {
            assert!(
                since.elapsed() < PATIENCE,
                "{PATIENCE:?} passed before {what}: {}",
                summary(&device.forces())
            );
            for _ in 0..10 {
                tick += 1;
                let deadline = start + Duration::from_micros(tick * 1_000);
                if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
                servo.exchange(TickInput::at(DVec3::new(0.8, 0.0, 0.0), tick * 1_000));
                stats.ticks.fetch_add(1, Ordering::Release);
            }
        }
    };
    // The whole 0.8 N (ramp done, up to f32 rounding) before the stall.
    tick_until(&mut servo, "the force ramped in", &|device| {
        device
            .last_force()
            .is_some_and(|f| f.enabled && f.magnitude_n() > 0.79)
    });
    let before_stall = device.forces();
    let last = *before_stall.last().expect("no SetForce before the stall");
    assert!(
        last.enabled && last.magnitude_n() > 0.5,
        "no force was being rendered before the stall: {}",
        summary(&before_stall)
    );

    // The stall: nobody ticks for 300 ms. (On a loaded machine this thread may already have overslept 20 ms
    // during the ticks above, and the monitor rightly acted then too: count only this stall.)
    let stops_before = stats.monitor_stops.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(300));
    let forces = device.forces();
    let zero = forces
        .iter()
        .find(|f| f.index > last.index && f.is_zero())
        .unwrap_or_else(|| panic!("no zero SetForce after the stall; {}", summary(&forces)));
    let took = zero.at.duration_since(last.at);
    assert!(
        took <= config.stall_after() + MARGIN,
        "the zero force came {took:?} after the last tick's force (monitor: {:?} + {MARGIN:?})",
        config.stall_after()
    );
    let messages = device.messages();
    let disable = messages
        .iter()
        .find(|m| m.index > last.index && m.message == HostMessage::Disable)
        .expect("no Disable from the monitor");
    let device_watchdog = device.sent().into_iter().find(|s| {
        s.index > last.index
            && s.message_type == types::FAULT
            && s.detail == u16::from(fault::WATCHDOG_EXPIRED)
    });
    if let Some(fired) = device_watchdog {
        assert!(
            fired.index > disable.index,
            "the device's own watchdog fired before the monitor's Disable"
        );
    }
    assert_eq!(
        stats.monitor_stops.load(Ordering::Relaxed),
        stops_before + 1,
        "one monitor stop for the stall"
    );

    // Ticking again: zero until a new Enable, then force ramps in again.
    tick_until(&mut servo, "a new Enable and force again", &|device| {
        enable_after(device, disable.index).is_some_and(|enable| {
            device
                .last_force()
                .is_some_and(|f| f.index > enable.index && f.magnitude_n() > 0.5)
        })
    });
    monitor.stop();
    servo.stop();
    device.stop();
    let forces = device.forces();
    let enable = enable_after(&device, disable.index).expect("no Enable after the stall");
    let early: Vec<_> = forces
        .iter()
        .filter(|f| f.index > disable.index && f.index < enable.index && !f.is_zero())
        .collect();
    assert!(
        early.is_empty(),
        "non-zero force before the new Enable: {early:?}"
    );
    assert!(
        forces
            .iter()
            .any(|f| f.index > enable.index && f.magnitude_n() > 0.5),
        "force never came back after the stall; {}",
        summary(&forces)
    );
    assert_slew_limited(&device);
}
