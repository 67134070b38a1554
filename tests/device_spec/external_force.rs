//! The external force input (`serve --external-force`), sent over the WebSocket control API while the handle rests
//! in free space (where the scene renders nothing), checked on what the device received and in the recorded trace:
//! the commanded force arrives as it was sent while it is within the device's limits; a huge one never exceeds the
//! device's max force or the host's slew limit; and once the messages stop it is zero after the staleness timeout.
//!
//! Counted, not timed: the timeout is checked on a force sent in one message only, a value no other message
//! carries, so the SetForce frames that carry it are exactly the host ticks that applied it, however many frames a
//! busy machine held back on the way.

use crate::util::spec_device::{
    ForceRecord, HostMessage, SpecDevice, SpecDeviceConfig, SpecDeviceHandle,
};
use crate::util::spec_serve::{
    assert_finite_and_bounded, assert_slew_limited, ball_scene, free_space, take_turn, Serve,
    PATIENCE,
};
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

const TOKEN: &str = "external-force-token-0123";
/// What the device declares (DeviceInfo): the host caps every force there.
const MAX_FORCE_N: f32 = 2.0;
/// `--external-force-timeout 0.05`: 50 ticks at 1 kHz.
const TIMEOUT_TICKS: usize = 50;

/// A force within the limits (|F| = 0.75 N, below the host's 1 N engage threshold, so a host that had to enable the
/// device again engages while it is sent), and one far above them (but below the 1000 N the input accepts).
const WITHIN: [f64; 3] = [0.6, -0.45, 0.0];
const HUGE: [f64; 3] = [0.0, 0.0, -400.0];
/// A small force along the huge one (below the engage threshold too): flowing, it shows the output is engaged
/// before the huge force is sent.
const PROBE: [f64; 3] = [0.0, 0.0, -0.5];

/// The force of the one message whose timeout is checked, at its `attempt` (1, 2, ...): [`WITHIN`] but for a z
/// that no other message carries, so the frames that carry it are the ticks that applied it.
fn once_force(attempt: u32) -> [f64; 3] {
    [WITHIN[0], WITHIN[1], 0.01 * f64::from(attempt)]
}

/// What the test asks the sender thread to send (`None`: nothing), with a phase number the thread acknowledges
/// once it has no message in flight for an older phase.
#[derive(Default)]
struct Command {
    phase: u64,
    force_n: Option<[f64; 3]>,
    /// Send the force in one message only, then nothing.
    once: bool,
}

/// When each accepted message was answered, and the force it carried.
type Accepted = Arc<Mutex<Vec<(Instant, [f64; 3])>>>;

/// A WebSocket client on its own thread that sends the current command every 10 ms (`set_external_force`, with
/// the token) and keeps the time of every accepted reply.
struct ForceSender {
    command: Arc<Mutex<Command>>,
    acked_phase: Arc<AtomicU64>,
    accepted: Accepted,
    errors: Arc<Mutex<Vec<String>>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ForceSender {
    fn start(port: u16) -> ForceSender {
        let mut sender = ForceSender {
            command: Arc::default(),
            acked_phase: Arc::default(),
            accepted: Arc::default(),
            errors: Arc::default(),
            stop: Arc::default(),
            thread: None,
        };
        let (command, acked, accepted, errors, stop) = (
            sender.command.clone(),
            sender.acked_phase.clone(),
            sender.accepted.clone(),
            sender.errors.clone(),
            sender.stop.clone(),
        );
        let thread = std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap();
            runtime.block_on(async move {
                let url = format!("ws://127.0.0.1:{port}/ws?rate=1");
                // serve may still be starting: retry until it listens.
                let mut ws = loop {
                    if stop.load(Ordering::Acquire) {
                        return;
                    }
                    match tokio_tungstenite::connect_async(&url).await {
                        Ok((ws, _)) => break ws,
                        Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
                    }
                };
                let mut id = 0u64;
                while !stop.load(Ordering::Acquire) {
                    let (phase, force, once) = {
                        let c = command.lock().unwrap();
                        (c.phase, c.force_n, c.once)
                    };
                    if let Some(force_n) = force {
                        id += 1;
                        let message = json!({"type": "control", "id": id, "token": TOKEN,
                            "command": {"command": "set_external_force", "force_n": force_n}});
                        if ws
                            .send(Message::Text(message.to_string().into()))
                            .await
                            .is_err()
                        {
                            errors
                                .lock()
                                .unwrap()
                                .push("the WebSocket closed".to_owned());
                            return;
                        }
                        // The answer to this id (states and the hello are skipped).
                        loop {
                            let next =
                                tokio::time::timeout(Duration::from_secs(30), ws.next()).await;
                            let Ok(Some(Ok(Message::Text(text)))) = next else {
                                if !matches!(next, Ok(Some(Ok(_)))) {
                                    errors.lock().unwrap().push(format!("no answer: {next:?}"));
                                    return;
                                }
                                continue;
                            };
                            let value: Value = serde_json::from_str(text.as_str()).unwrap();
                            if value["id"] != json!(id) {
                                continue;
                            }
                            if value["ok"] == json!(true) {
                                accepted.lock().unwrap().push((Instant::now(), force_n));
                            } else {
                                errors.lock().unwrap().push(value.to_string());
                            }
                            break;
                        }
                        if once {
                            let mut c = command.lock().unwrap();
                            if c.phase == phase {
                                c.force_n = None;
                            }
                        }
                    }
                    acked.store(phase, Ordering::Release);
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            });
        });
        sender.thread = Some(thread);
        sender
    }

    /// Sends `force_n` from now on (`None`: stops sending); returns once no message of the previous command is in
    /// flight any more.
    fn set(&self, force_n: Option<[f64; 3]>) {
        self.command(force_n, false);
    }

    /// Sends `force_n` in one message only; returns once it was answered.
    fn send_once(&self, force_n: [f64; 3]) {
        self.command(Some(force_n), true);
    }

    fn command(&self, force_n: Option<[f64; 3]>, once: bool) {
        let phase = {
            let mut c = self.command.lock().unwrap();
            c.phase += 1;
            c.force_n = force_n;
            c.once = once;
            c.phase
        };
        let start = Instant::now();
        while self.acked_phase.load(Ordering::Acquire) < phase {
            self.check();
            assert!(
                start.elapsed() < PATIENCE,
                "the sender did not take the command"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// When the last message with `force_n` was accepted.
    fn last_accepted(&self, force_n: [f64; 3]) -> Instant {
        self.accepted
            .lock()
            .unwrap()
            .iter()
            .rev()
            .find(|(_, f)| *f == force_n)
            .map(|(at, _)| *at)
            .expect("a message was accepted")
    }

    fn check(&self) {
        let errors = self.errors.lock().unwrap();
        assert!(errors.is_empty(), "the control API refused: {errors:?}");
    }
}

impl Drop for ForceSender {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The device applied (Enabled) a SetForce equal to `force_n` as f32, the wire's type.
fn applied(device: &SpecDeviceHandle, force_n: [f64; 3]) -> bool {
    applied_after(device, force_n, 0)
}

/// [`applied`], among the SetForce frames after the first `from`.
fn applied_after(device: &SpecDeviceHandle, force_n: [f64; 3], from: usize) -> bool {
    let wanted = force_n.map(|f| f as f32);
    device
        .forces()
        .iter()
        .skip(from)
        .any(|f| f.enabled && f.force_n == wanted)
}

/// The device received the huge force capped at its max force after the first `from` SetForce frames.
fn capped_after(device: &SpecDeviceHandle, from: usize) -> bool {
    device
        .forces()
        .iter()
        .skip(from)
        .any(|f| f.enabled && f.magnitude_n() >= MAX_FORCE_N * 0.999)
}

/// Enable messages the device received so far (a new one: the host enabled it again, and engages only once the
/// rendered force is small).
fn enables(device: &SpecDeviceHandle) -> usize {
    device
        .messages_like(HostMessage::Enable {
            watchdog_timeout_us: 0,
        })
        .len()
}

/// SetForce frames received after `at`.
fn forces_after(device: &SpecDeviceHandle, at: Instant) -> Vec<ForceRecord> {
    device.forces().into_iter().filter(|f| f.at > at).collect()
}

/// At least `n` SetForce frames after `at`, the last 40 of them zero.
fn zero_after(at: Instant, n: usize) -> impl Fn(&SpecDeviceHandle) -> bool {
    move |device| {
        let after = forces_after(device, at);
        after.len() >= n && after.iter().rev().take(40).all(ForceRecord::is_zero)
    }
}

/// The force sent in one message only (`force_n`, a value no other message carries) was applied for at most the
/// timeout: the frames that carry it are the host ticks that applied it (at most one frame per tick, and the timeout
/// counts skipped ticks too), however many frames were held back on the way. After the last of them, only the slew
/// down to zero (at most `MAX_FORCE_N / 0.5 N per ms` ticks) is non-zero, never above it, and the force stays zero.
fn assert_applied_for_at_most_the_timeout(device: &SpecDeviceHandle, force_n: [f64; 3]) {
    let forces = device.forces();
    let wanted = force_n.map(|f| f as f32);
    let carrying: Vec<usize> = (0..forces.len())
        .filter(|&i| forces[i].force_n == wanted)
        .collect();
    assert!(!carrying.is_empty(), "the force was never sent");
    let pattern = || run_lengths(&forces[carrying[0]..]);
    assert!(
        carrying.len() <= TIMEOUT_TICKS,
        "{} SetForce carried the force of one message (timeout {TIMEOUT_TICKS} ticks); after its first: {}",
        carrying.len(),
        pattern()
    );
    let after = &forces[carrying[carrying.len() - 1] + 1..];
    let ramp = (MAX_FORCE_N / 0.5).ceil() as usize;
    let nonzero = after.iter().filter(|f| !f.is_zero()).count();
    let magnitude = wanted.iter().map(|f| f * f).sum::<f32>().sqrt();
    assert!(
        nonzero <= ramp && after.iter().all(|f| f.magnitude_n() <= magnitude),
        "after the last tick that applied the force, {nonzero} non-zero SetForce (slew down at most {ramp}, none \
         above {magnitude} N); after its first: {}",
        pattern()
    );
    assert!(
        after.iter().rev().take(40).all(ForceRecord::is_zero),
        "the force did not stay zero; after its first: {}",
        pattern()
    );
}

/// The SetForce frames as runs of equal forces: `count x [fx, fy, fz]`.
fn run_lengths(forces: &[ForceRecord]) -> String {
    let mut runs: Vec<(usize, [f32; 3])> = Vec::new();
    for f in forces {
        match runs.last_mut() {
            Some((count, force)) if *force == f.force_n => *count += 1,
            _ => runs.push((1, f.force_n)),
        }
    }
    let runs: Vec<String> = runs.iter().map(|(n, f)| format!("{n} x {f:?}")).collect();
    runs.join(", ")
}

#[test]
fn an_external_force_over_the_websocket_reaches_the_device_capped_and_times_out() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), 0.0);
    let trace = dir.path().join("run.csv");
    let port = free_port();
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        max_force_n: MAX_FORCE_N,
        handle: free_space(),
        ..SpecDeviceConfig::default()
    });
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command
        .args(["serve", "--no-foxglove", "--rt", "off", "--device"])
        .arg(format!("serial:{}", device.path()))
        .arg("--scene")
        .arg(&scene)
        .args(["--http", &format!("127.0.0.1:{port}"), "--token", TOKEN])
        .args(["--external-force", "--external-force-timeout", "0.05"])
        .arg("--record")
        .arg(&trace);
    let mut serve = Serve::spawn(command);
    let sender = ForceSender::start(port);

    // 1. Within the limits: the device applies exactly the force sent (as f32, the wire's type); the force of one
    // last message, once it flows, for at most the timeout. (A host that lost the link or stopped the device
    // meanwhile may apply none of it: then again.)
    let mut once = Vec::new();
    loop {
        assert!(
            once.len() < 20,
            "the one message's force was never applied: {once:?}"
        );
        let from = device.force_count();
        sender.set(Some(WITHIN));
        serve.wait_for(&device, "the commanded force at the device", |d| {
            applied_after(d, WITHIN, from)
        });
        sender.check();
        let force_n = once_force(once.len() as u32 + 1);
        once.push(force_n);
        sender.send_once(force_n);
        let last = sender.last_accepted(force_n);
        serve.wait_for(
            &device,
            "zero force after the messages stopped",
            zero_after(last, 200),
        );
        if applied(&device, force_n) {
            assert_applied_for_at_most_the_timeout(&device, force_n);
            break;
        }
    }

    // 2. Far above the device's limit: capped at its max force, never stepping faster than the slew limit. Sent
    // once a small force along it flows (the output is engaged: a host that enabled the device again engages only
    // while the rendered force is small, so not while the huge one is sent: then again).
    loop {
        let from = device.force_count();
        sender.set(Some(PROBE));
        serve.wait_for(&device, "the small force along the huge one", |d| {
            applied_after(d, PROBE, from)
        });
        let (from, enabled) = (device.force_count(), enables(&device));
        sender.set(Some(HUGE));
        serve.wait_for(&device, "the huge force capped at the device", |d| {
            capped_after(d, from) || enables(d) > enabled
        });
        if capped_after(&device, from) {
            break;
        }
    }
    sender.check();
    sender.set(None);
    let last = sender.last_accepted(HUGE);
    serve.wait_for(
        &device,
        "zero force after the messages stopped",
        zero_after(last, 200),
    );
    drop(sender);
    serve.signal(libc::SIGTERM);
    let (status, output) = serve.finish(PATIENCE);
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    assert!(status.success(), "serve failed: {output}");
    assert!(output.contains("external force: accepted"), "{output}");
    assert_finite_and_bounded(&device, MAX_FORCE_N);
    assert_slew_limited(&device);
    let capped = device
        .forces()
        .iter()
        .filter(|f| f.magnitude_n() >= MAX_FORCE_N * 0.999)
        .all(|f| f.force_n[0] == 0.0 && f.force_n[1] == 0.0 && f.force_n[2] < 0.0);
    assert!(capped, "the capped force points along the huge one (-z)");

    // 3. The trace: its external force columns hold exactly what was sent (the huge one too: what was added before
    // the safety pipeline), and zero otherwise; the force sent never exceeds the device's limit.
    let text = std::fs::read_to_string(&trace).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|c| *c == name)
            .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
    };
    let external = ["x", "y", "z"].map(|a| column(&format!("external_force_{a}_n")));
    let sent = ["x", "y", "z"].map(|a| column(&format!("force_{a}_n")));
    // Rows with no, the small, the huge, and another external force (the probe, the one message's).
    let mut seen = [0usize; 4];
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let value = |i: usize| cells[i].parse::<f64>().unwrap();
        let force = external.map(value);
        let which = [[0.0; 3], WITHIN, HUGE, PROBE]
            .iter()
            .chain(&once)
            .position(|f| *f == force);
        let which =
            which.unwrap_or_else(|| panic!("external force {force:?} was never sent: {line}"));
        seen[which.min(3)] += 1;
        let sent = sent.map(value);
        let magnitude = sent.iter().map(|f| f * f).sum::<f64>().sqrt();
        assert!(magnitude <= f64::from(MAX_FORCE_N) * (1.0 + 1e-9), "{line}");
    }
    assert!(
        seen[1] > 0 && seen[2] > 0 && seen[0] > 0 && seen[3] > 0,
        "rows with no, the small, the huge and another external force: {seen:?}"
    );
}
