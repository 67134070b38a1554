//! End to end: `voxhap serve` drives `voxhap mock-device` over a real pseudo-terminal for a few seconds,
//! recording, is stopped with SIGTERM, and the trace it leaves is checked.

use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use voxhap::record::{read_trace, FLAG_FORCE_LIMITED_BY_SAFETY};

#[test]
fn serve_against_the_mock_device_records_a_clean_trace_and_stops_on_sigterm() {
    let dir = tempfile::tempdir().unwrap();
    let trace_path = dir.path().join("serve.csv");
    let mut mock = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(["mock-device", "--pty"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start voxhap mock-device");
    let mut mock_out = BufReader::new(mock.stdout.take().unwrap());
    let mut line = String::new();
    mock_out.read_line(&mut line).unwrap();
    let pty = line.trim().strip_prefix("serving ").unwrap().to_owned();

    let mut serve = crate::util::serve_headless(&format!("mock:{pty}"))
        .arg("--record")
        .arg(&trace_path)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start voxhap serve");
    let mut serve_out = BufReader::new(serve.stdout.take().unwrap());
    let mut first = String::new();
    serve_out.read_line(&mut first).unwrap();
    assert!(
        first.starts_with("serving: device mock:"),
        "serve said {first:?}"
    );

    // Run until the trace on disk holds FREE_TICKS ticks whose force no safety limit touched (engaged and
    // rendering freely), at least 3 s: on a busy machine overruns and host-watchdog restarts of the engage
    // rule can take longer, so the test waits for what it checks instead of a fixed time (60 s at most).
    const FREE_TICKS: usize = 1000;
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(3)
        || (free_ticks_on_disk(&trace_path) < FREE_TICKS
            && started.elapsed() < Duration::from_secs(60))
    {
        std::thread::sleep(Duration::from_millis(100));
    }
    let started = Instant::now();
    // SAFETY: plain kill(2) on our own child's pid.
    let sent = unsafe { libc::kill(serve.id() as libc::pid_t, libc::SIGTERM) };
    assert_eq!(sent, 0);
    let status = loop {
        if let Some(status) = serve.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "serve did not stop on SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut rest = String::new();
    serve_out.read_to_string(&mut rest).unwrap();
    let mut errors = String::new();
    serve
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut errors)
        .unwrap();
    let _ = mock.kill();
    let _ = mock.wait();
    assert!(
        status.success(),
        "exit {status:?}\nstdout: {rest}\nstderr: {errors}"
    );
    assert!(
        rest.contains("stopped (SIGTERM): force zeroed, device closed"),
        "{rest}"
    );
    assert!(
        rest.contains("lateness"),
        "statistics printed on exit: {rest}"
    );

    let trace = read_trace(&trace_path).unwrap();
    assert!(trace.sidecar.is_some(), "sidecar written");
    let samples = &trace.samples;
    assert!(samples.len() >= FREE_TICKS, "{} samples", samples.len());
    assert!(samples
        .windows(2)
        .all(|w| w[0].tick < w[1].tick && w[0].t_s < w[1].t_s));
    let mut max_force: f64 = 0.0;
    for sample in samples {
        assert!(
            sample.sent_force_n.is_finite() && sample.probe_m.is_finite(),
            "tick {}",
            sample.tick
        );
        assert!(
            sample.sent_force_n.length() <= 5.0 + 1e-9,
            "over the mock's 5 N limit at tick {}",
            sample.tick
        );
        max_force = max_force.max(sample.sent_force_n.length());
    }
    // The mock's hand circles 2 cm from the centre, inside the built-in ball (3 cm): the surface pushes.
    assert!(
        max_force > 0.2,
        "max force {max_force} N: the device never felt the surface"
    );
    // Forces ramp in at the start (safety pipeline), then flow freely.
    assert!(samples[0].flags & FLAG_FORCE_LIMITED_BY_SAFETY != 0);
    let free = samples
        .iter()
        .filter(|s| s.flags & FLAG_FORCE_LIMITED_BY_SAFETY == 0)
        .count();
    assert!(
        free >= FREE_TICKS,
        "{free} of {} ticks free of safety limits after {:?}",
        samples.len(),
        started.elapsed()
    );
    let travelled = samples
        .windows(2)
        .map(|w| (w[1].probe_m - w[0].probe_m).length())
        .sum::<f64>();
    assert!(travelled > 0.01, "the probe moved {travelled} m");
}

#[test]
fn a_session_survives_a_device_disconnect_and_reconnects_off_the_servo_thread() {
    use voxhap::servo::device::DeviceSpec;
    use voxhap::servo::setup::SceneSetup;
    use voxhap::servo::{Session, SessionApi, SessionConfig};

    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("mock-tty");
    let trace_path = dir.path().join("reconnect.csv");
    let mut mock = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "mock-device",
            "--disconnect-after",
            "1.0",
            "--reconnect-after",
            "0.5",
            "--port",
        ])
        .arg(&link)
        .stdout(Stdio::piped())
        .spawn()
        .expect("start voxhap mock-device");
    let mut mock_out = BufReader::new(mock.stdout.take().unwrap());
    let mut line = String::new();
    mock_out.read_line(&mut line).unwrap();
    assert!(line.starts_with("serving "), "mock said {line:?}");

    let mut config = SessionConfig::new(
        DeviceSpec::Mock(link.clone()),
        SceneSetup::builtin().unwrap(),
    );
    config.rt = voxhap::servo::rt::RtMode::Off;
    config.record = Some((trace_path.clone(), voxhap::record::TraceFormat::Csv));
    let session = Session::start(config).unwrap();
    let api = session.api();
    let started = Instant::now();
    let mut saw_disconnected = false;
    let mut reconnected = false;
    let mut first_disconnected_tick = None;
    while started.elapsed() < Duration::from_secs(8) {
        if let Some(snapshot) = api.snapshot() {
            if !snapshot.connected {
                saw_disconnected = true;
                // The tick that found the link dead had already written its force; every later one is zero.
                let first = *first_disconnected_tick.get_or_insert(snapshot.tick);
                if snapshot.tick > first {
                    assert_eq!(
                        snapshot.sent_force_n,
                        glam::DVec3::ZERO,
                        "force sent while disconnected"
                    );
                }
            } else if saw_disconnected {
                reconnected = true;
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    // Let it run connected for a moment, then stop.
    std::thread::sleep(Duration::from_millis(300));
    let summary = session.stop();
    let _ = mock.kill();
    let _ = mock.wait();
    assert!(
        saw_disconnected,
        "the session never reported the disconnect"
    );
    assert!(
        reconnected,
        "the session did not reconnect when the mock came back"
    );
    assert!(summary.stats.disconnects >= 1);
    let trace = read_trace(&trace_path).unwrap();
    let last = trace.samples.last().unwrap();
    assert!(last.flags & FLAG_FORCE_LIMITED_BY_SAFETY == 0 || last.sent_force_n.length() < 5.0);
    // The servo kept its schedule while the connector thread reopened the port: the ticks did not stop.
    let gap = trace
        .samples
        .windows(2)
        .map(|w| w[1].tick - w[0].tick)
        .max()
        .unwrap();
    assert!(
        gap < 100,
        "the servo stalled for {gap} ticks during the reconnect"
    );
}

/// Ticks in the CSV trace at `path` (whole lines written so far) whose `flag_bits` lack
/// [`FLAG_FORCE_LIMITED_BY_SAFETY`]; 0 while the file or its header is not there yet.
fn free_ticks_on_disk(path: &std::path::Path) -> usize {
    let Ok(text) = std::fs::read_to_string(path) else {
        return 0;
    };
    let mut lines = text
        .split_inclusive('\n')
        .filter(|line| line.ends_with('\n'));
    let Some(column) = lines
        .next()
        .and_then(|header| header.trim_end().split(',').position(|c| c == "flag_bits"))
    else {
        return 0;
    };
    lines
        .filter_map(|line| line.trim_end().split(',').nth(column)?.parse::<u32>().ok())
        .filter(|bits| bits & FLAG_FORCE_LIMITED_BY_SAFETY == 0)
        .count()
}
