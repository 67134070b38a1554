//! Connecting to a slow device: `voxhap serve --device serial:PTY` against the SPEC device double
//! (tests/util/spec_device.rs) when its DeviceInfo comes late, and against a port where nothing answers.
//!
//! Regression tests for two defects: a first connect that took longer than the servo's per-tick budget (500 µs
//! for the State after DeviceInfo) was fatal to `serve`, and a reconnect could not succeed while a round trip took
//! more than about 0.5 s (each reopen discarded the late DeviceInfo, or took a stale one for a fresh one).
//! What is checked is what the device received (every SetForce, Hello, Heartbeat and Enable is logged there), and
//! what `serve` said and how long it took to give up. `serve` runs one at a time with the other device tests
//! (`take_turn`); waits end as soon as their condition holds, up to [`PATIENCE`].

use crate::util::pty::PtyDevice;
use crate::util::spec_device::{HostMessage, SpecDeviceConfig, SpecDeviceHandle};
use crate::util::spec_serve::{
    assert_force_invariants, assert_force_invariants_across_a_reset, assert_slew_limited,
    enable_after, enabled_again_after_trigger, run_until, summary, take_turn, tapping_until, Serve,
    FLOWING, INSIDE_X_M, PATIENCE,
};
use std::process::ExitStatus;
use std::time::{Duration, Instant};

/// The documented default of `--connect-timeout` (docs/serve.md, docs/safety.md).
const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// Runs `serve` on the ball scene (no damping) against a device with `config` until `done` holds, then SIGTERM;
/// returns the device (stopped), serve's status and output (device_spec's `run_until`).
fn serve_until(
    config: SpecDeviceConfig,
    what: &str,
    done: impl Fn(&SpecDeviceHandle) -> bool,
) -> (SpecDeviceHandle, ExitStatus, String) {
    run_until(config, 0.0, what, done)
}

/// Enabled, and `forces` SetForce after the first Enable.
fn enabled_then(forces: usize) -> impl Fn(&SpecDeviceHandle) -> bool {
    move |device| {
        enable_after(device, 0)
            .is_some_and(|enable| device.force_count_after_index(enable.index) >= forces)
    }
}

/// From the device's side: no SetForce with a non-zero force arrived before the host enabled the session (the
/// first Enable), nor between the Hello at or after `from_index` and the Enable that followed it.
fn assert_zero_until_enabled(device: &SpecDeviceHandle, from_index: u64) {
    let messages = device.messages();
    let hello = messages
        .iter()
        .find(|m| m.index >= from_index && matches!(m.message, HostMessage::Hello { .. }))
        .unwrap_or_else(|| panic!("no Hello after event {from_index}: {messages:?}"));
    let enable = enable_after(device, hello.index)
        .unwrap_or_else(|| panic!("no Enable after the Hello at event {}", hello.index));
    let early: Vec<_> = device
        .forces()
        .into_iter()
        .filter(|f| f.index > hello.index && f.index < enable.index && !f.is_zero())
        .collect();
    assert!(
        early.is_empty(),
        "{} non-zero SetForce between Hello and Enable (first {:?}); {}",
        early.len(),
        early.first(),
        summary(&device.forces())
    );
}

/// Serve connects to a device whose DeviceInfo comes `delay` after each Hello, enables it, and commands no force
/// before that; the wait between the first Hello and the first SetForce shows the delay was really there.
fn first_connect_with_device_info_late_by(delay: Duration) {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        device_info_delay: delay,
        ..SpecDeviceConfig::default()
    };
    let (device, status, output) = serve_until(
        config,
        "an Enable and 50 SetForce after it",
        enabled_then(50),
    );
    assert!(status.success(), "serve failed: {output}");
    let messages = device.messages();
    let first_hello = messages
        .iter()
        .find(|m| matches!(m.message, HostMessage::Hello { .. }))
        .expect("no Hello");
    let first_force = device.forces().first().copied().expect("no SetForce");
    assert!(
        first_force.at >= first_hello.at + delay,
        "the first SetForce came {:?} after the first Hello, before the DeviceInfo was due ({delay:?})",
        first_force.at - first_hello.at
    );
    assert_zero_until_enabled(&device, 0);
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn first_connect_waits_for_a_device_info_50_ms_late() {
    first_connect_with_device_info_late_by(Duration::from_millis(50));
}

#[test]
fn first_connect_waits_for_a_device_info_1_s_late() {
    first_connect_with_device_info_late_by(Duration::from_secs(1));
}

/// The device resets while force flows (the link is lost: its session is closed) and from then on answers Hello
/// 1 s late: the connector must still reconnect, and command nothing but zero until it has enabled the device.
#[test]
fn a_reconnect_waits_for_a_device_info_1_s_late() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        reset: Some(FLOWING),
        device_info_delay: Duration::from_secs(1),
        device_info_delay_from: Some(FLOWING),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let (device, status, output) = serve_until(
        config,
        "a new Enable after the reset, and 50 SetForce after it",
        enabled_again_after_trigger(FLOWING, 50),
    );
    assert!(status.success(), "serve failed: {output}");
    let reset = device.fired(FLOWING).expect("the reset fired");
    let messages = device.messages();
    let hello = messages
        .iter()
        .find(|m| m.index > reset.index && matches!(m.message, HostMessage::Hello { .. }))
        .expect("no Hello after the reset");
    let enable = enable_after(&device, hello.index).expect("no Enable after the reset");
    assert!(
        enable.at >= hello.at + Duration::from_secs(1),
        "enabled {:?} after the first Hello following the reset, before its DeviceInfo was due",
        enable.at - hello.at
    );
    assert_zero_until_enabled(&device, hello.index);
    // The first session, before the reset, was enabled the ordinary way too.
    assert_zero_until_enabled(&device, 0);
    // And across both sessions: finite, never above the device's maximum, zero while not enabled but for what
    // was in flight when it reset, no rise faster than the slew limit.
    assert_force_invariants_across_a_reset(&device, &reset, 8.0);
    assert_slew_limited(&device);
}

/// A port that is there but silent (a pseudo-terminal nobody answers on): serve gives up after the documented
/// connect timeout, not at once and not never, with a message naming the port, what it sent and what to check.
#[test]
fn a_port_where_nothing_answers_fails_after_the_connect_timeout() {
    let _turn = take_turn();
    let silent = PtyDevice::new();
    let start = Instant::now();
    let serve = Serve::start_on(silent.path(), None, None, &[]);
    let (status, output) = serve.finish(DEFAULT_CONNECT_TIMEOUT + PATIENCE);
    let took = start.elapsed();
    assert_eq!(status.code(), Some(1), "serve did not fail: {output}");
    assert!(
        took >= DEFAULT_CONNECT_TIMEOUT,
        "serve gave up after {took:?}, before the {DEFAULT_CONNECT_TIMEOUT:?} connect timeout: {output}"
    );
    for expected in [
        silent.path(),
        "could not connect",
        "no DeviceInfo answering Hello within 3.0 s",
        "Hellos sent",
        "is powered, on this port",
        "--connect-timeout",
    ] {
        assert!(output.contains(expected), "no {expected:?} in: {output}");
    }
    // On an idle machine serve gives up right at the timeout; the bound leaves room for a loaded one.
    assert!(
        took < DEFAULT_CONNECT_TIMEOUT + Duration::from_secs(20),
        "serve took {took:?} to give up: {output}"
    );
}

/// `--connect-timeout` shortens the wait for a silent port, and a value out of range is refused naming the flag.
#[test]
fn connect_timeout_is_configurable_and_checked() {
    let _turn = take_turn();
    let silent = PtyDevice::new();
    let start = Instant::now();
    let serve = Serve::start_on(silent.path(), None, None, &["--connect-timeout", "0.5"]);
    let (status, output) = serve.finish(PATIENCE);
    let took = start.elapsed();
    assert_eq!(status.code(), Some(1), "serve did not fail: {output}");
    assert!(output.contains("within 0.5 s"), "{output}");
    assert!(
        took >= Duration::from_millis(500) && took < DEFAULT_CONNECT_TIMEOUT,
        "serve gave up after {took:?} with --connect-timeout 0.5: {output}"
    );
    for bad in ["0", "0.05", "601", "nan", "soon"] {
        let serve = Serve::start_on(silent.path(), None, None, &["--connect-timeout", bad]);
        let (status, output) = serve.finish(PATIENCE);
        assert_eq!(
            status.code(),
            Some(2),
            "--connect-timeout {bad} accepted: {output}"
        );
        assert!(output.contains("--connect-timeout"), "{output}");
    }
}

/// A port that does not exist fails at once (no retries for the connect timeout), naming the port.
#[test]
fn a_missing_port_fails_at_once() {
    let _turn = take_turn();
    let path = "/dev/voxhap-no-such-port";
    let start = Instant::now();
    let serve = Serve::start_on(path, None, None, &[]);
    let (status, output) = serve.finish(PATIENCE);
    assert_eq!(status.code(), Some(1), "serve did not fail: {output}");
    assert!(output.contains(path), "the port is not named: {output}");
    assert!(
        start.elapsed() < DEFAULT_CONNECT_TIMEOUT,
        "a missing port took {:?} to fail: {output}",
        start.elapsed()
    );
}
