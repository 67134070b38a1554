//! The serial protocol driver against `voxhap mock-device` over real pseudo-terminals (a separate process):
//! handshake, a clean 1 kHz exchange, corruption, the device watchdog, and disconnect/reconnect.

use crate::util::mock_process::MockProcess as Mock;
use glam::DVec3;
use std::time::{Duration, Instant};
use voxhap::device::drivers::protocol::{ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{
    LossReason, Supervisor, SupervisorConfig, SupervisorEvent, TickClock, TickInput,
};
use voxhap::device::transport::SerialTransport;
use voxhap::device::{HapticDevice, Lifecycle};
use voxhap_protocol::{FaultCode, HostEvent, StatusFlags};

fn open(
    path: &str,
    config: ProtocolConfig,
) -> Lifecycle<ProtocolDevice<SerialLink<SerialTransport>>> {
    let transport = SerialTransport::open(path, 1_000_000).unwrap();
    let mut device = Lifecycle::new(ProtocolDevice::new(SerialLink::new(transport), config));
    device.open().unwrap();
    device
}

/// Sleeps until `deadline` (the pacing of a 1 kHz loop).
fn wait_until(deadline: Instant) {
    let now = Instant::now();
    if deadline > now {
        std::thread::sleep(deadline - now);
    }
}

#[test]
fn handshake_reports_the_mock_device_info() {
    let mock = Mock::start(&["--pty"]);
    let mut device = open(&mock.path, ProtocolConfig::default());
    let info = device.info().clone();
    assert_eq!(info.model, "voxhap-mock");
    assert_eq!(info.serial_number, "sim-0001");
    assert_eq!((info.position_dof, info.force_dof), (3, 3));
    assert!((info.max_force_n - 5.0).abs() < 1e-6);
    assert!(info.state_rates_hz.contains(&1000));
    device.close().unwrap();
}

#[test]
fn clean_link_at_1_khz_loses_no_frames() {
    let mock = Mock::start(&["--pty"]);
    // Patience far beyond any scheduling delay, so that on a loaded machine the host never sends a second
    // Hello, a second first zero force or gives up on a State (each would add or move frames); the device's
    // own watchdog at its longest, 1 s. A host stalled longer than that still trips it, and the device then
    // sends one Fault frame: counted below, not a lost or extra frame.
    // (The update keeps this compiling, with defaults, if the driver gains settings.)
    #[allow(clippy::needless_update)]
    let config = ProtocolConfig {
        hello_timeout: Duration::from_secs(60),
        connect_timeout: Duration::from_secs(60),
        state_timeout: Duration::from_secs(60),
        device_watchdog_us: 1_000_000,
        ..ProtocolConfig::default()
    };
    let mut device = open(&mock.path, config);
    device.enable().unwrap();
    let start = Instant::now();
    let ticks = 2_500;
    let mut previous_time_us = 0;
    for tick in 1..=ticks {
        wait_until(start + Duration::from_micros(tick * 1_000));
        device.write_force(DVec3::new(0.1, 0.0, 0.0)).unwrap();
        let state = device.read_state().unwrap();
        let time_us = state.device_time_us.unwrap();
        assert!(time_us >= previous_time_us, "device time went back");
        previous_time_us = time_us;
    }
    let driver = device.device();
    let stats = driver.decoder_stats();
    let counters = driver.counters();
    assert_eq!(stats.dropped(), 0, "{stats:?}");
    assert_eq!(counters.hellos, 1, "{counters:?}");
    assert_eq!(counters.states_lost, 0, "{counters:?}");
    assert_eq!(counters.late_states, 0, "{counters:?}");
    assert_eq!(counters.timeouts, 0, "{counters:?}");
    assert_eq!(counters.rejections, 0, "{counters:?}");
    if counters.faults > 0 {
        let fault = driver.last_fault().unwrap();
        assert_eq!(
            fault.code,
            FaultCode::WATCHDOG_EXPIRED,
            "the only fault a clean link may see is a host stalled past the device watchdog"
        );
    }
    // What the device sent (protocol/SPEC.md): DeviceInfo and a HeartbeatReply for the Hello, one State
    // answering each SetForce (the open's zero force and one per tick), and one Fault per watchdog trip.
    assert_eq!(
        stats.frames_ok,
        ticks + 3 + counters.faults,
        "one state per force, plus info, the handshake's heartbeat reply, the open state and {} watchdog faults",
        counters.faults
    );
    device.close().unwrap();
}

#[test]
fn corrupted_link_counts_crc_errors_and_recovers() {
    let mock = Mock::start(&["--pty", "--corrupt-rate", "0.002", "--seed", "42"]);
    let config = ProtocolConfig {
        state_timeout: Duration::from_millis(20),
        ..ProtocolConfig::default()
    };
    // The handshake itself may be hit: retry it a few times, as a host would.
    let mut device = None;
    for _ in 0..5 {
        let transport = SerialTransport::open(&mock.path, 1_000_000).unwrap();
        let mut candidate = Lifecycle::new(ProtocolDevice::new(SerialLink::new(transport), config));
        if candidate.open().is_ok() {
            device = Some(candidate);
            break;
        }
    }
    let mut device = device.expect("handshake never got through a 0.2 % corrupted link");
    device.enable().unwrap();
    // Until 800 exchanges succeeded (20 000 attempts at most): a busy machine adds timeouts and watchdog
    // trips to the corruption's failures, so the test counts successes instead of a success rate.
    let mut ok = 0;
    let mut ok_after_error = false;
    let mut had_error = false;
    for _ in 0..20_000 {
        if ok >= 800 && ok_after_error {
            break;
        }
        if device
            .write_force(DVec3::ZERO)
            .and_then(|()| device.read_state())
            .is_ok()
        {
            ok += 1;
            ok_after_error |= had_error;
        } else {
            had_error = true;
        }
    }
    let stats = device.device().decoder_stats();
    assert!(
        stats.crc_errors + stats.cobs_errors > 0,
        "no corruption seen: {stats:?}"
    );
    assert!(
        had_error && ok_after_error,
        "the link never failed, or never recovered"
    );
    assert!(
        ok >= 800,
        "only {ok} exchanges succeeded in 20 000; {stats:?}"
    );
    device.mark_lost();
}

/// Enables `device` and exchanges forces until the State answering the last one says the device is still
/// enabled (a host descheduled for longer than the device watchdog trips it, which is right: enable again);
/// returns that State's device time, µs (the time the device took the last force, which restarts its watchdog).
fn exchange_until_enabled<L: voxhap::device::drivers::protocol::MessageLink>(
    device: &mut ProtocolDevice<L>,
    exchanges: usize,
) -> u64 {
    for _ in 0..100 {
        device.enable().unwrap();
        let mut last = None;
        for _ in 0..exchanges {
            device.write_force(DVec3::new(0.5, 0.0, 0.0)).unwrap();
            last = Some(device.read_state().unwrap());
        }
        let last = last.unwrap();
        if last.status.is_some_and(|s| s.enabled) {
            return last.device_time_us.unwrap();
        }
    }
    panic!("the device never stayed enabled through {exchanges} exchanges in 100 tries");
}

/// The device side of the watchdog, end to end over a real pseudo-terminal: when the host stops sending, the
/// mock trips its watchdog, and not before the timeout has passed since the last force it took (device clock).
/// How promptly it trips is a property of the device session under a given clock, tested with virtual time
/// (protocol/tests/protocol/sessions.rs); here the mock process may be descheduled, so no upper bound.
#[test]
fn device_drops_to_zero_force_within_its_watchdog_when_the_host_stops() {
    // The mock exits after 120 s, so a watchdog that never trips ends the test instead of hanging it.
    let mut mock = Mock::start(&["--pty", "--duration", "120"]);
    let watchdog_us = 20_000;
    let config = ProtocolConfig {
        device_watchdog_us: watchdog_us,
        // A late answer on a loaded machine is not what this test is about: wait for it.
        state_timeout: Duration::from_secs(60),
        ..ProtocolConfig::default()
    };
    let transport = SerialTransport::open(&mock.path, 1_000_000).unwrap();
    let mut device = ProtocolDevice::new(SerialLink::new(transport), config);
    device.open().unwrap();
    let last_force_us = exchange_until_enabled(&mut device, 100);
    // The host stops sending (the link stays open): nothing more goes out, not even the zero force of a
    // clean disable.
    // Trips during the exchanges above (a stalled host) were reported before the last force; skip them.
    let tripped_us = loop {
        let line = mock.next_line();
        let seconds: f64 = line
            .strip_prefix("watchdog tripped at ")
            .and_then(|rest| rest.strip_suffix(" s"))
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("mock said {line:?}, not a watchdog trip"));
        // Printed in whole milliseconds: within 500 µs of the device time.
        let tripped_us = seconds * 1e6;
        if tripped_us + 500.0 >= last_force_us as f64 {
            break tripped_us;
        }
    };
    assert!(
        tripped_us + 500.0 > (last_force_us + u64::from(watchdog_us)) as f64,
        "the watchdog tripped at {tripped_us} us, less than {watchdog_us} us after the last force at {last_force_us} us"
    );
}

#[test]
fn watchdog_fault_reaches_the_host_and_the_device_stays_disabled() {
    let mock = Mock::start(&["--pty"]);
    let watchdog_us = 10_000;
    let config = ProtocolConfig {
        device_watchdog_us: watchdog_us,
        // A late answer on a loaded machine is not what this test is about: wait for it.
        state_timeout: Duration::from_secs(60),
        ..ProtocolConfig::default()
    };
    let transport = SerialTransport::open(&mock.path, 1_000_000).unwrap();
    let mut device = ProtocolDevice::new(SerialLink::new(transport), config);
    device.open().unwrap();
    let last_force_us = exchange_until_enabled(&mut device, 20);
    // The host stops sending; the Fault must come (a generous deadline only guards against a hang).
    let stopped = Instant::now();
    let fault = loop {
        assert!(
            stopped.elapsed() < Duration::from_secs(60),
            "no fault message within 60 s"
        );
        if let Some(HostEvent::Fault(fault)) = device.poll_event(Duration::from_millis(50)).unwrap()
        {
            break fault;
        }
    };
    assert_eq!(fault.code, FaultCode::WATCHDOG_EXPIRED);
    assert!(
        fault.device_time_us > last_force_us + u64::from(watchdog_us),
        "the fault at device time {} us came less than {watchdog_us} us after the last force at {last_force_us} us",
        fault.device_time_us
    );
    let reply = device.heartbeat(Duration::from_secs(60)).unwrap();
    assert!(reply.status.contains(StatusFlags::WATCHDOG_TRIPPED));
    assert!(
        !reply.status.contains(StatusFlags::ENABLED),
        "device still enabled: {:?}",
        reply.status
    );
}

/// The mock hangs up 0.6 s after it started (its clock) and serves again 0.4 s later: the host reports the
/// hang-up, sends no force while the link is down, reconnects, and runs on the device that came back. What
/// holds whatever the scheduling: the one hang-up is reported as one, every State after the reconnection was
/// sent after the mock came back (device time at least 1.0 s), and losses the host declares itself on a loaded
/// machine (a mock descheduled past the link-health bound) are timeouts it recovers from.
#[test]
fn host_reports_a_disconnect_outputs_zero_and_reconnects() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("arm");
    let link_text = link.to_str().unwrap().to_string();
    let _mock = Mock::start(&[
        "--port",
        &link_text,
        "--disconnect-after",
        "0.6",
        "--reconnect-after",
        "0.4",
    ]);
    let back_us = 1_000_000; // device time when the mock serves again
    let protocol = ProtocolConfig {
        state_timeout: Duration::from_millis(20),
        ..ProtocolConfig::default()
    };
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 50_000,
            ..SafetyConfig::default()
        },
        reconnect_interval_us: 50_000,
        max_consecutive_errors: 10,
        ..SupervisorConfig::default()
    };
    let mut supervisor = Supervisor::new(config, || {
        let transport = SerialTransport::open(&link_text, 1_000_000)?;
        Ok(ProtocolDevice::new(SerialLink::new(transport), protocol))
    })
    .unwrap();
    let start = Instant::now();
    let mut hang_ups = 0;
    let mut other_losses = 0;
    let mut connects = 0;
    let mut link_down = false;
    // After the hang-up: reconnected, and good ticks since.
    let mut reconnected = false;
    let mut ticks_after_reconnect = 0;
    let mut tick = 0u64;
    while ticks_after_reconnect < 200 {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no 200 good ticks after a reconnection within 120 s: {hang_ups} hang-ups, {connects} connects"
        );
        tick += 1;
        wait_until(start + Duration::from_micros(tick * 1_000));
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap();
        let out = supervisor.tick(TickInput {
            clock: TickClock::Monotonic,
            ..TickInput::at(DVec3::new(0.2, 0.0, 0.0), now_us)
        });
        // The tick that notices a loss sent its force before noticing; from the next one on, nothing.
        if link_down {
            assert_eq!(
                out.sent_force_n,
                DVec3::ZERO,
                "force sent while disconnected"
            );
        }
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Connected => {
                    connects += 1;
                    link_down = false;
                    reconnected = hang_ups > 0;
                }
                SupervisorEvent::Disconnected { kind, reason } => {
                    link_down = true;
                    reconnected = false;
                    if reason == LossReason::HungUp {
                        assert_eq!(kind, voxhap::device::ErrorKind::Disconnected);
                        hang_ups += 1;
                    } else {
                        assert_eq!(
                            kind,
                            voxhap::device::ErrorKind::Timeout,
                            "a loss other than the hang-up: {reason:?}"
                        );
                        other_losses += 1;
                    }
                }
                _ => {}
            }
        }
        if let Some(state) = out
            .state
            .filter(|_| reconnected && !out.stale && out.connected)
        {
            let device_time_us = state.device_time_us.unwrap();
            assert!(
                device_time_us >= back_us,
                "a state from device time {device_time_us} us after the reconnection: the mock served again at {back_us} us"
            );
            ticks_after_reconnect += 1;
        }
    }
    assert_eq!(hang_ups, 1, "the mock hung up once");
    assert_eq!(
        connects,
        1 + hang_ups + other_losses,
        "every loss is followed by one reconnection"
    );
    assert_eq!(supervisor.counters().disconnects, hang_ups + other_losses);
}

/// The mock stops answering 0.3 s after it started and stays mute: the host declares the link lost (a
/// timeout), sends no force while it is down, and its reopen attempts fail. On a loaded machine the mock can
/// be descheduled for longer than the link-health bound while it still answers, and then the host rightly
/// drops the link and reconnects; what must hold is that the loss it never recovers from is a timeout and
/// that no force goes out while the link is down.
#[test]
fn a_mute_device_is_declared_lost_after_repeated_timeouts() {
    let mock = Mock::start(&["--pty", "--stop-after", "0.3"]);
    let path = mock.path.clone();
    let protocol = ProtocolConfig {
        state_timeout: Duration::from_micros(500),
        hello_timeout: Duration::from_millis(50),
        ..ProtocolConfig::default()
    };
    let config = SupervisorConfig {
        reconnect_interval_us: 100_000,
        ..SupervisorConfig::default()
    };
    let mut supervisor = Supervisor::new(config, || {
        let transport = SerialTransport::open(&path, 1_000_000)?;
        Ok(ProtocolDevice::new(SerialLink::new(transport), protocol))
    })
    .unwrap();
    let start = Instant::now();
    let mut losses = 0;
    let mut link_down = false;
    // Reopen attempts that failed since the link was last up.
    let mut failed_reconnects = 0;
    let mut tick = 0u64;
    while failed_reconnects < 2 {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the mute device was not given up on within 120 s: {losses} losses, {failed_reconnects} failed reopens"
        );
        tick += 1;
        wait_until(start + Duration::from_micros(tick * 1_000));
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap();
        let out = supervisor.tick(TickInput {
            clock: TickClock::Monotonic,
            ..TickInput::at(DVec3::new(0.2, 0.0, 0.0), now_us)
        });
        if link_down {
            assert_eq!(
                out.sent_force_n,
                DVec3::ZERO,
                "force sent while the link was down"
            );
        }
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Disconnected { kind, .. } => {
                    assert_eq!(kind, voxhap::device::ErrorKind::Timeout);
                    losses += 1;
                    link_down = true;
                }
                SupervisorEvent::Connected => {
                    link_down = false;
                    failed_reconnects = 0;
                }
                SupervisorEvent::ReconnectFailed(_) => failed_reconnects += 1,
                _ => {}
            }
        }
    }
    assert!(losses >= 1, "a mute device was never declared lost");
    assert!(
        link_down,
        "the link is up again although the device is mute"
    );
}

/// Runs `voxhap serve` on the mock device at `path` for `seconds`; returns its stdout and stderr.
fn serve_on(path: &str, seconds: &str) -> (bool, String) {
    let output = crate::util::serve_headless(&format!("mock:{path}"))
        .args(["--duration", seconds])
        .output()
        .expect("run voxhap serve");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    (output.status.success(), text)
}

/// The number after `label ` in the exit summary (`ticks 2999`, `skipped 4 ticks`).
fn summary_number(text: &str, label: &str) -> u64 {
    let at = text
        .find(label)
        .unwrap_or_else(|| panic!("no {label:?} in {text}"));
    text[at + label.len()..]
        .split(|c: char| !c.is_ascii_digit())
        .find(|s| !s.is_empty())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no number after {label:?} in {text}"))
}

/// Regression: replies 5 ms late must not make connect fail (with a misleading "permissions?" message). The
/// handshake waits 100 ms per Hello and the servo reads pipelined states, so the session runs and engages.
#[test]
fn a_device_answering_5_ms_late_connects_and_engages() {
    let mock = Mock::start(&["--pty", "--latency-ms", "5"]);
    // Long enough to engage on a loaded machine; a link the host drops there (a descheduled mock) is enabled
    // again, so at least one enable is what must hold.
    let (ok, text) = serve_on(&mock.path, "10");
    assert!(ok, "{text}");
    assert!(summary_number(&text, "enables ") >= 1, "{text}");
    assert!(!text.contains("permission"), "{text}");
}

/// Regression: with 1 % of the bytes corrupted, a device read that waits too long skips most ticks (73 % when
/// this test was written). Device I/O waits at most half a period, so ticks keep their rate; the safety rules keep the force at zero or hold.
/// The servo's own device wiring (`open_device` for a 1 kHz loop, as `serve` uses it) on a link that corrupts
/// 1 % of the bytes: every lost State is one failed exchange, after which the exchanges go on with States, and
/// the output gets enabled. Counted, not timed: the loop runs until 2 000 exchanges brought a State after the
/// first failed one (60 000 exchanges at most), so a starved machine only makes it take longer. (The wait per
/// lost State, half a period, is the driver's `ProtocolConfig::for_period`; the tick rate it keeps is measured
/// by `voxhap bench-loop`, not asserted here.)
#[test]
fn a_lossy_link_keeps_the_servo_exchanging() {
    let mock = Mock::start(&["--pty", "--corrupt-rate", "0.01", "--seed", "7"]);
    let mut device = mock.open_connected();
    let start = Instant::now();
    let (mut with_state_after_failure, mut exchanges) = (0u64, 0u64);
    let mut failed = false;
    while with_state_after_failure < 2_000 && exchanges < 60_000 {
        exchanges += 1;
        wait_until(start + Duration::from_micros(exchanges * 1_000));
        let out = device.exchange(TickInput::at(DVec3::ZERO, exchanges * 1_000));
        let counters = device.counters();
        failed |= counters.errors + counters.timeouts > 0;
        if failed && out.connected && out.state.is_some() {
            with_state_after_failure += 1;
        }
    }
    let counters = device.counters();
    device.stop();
    assert!(
        counters.errors >= 1,
        "the corruption never cost an exchange: {counters:?}"
    );
    assert_eq!(
        with_state_after_failure, 2_000,
        "{exchanges} exchanges: {counters:?}"
    );
    assert!(counters.enables >= 1, "{counters:?}");
}

/// The reconnecting wrapper the servo thread holds for every real device (connector thread, stop channel,
/// supervisor, protocol driver over a real pseudo-terminal) allocates nothing per exchange once connected and
/// enabled.
#[test]
fn the_reconnecting_wrapper_exchange_does_not_allocate() {
    let mock = Mock::start(&["--pty"]);
    let mut device = mock.open_connected();
    let start = Instant::now();
    let mut tick = 0u64;
    let mut exchange = |device: &mut Box<dyn voxhap::servo::device::ServoDevice>| {
        tick += 1;
        wait_until(start + Duration::from_micros(tick * 1_000));
        device.exchange(TickInput::at(DVec3::new(0.05, 0.0, 0.0), tick * 1_000))
    };
    // Enabled after 50 steady ticks; engaged once the force is small.
    for _ in 0..200 {
        exchange(&mut device);
    }
    assert!(device.counters().enables >= 1, "{:?}", device.counters());
    // Until 2 000 exchanges were connected (20 000 at most): on a busy machine the link may drop and be
    // reopened, which costs exchanges but never an allocation on this thread.
    let mut connected = 0;
    let mut exchanges = 0;
    let allocations = crate::util::count_allocations(|| {
        while connected < 2_000 && exchanges < 20_000 {
            exchanges += 1;
            if exchange(&mut device).connected {
                connected += 1;
            }
        }
    });
    device.stop();
    assert_eq!(allocations, 0);
    assert!(
        connected >= 2_000,
        "{connected} of {exchanges} exchanges connected"
    );
}

/// The protocol handshake has one overall deadline: a device whose every answer comes 1.5 s late needs 3 s for
/// DeviceInfo and then its first State, so with a 2 s connect timeout open fails (a handshake and a first
/// State that each had the whole timeout let it connect at about 3 s). Whatever the machine's load, the
/// answer cannot come sooner; the error comes by the deadline (a generous margin for a busy machine).
#[test]
fn the_protocol_handshake_has_one_overall_deadline() {
    let mock = Mock::start(&["--pty", "--latency-ms", "1500"]);
    let config = ProtocolConfig {
        connect_timeout: Duration::from_secs(2),
        ..ProtocolConfig::default()
    };
    let transport = SerialTransport::open(&mock.path, 1_000_000).unwrap();
    let mut device = Lifecycle::new(ProtocolDevice::new(SerialLink::new(transport), config));
    let started = Instant::now();
    let result = device.open();
    let took = started.elapsed();
    assert!(
        result.is_err(),
        "open outlived its 2 s deadline and connected after {took:?}"
    );
    assert!(took < Duration::from_secs(12), "{took:?}");
}
