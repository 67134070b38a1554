//! The external force input (`serve --external-force`), sent over the WebSocket control API while the handle rests
//! in free space (where the scene renders nothing), checked on what the device received and in the recorded trace:
//! the commanded force arrives as it was sent while it is within the device's limits; a huge one never exceeds the
//! device's max force or the host's slew limit; and once the messages stop it is zero after the staleness timeout.

use crate::util::spec_device::{ForceRecord, SpecDevice, SpecDeviceConfig, SpecDeviceHandle};
use crate::util::spec_serve::{
    assert_finite_and_bounded, assert_slew_limited, ball_scene, free_space, summary, take_turn,
    Serve, PATIENCE,
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

/// What the test asks the sender thread to send (`None`: nothing), with a phase number the thread acknowledges
/// once it has no message in flight for an older phase.
#[derive(Default)]
struct Command {
    phase: u64,
    force_n: Option<[f64; 3]>,
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
                    let (phase, force) = {
                        let c = command.lock().unwrap();
                        (c.phase, c.force_n)
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
        let phase = {
            let mut c = self.command.lock().unwrap();
            c.phase += 1;
            c.force_n = force_n;
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
    let wanted = force_n.map(|f| f as f32);
    device
        .forces()
        .iter()
        .any(|f| f.enabled && f.force_n == wanted)
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

/// After the last accepted message (answered at `last`), the host sends the force for at most the timeout: counted
/// in its ticks, one SetForce each, from the first tick that saw the message, which began before `last`. Frames
/// arriving after `last` are at most those ticks, plus the frames already on their way and the ticks the safety
/// pipeline may take to bring |F| down to zero.
fn assert_zero_within_the_timeout(device: &SpecDeviceHandle, last: Instant, what: &str) {
    let after = forces_after(device, last);
    let nonzero = after.iter().filter(|f| !f.is_zero()).count();
    // In flight: the SetForce of the tick under way and the one the pty still holds; ramp: at most
    // MAX_FORCE_N / (0.5 N/ms) ticks if the host slews |F| down too.
    let bound = TIMEOUT_TICKS + 2 + (MAX_FORCE_N / 0.5).ceil() as usize;
    assert!(
        nonzero <= bound,
        "{what}: {nonzero} non-zero SetForce after the last message was accepted (timeout {TIMEOUT_TICKS} ticks, \
         bound {bound}); {}",
        summary(&after)
    );
    let first_zero = after.iter().position(ForceRecord::is_zero).unwrap();
    assert!(
        after[first_zero..].iter().all(ForceRecord::is_zero),
        "{what}: force came back after it went to zero; {}",
        summary(&after)
    );
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

    // 1. Within the limits: the device applies exactly the force sent (as f32, the wire's type).
    sender.set(Some(WITHIN));
    serve.wait_for(&device, "the commanded force at the device", |d| {
        applied(d, WITHIN)
    });
    sender.check();
    sender.set(None);
    let last = sender.last_accepted(WITHIN);
    serve.wait_for(
        &device,
        "zero force after the messages stopped",
        zero_after(last, 200),
    );
    assert_zero_within_the_timeout(&device, last, "within the limits");

    // 2. Far above the device's limit: capped at its max force, never stepping faster than the slew limit.
    sender.set(Some(HUGE));
    serve.wait_for(&device, "the huge force capped at the device", |d| {
        d.forces()
            .iter()
            .any(|f| f.enabled && f.magnitude_n() >= MAX_FORCE_N * 0.999)
    });
    sender.check();
    sender.set(None);
    let last = sender.last_accepted(HUGE);
    serve.wait_for(
        &device,
        "zero force after the messages stopped",
        zero_after(last, 200),
    );
    assert_zero_within_the_timeout(&device, last, "the huge force");
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
    let mut seen = [0usize; 3];
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let value = |i: usize| cells[i].parse::<f64>().unwrap();
        let force = external.map(value);
        let which = [[0.0; 3], WITHIN, HUGE].iter().position(|f| *f == force);
        let which =
            which.unwrap_or_else(|| panic!("external force {force:?} was never sent: {line}"));
        seen[which] += 1;
        let sent = sent.map(value);
        let magnitude = sent.iter().map(|f| f * f).sum::<f64>().sqrt();
        assert!(magnitude <= f64::from(MAX_FORCE_N) * (1.0 + 1e-9), "{line}");
    }
    assert!(
        seen[1] > 0 && seen[2] > 0 && seen[0] > 0,
        "rows with no, the small and the huge external force: {seen:?}"
    );
}
