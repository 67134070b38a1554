//! `voxhap mock-device --local-model` over a real pseudo-terminal (protocol/SPEC.md section 10): a host that
//! sends local models gets them rendered by the device's own loop, and from the device's own log the force never
//! exceeds the limit and is zero once a silenced host's last model is 5 ms past its expiry; `voxhap serve`, which
//! does not send local models, drives the capable device through SetForce as before. Only what holds whatever the
//! machine's load is asserted: the log's times are the device's own.

use crate::util::mock_process::MockProcess as Mock;
use serialport::SerialPort;
use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};
use voxhap_protocol::{
    encode_frame, DeviceToHost, Enable, FrameDecoder, Heartbeat, HostSession, HostToDevice,
    LocalKind, LocalModelParams, SiPrimitive, StatusFlags, MAX_WIRE_FRAME_LEN,
};

/// One line of the mock's log (`LOCAL_LOG_HEADER`).
#[derive(Debug)]
struct Cycle {
    t_us: u64,
    mode: String,
    force_n: f64,
    limit_n: f64,
    model_age_us: u64,
    expiry_us: u64,
}

fn read_log(path: &Path) -> Vec<Cycle> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(voxhap::device::mock::LOCAL_LOG_HEADER),
        "the log starts with its header"
    );
    lines
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            assert_eq!(f.len(), 9, "{line}");
            Cycle {
                t_us: f[0].parse().unwrap(),
                mode: f[1].to_string(),
                force_n: f[2].parse().unwrap(),
                limit_n: f[3].parse().unwrap(),
                model_age_us: f[5].parse().unwrap(),
                expiry_us: f[6].parse().unwrap(),
            }
        })
        .collect()
}

/// Reads the mock's stdout until its exit summary (it flushes its log before printing it).
fn wait_for_done(mock: &mut Mock) -> String {
    loop {
        let line = mock.next_line();
        if line.starts_with("done:") || line.is_empty() {
            return line;
        }
    }
}

fn send(port: &mut dyn SerialPort, message: &HostToDevice) {
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(message, &mut frame).unwrap();
    port.write_all(&frame[..len]).unwrap();
}

/// Whatever the device sent so far, decoded (non-blocking beyond the port's short timeout).
fn receive(
    port: &mut dyn SerialPort,
    decoder: &mut FrameDecoder<DeviceToHost>,
) -> Vec<DeviceToHost> {
    let mut buffer = [0u8; 4096];
    let n = match port.read(&mut buffer) {
        Ok(n) => n,
        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
        // The mock closed the terminal: it ran its duration (the caller checks that it exited cleanly).
        // (EIO, 5, from a pseudo-terminal whose other side is closed.)
        Err(e) if e.raw_os_error() == Some(5) || e.kind() == std::io::ErrorKind::BrokenPipe => 0,
        Err(e) => panic!("reading the mock: {e}"),
    };
    decoder.feed(&buffer[..n]).filter_map(Result::ok).collect()
}

/// A wall at x = 10 mm facing -x: the mock's hand circles out to x = 20 mm, so the handle presses into it.
fn wall() -> SiPrimitive {
    SiPrimitive {
        kind: LocalKind::Plane,
        position_m: [0.01, 0.0, 0.0],
        direction: [-1.0, 0.0, 0.0],
        strength_n: 30.0,
    }
}

const LIMIT_N: f64 = 2.0;

#[test]
fn a_capable_mock_renders_local_models_and_ramps_out_when_the_host_goes_silent() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("device.csv");
    let log_arg = log.to_str().unwrap();
    let mut mock = Mock::start(&[
        "--pty",
        "--local-model",
        "--duration",
        "6",
        "--log",
        log_arg,
    ]);
    let mut port = serialport::new(&mock.path, 1_000_000)
        .timeout(Duration::from_millis(1))
        .open()
        .unwrap();
    let mut decoder = FrameDecoder::<DeviceToHost>::new();
    let mut host = HostSession::new();

    // Handshake: the HeartbeatReply after DeviceInfo carries the capability bit.
    port.write_all(&[0]).unwrap();
    send(&mut *port, &host.hello());
    send(
        &mut *port,
        &HostToDevice::Heartbeat(Heartbeat { counter: 77 }),
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut capable = None;
    while capable.is_none() {
        assert!(Instant::now() < deadline, "no HeartbeatReply from the mock");
        for message in receive(&mut *port, &mut decoder) {
            if let DeviceToHost::Heartbeat(reply) = message {
                capable = Some(reply.status.contains(StatusFlags::LOCAL_MODEL));
            }
        }
    }
    assert_eq!(capable, Some(true), "--local-model sets LOCAL_MODEL");
    send(
        &mut *port,
        &HostToDevice::Enable(Enable {
            watchdog_timeout_us: 50_000,
        }),
    );

    // Two seconds of models at about 1 kHz (the pacing does not matter: each model expires 5 ms after it
    // arrives), reading whatever comes back so that the terminal's buffer never fills.
    let params = LocalModelParams {
        sequence: 0,
        expiry_us: 5000,
        stiffness_n_per_m: 2000.0,
        damping_n_s_per_m: 1.0,
        force_limit_n: LIMIT_N,
        anchor_m: [0.01, 0.0, 0.0],
    };
    let mut local_states = 0;
    let until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < until {
        let model = host.local_model(&params, &[wall()]).unwrap();
        send(&mut *port, &model);
        for message in receive(&mut *port, &mut decoder) {
            if let DeviceToHost::LocalState(state) = message {
                assert!(
                    f64::from(state.peak_force_n) <= LIMIT_N * (1.0 + 1e-6),
                    "{state:?}"
                );
                local_states += 1;
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    // Silence: the device must ramp out by itself. Keep draining until the mock exits.
    let done = loop {
        if mock.has_exited() {
            break wait_for_done(&mut mock);
        }
        receive(&mut *port, &mut decoder);
        std::thread::sleep(Duration::from_millis(1));
    };
    assert!(done.starts_with("done:"), "{done}");
    assert!(local_states > 0, "no LocalState reached the host");

    let cycles = read_log(&log);
    assert!(!cycles.is_empty());
    // Never above the limit in force (the model's, capped by the device's maximum), in any mode.
    for c in &cycles {
        assert!(c.force_n <= c.limit_n * (1.0 + 1e-6) + 1e-9, "{c:?}");
    }
    // The local loop rendered the wall: full ramp, a real force, at the model's limit of 2 N or below.
    let local: Vec<&Cycle> = cycles.iter().filter(|c| c.mode == "local").collect();
    assert!(
        local.iter().any(|c| c.force_n > 0.1),
        "the handle never felt the wall"
    );
    assert!(local.iter().all(|c| (c.limit_n - LIMIT_N).abs() < 1e-9));
    // Expiry: once a model is 5 ms past its expiry the force is zero, whatever the cycle timing.
    for c in &local {
        if c.model_age_us >= c.expiry_us + 5000 {
            assert_eq!(c.force_n, 0.0, "{c:?}");
        }
    }
    // The silence was seen (the log runs on well past the last model), and it ended at zero force.
    let last_local = local.last().unwrap().t_us;
    let after: Vec<&Cycle> = cycles.iter().filter(|c| c.t_us > last_local).collect();
    assert!(!after.is_empty(), "the log stops at the last local cycle");
    assert!(
        after
            .iter()
            .all(|c| c.force_n == 0.0 && c.mode != "set_force"),
        "{:?}",
        after.first()
    );
}

#[test]
fn serve_drives_a_capable_mock_through_set_force() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("device.csv");
    let mut mock = Mock::start(&[
        "--pty",
        "--local-model",
        "--duration",
        "14",
        "--log",
        log.to_str().unwrap(),
    ]);
    let output = crate::util::serve_headless(&format!("mock:{}", mock.path))
        .args(["--duration", "10"])
        .output()
        .expect("run voxhap serve");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(output.status.success(), "{text}");
    let done = wait_for_done(&mut mock);
    assert!(done.starts_with("done:"), "{done}");
    let cycles = read_log(&log);
    // A host that does not send local models: the capable device is driven through SetForce only.
    assert!(
        cycles.iter().all(|c| c.mode != "local"),
        "a local cycle without a local model"
    );
    assert!(
        cycles.iter().any(|c| c.mode == "set_force"),
        "serve never enabled the device: {text}"
    );
    assert!(cycles
        .iter()
        .all(|c| c.force_n <= c.limit_n * (1.0 + 1e-6) + 1e-9));
}
