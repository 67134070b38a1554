//! The serial protocol driver against `voxhap mock-device` over real pseudo-terminals (a separate process):
//! handshake, a clean 1 kHz exchange, corruption, the device watchdog, and disconnect/reconnect.

use crate::util::mock_process::MockProcess as Mock;
use glam::DVec3;
use std::process::Command;
use std::time::{Duration, Instant};
use voxhap::device::drivers::protocol::{ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, SupervisorEvent, TickInput};
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
    let config = ProtocolConfig {
        state_timeout: Duration::from_millis(100),
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
    assert_eq!(
        driver.decoder_stats().dropped(),
        0,
        "{:?}",
        driver.decoder_stats()
    );
    assert_eq!(
        driver.decoder_stats().frames_ok,
        ticks + 3,
        "one state per force, plus info, the handshake's heartbeat reply and the open state"
    );
    assert_eq!(driver.counters().states_lost, 0);
    assert_eq!(driver.counters().late_states, 0);
    assert_eq!(driver.counters().timeouts, 0);
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
    let mut ok = 0;
    let mut ok_after_error = false;
    let mut had_error = false;
    for _ in 0..1_000 {
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
    assert!(ok > 800, "only {ok} of 1000 exchanges succeeded; {stats:?}");
    device.mark_lost();
}

#[test]
fn device_drops_to_zero_force_within_its_watchdog_when_the_host_stops() {
    let mut mock = Mock::start(&["--pty"]);
    let watchdog_us = 20_000;
    let config = ProtocolConfig {
        device_watchdog_us: watchdog_us,
        // A late answer on a loaded machine is not what this test is about: wait for it.
        state_timeout: Duration::from_millis(100),
        ..ProtocolConfig::default()
    };
    let mut device = open(&mock.path, config);
    device.enable().unwrap();
    for _ in 0..100 {
        device.write_force(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        device.read_state().unwrap();
    }
    // The host stops sending. The mock must report its watchdog within the timeout plus one control period
    // (1 ms) plus scheduling slack.
    let stopped = Instant::now();
    device.mark_lost(); // nothing more is sent, not even the zero force of a clean disable
    let line = mock.next_line();
    let elapsed = stopped.elapsed();
    assert!(line.starts_with("watchdog tripped"), "mock said {line:?}");
    assert!(
        elapsed < Duration::from_micros(u64::from(watchdog_us)) + Duration::from_millis(80),
        "watchdog reported after {elapsed:?}"
    );
}

#[test]
fn watchdog_fault_reaches_the_host_and_the_device_stays_disabled() {
    let mock = Mock::start(&["--pty"]);
    let config = ProtocolConfig {
        device_watchdog_us: 10_000,
        // A late answer on a loaded machine is not what this test is about: wait for it.
        state_timeout: Duration::from_millis(100),
        ..ProtocolConfig::default()
    };
    let transport = SerialTransport::open(&mock.path, 1_000_000).unwrap();
    let mut device = ProtocolDevice::new(SerialLink::new(transport), config);
    device.open().unwrap();
    device.enable().unwrap();
    for _ in 0..20 {
        device.write_force(DVec3::new(0.5, 0.0, 0.0)).unwrap();
        device.read_state().unwrap();
    }
    let stopped = Instant::now();
    let fault = loop {
        assert!(
            stopped.elapsed() < Duration::from_millis(500),
            "no fault message"
        );
        if let Some(HostEvent::Fault(fault)) = device.poll_event(Duration::from_millis(50)).unwrap()
        {
            break fault;
        }
    };
    assert_eq!(fault.code, FaultCode::WATCHDOG_EXPIRED);
    assert!(
        stopped.elapsed() < Duration::from_millis(10 + 60),
        "fault after {:?}",
        stopped.elapsed()
    );
    let reply = device.heartbeat(Duration::from_millis(200)).unwrap();
    assert!(reply.status.contains(StatusFlags::WATCHDOG_TRIPPED));
    assert!(
        !reply.status.contains(StatusFlags::ENABLED),
        "device still enabled: {:?}",
        reply.status
    );
}

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
    let (mut disconnected_at, mut reconnected_at) = (None, None);
    let mut connects = 0;
    let mut ticks_after_reconnect = 0;
    let mut tick = 0u64;
    while start.elapsed() < Duration::from_secs(4) && ticks_after_reconnect < 200 {
        tick += 1;
        wait_until(start + Duration::from_micros(tick * 1_000));
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap();
        let out = supervisor.tick(TickInput::at(DVec3::new(0.2, 0.0, 0.0), now_us));
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Connected => {
                    connects += 1;
                    if disconnected_at.is_some() {
                        reconnected_at = Some(now_us);
                    }
                }
                SupervisorEvent::Disconnected { .. } => disconnected_at = Some(now_us),
                _ => {}
            }
        }
        // From the tick after the one that noticed the loss (whose force went out before it was noticed).
        if disconnected_at.is_some_and(|at| at < now_us) && reconnected_at.is_none() {
            assert_eq!(
                out.sent_force_n,
                DVec3::ZERO,
                "force sent while disconnected"
            );
            assert!(!out.connected || !out.events.is_empty());
        }
        if reconnected_at.is_some() && !out.stale {
            ticks_after_reconnect += 1;
        }
    }
    let disconnected_at = disconnected_at.expect("the host never noticed the disconnect");
    let reconnected_at = reconnected_at.expect("the host never reconnected");
    assert_eq!(connects, 2);
    assert!(
        disconnected_at > 500_000,
        "disconnect noticed too early: {disconnected_at} us"
    );
    assert!(
        reconnected_at - disconnected_at >= 300_000,
        "reconnected before the mock came back"
    );
    assert!(
        ticks_after_reconnect >= 200,
        "only {ticks_after_reconnect} good ticks after reconnecting"
    );
    assert_eq!(supervisor.counters().disconnects, 1);
}

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
    // The last loss: on a loaded machine the mock can be descheduled for longer than the link-health bound while
    // it still answers, and then the host rightly drops the link and reconnects; what must hold is that the loss
    // it never recovers from comes after the device went mute, and that no force goes out while the link is down.
    let mut lost_at = None;
    let mut link_down = false;
    let mut failed_reconnects = 0;
    let mut tick = 0u64;
    while start.elapsed() < Duration::from_secs(2) && failed_reconnects < 2 {
        tick += 1;
        wait_until(start + Duration::from_micros(tick * 1_000));
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap();
        let out = supervisor.tick(TickInput::at(DVec3::new(0.2, 0.0, 0.0), now_us));
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Disconnected { kind, .. } => {
                    assert_eq!(kind, voxhap::device::ErrorKind::Timeout);
                    lost_at = Some(now_us);
                    link_down = true;
                }
                SupervisorEvent::Connected => link_down = false,
                SupervisorEvent::ReconnectFailed(_) => failed_reconnects += 1,
                _ => {}
            }
        }
        if link_down {
            assert_eq!(out.sent_force_n, DVec3::ZERO);
        }
    }
    let lost_at = lost_at.expect("a mute device was never declared lost");
    assert!(
        lost_at >= 300_000,
        "last lost at {lost_at} us, before the device went mute"
    );
    assert!(
        failed_reconnects >= 1,
        "the supervisor never tried to reopen the mute device"
    );
}

/// Runs `voxhap serve` on the mock device at `path` for `seconds`; returns its stdout and stderr.
fn serve_on(path: &str, seconds: &str) -> (bool, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(["serve", "--device"])
        .arg(format!("mock:{path}"))
        .args([
            "--no-http",
            "--no-foxglove",
            "--rt",
            "off",
            "--duration",
            seconds,
        ])
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

/// Regression (issue 18): replies 5 ms late made connect fail with a "permissions?" message. The handshake
/// waits 100 ms per Hello and the servo reads pipelined states, so the session runs and engages.
#[test]
fn a_device_answering_5_ms_late_connects_and_engages() {
    let mock = Mock::start(&["--pty", "--latency-ms", "5"]);
    let (ok, text) = serve_on(&mock.path, "3");
    assert!(ok, "{text}");
    assert!(
        text.contains("enables 1") || text.contains("enables 2"),
        "{text}"
    );
    assert!(!text.contains("permission"), "{text}");
}

/// Regression (issue 18): with 1 % of the bytes corrupted, 73 % of the ticks were skipped. Device I/O now
/// waits at most half a period, so ticks keep their rate; the safety rules keep the force at zero or hold.
#[test]
fn a_lossy_link_keeps_the_tick_rate() {
    let mock = Mock::start(&["--pty", "--corrupt-rate", "0.01", "--seed", "7"]);
    let (ok, text) = serve_on(&mock.path, "3");
    assert!(ok, "{text}");
    let ticks = summary_number(&text, "ticks ");
    let skipped = summary_number(&text, "(skipped ");
    // Generous for a shared machine: before the fix 73 % were skipped.
    assert!(
        skipped * 10 < ticks,
        "{skipped} of {ticks} ticks skipped: {text}"
    );
}

/// The reconnecting wrapper the servo thread holds for every real device (connector thread, stop channel,
/// supervisor, protocol driver over a real pseudo-terminal) allocates nothing per exchange once connected and
/// enabled.
#[test]
fn the_reconnecting_wrapper_exchange_does_not_allocate() {
    use voxhap::servo::device::{open_device, DeviceSpec};
    use voxhap::servo::monitor::StopSlot;
    use voxhap::servo::setup::SceneSetup;
    let mock = Mock::start(&["--pty"]);
    let setup = SceneSetup::builtin().unwrap();
    let mut device = open_device(
        &DeviceSpec::Mock(mock.path.clone().into()),
        SupervisorConfig::default(),
        (setup.arm.clone(), setup.start_m),
        1e-3,
    )
    .unwrap()
    .device;
    device.set_stop_slot(StopSlot::new());
    device.connect(0).unwrap();
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
    let mut connected = 0;
    let allocations = crate::util::count_allocations(|| {
        for _ in 0..2_000 {
            if exchange(&mut device).connected {
                connected += 1;
            }
        }
    });
    device.stop();
    assert_eq!(allocations, 0);
    assert!(connected > 1_900, "{connected} of 2000 exchanges connected");
}
