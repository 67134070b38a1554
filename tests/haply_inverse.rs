//! The Haply Inverse3 driver against a double of the Inverse Service (tests/util/inverse_service.rs, written from
//! Haply's service documentation) over a real WebSocket on 127.0.0.1: identity and session set-up, one force per
//! tick, the safety pipeline's limits seen from the service's side, malformed frames, a service restart, and the
//! open error when nothing listens. Then a service that misbehaves: more than one message per command and
//! unsolicited updates (no backlog, no force from stale positions, reported), a service that refuses or drops
//! every connection (reconnects back off), and a slow-loris handshake while `voxhap serve` stops (the stop
//! is bounded).

use crate::util::inverse_service::{stamp_of, InverseService, ServiceEvent, DEVICE_ID};
use crate::util::inverse_ticks::{forced_tick, settle, tick_stamped_force};
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use voxhap::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, SupervisorEvent, TickInput};
use voxhap::device::transport::inverse_service::{Configuration, ServiceConfig};
use voxhap::device::{DeviceEvent, HapticDevice, Lifecycle};

fn config(url: &str, events_url: &str) -> HaplyInverseConfig {
    HaplyInverseConfig {
        service: ServiceConfig {
            url: url.to_owned(),
            events_url: Some(events_url.to_owned()),
            ..ServiceConfig::default()
        },
        // Generous for a shared 2-core test machine; the default is 0.4 ms.
        reply_wait: Duration::from_millis(20),
        ..HaplyInverseConfig::default()
    }
}

/// A driver that waits for every answer as long as a loaded machine may need (1 s per state, 50 times the
/// usual test wait, in `read_state` and in the I/O thread): the tests that check what the service receives and
/// what comes back, not the timing, use it, so a busy machine does not turn a late answer into a timeout or a
/// dropped link. An answer that never comes (a malformed frame) costs that second.
fn patient_config(url: &str, events_url: &str) -> HaplyInverseConfig {
    let mut config = config(url, events_url);
    config.reply_wait = Duration::from_secs(1);
    config.service.reply_timeout = Duration::from_secs(1);
    config
}

#[test]
fn open_reads_the_inventory_and_configures_the_identity_basis() {
    let service = InverseService::start();
    let mut device = Lifecycle::new(HaplyInverse::new(config(
        &service.url(),
        &service.events_url(),
    )));
    device.open().unwrap();
    assert_eq!(device.info().serial_number, DEVICE_ID);
    assert_eq!(device.info().model, "Haply inverse3 (Inverse Service)");
    let link = device.device().link().unwrap();
    assert_eq!(link.device.firmware.as_deref(), Some("7.4"));
    assert_eq!(link.device.session_id.as_deref(), Some("7"));
    // The read-back confirmed Haply's default frame, and reported the filters as the service has them.
    assert_eq!(link.device.configuration, Configuration::Confirmed);
    assert!(link
        .device
        .filters
        .as_deref()
        .unwrap()
        .contains("force_gate"));
    device.close().unwrap();
    let events = service.events();
    let session = events
        .iter()
        .find_map(|e| match e {
            ServiceEvent::Session(s) => Some(s.clone()),
            _ => None,
        })
        .expect("the first message configures the session");
    assert_eq!(session["configure"]["basis"]["permutation"], "XYZ");
    // The device's own configure block: preset and basis (never a mount beside a preset: tutorial 07).
    assert!(events
        .iter()
        .any(|e| matches!(e, ServiceEvent::Configure(block)
        if block["preset"]["preset"] == "defaults" && block["basis"]["permutation"] == "XYZ")));
    assert!(!events
        .iter()
        .any(|e| matches!(e, ServiceEvent::ConfigureRefused(_))));
    // open's zero force with the session, and the I/O thread's zero before closing.
    let forces = settle(&service, |f| f.len() >= 2);
    assert!(
        forces.len() >= 2 && forces.iter().all(|f| *f == [0.0; 3]),
        "{forces:?}"
    );
}

#[test]
fn one_force_per_tick_reaches_the_service_and_its_state_comes_back() {
    let service = InverseService::start();
    let mut device = Lifecycle::new(HaplyInverse::new(patient_config(
        &service.url(),
        &service.events_url(),
    )));
    device.open().unwrap();
    device.enable().unwrap();
    let before = service.forces().len();
    for i in 0..50 {
        service.set_position([0.001 * f64::from(i), -0.12, 0.15]);
        device
            .write_force(DVec3::new(0.01 * f64::from(i), 0.0, 0.5))
            .unwrap();
        let state = device.read_state().unwrap();
        assert!(
            (state.position_m.x - 0.001 * f64::from(i)).abs() < 1e-12,
            "tick {i}: {state:?}"
        );
        assert!((state.position_m.y + 0.12).abs() < 1e-12);
    }
    device.disable().unwrap();
    device.close().unwrap();
    // 50 ticks, then zeros: disable's, close's (the wrapper zeroes on every stop) and the I/O thread's own; the
    // I/O thread may coalesce queued zeros into one message, and sends a zero keepalive whenever no force came
    // for 100 ms (a descheduled test thread), so the zeros are told apart from the ticks by value.
    let forces = settle(&service, |f| {
        f.len() >= before + 51 && f.last() == Some(&[0.0; 3])
    });
    let ticks: Vec<[f64; 3]> = forces[before..]
        .iter()
        .copied()
        .filter(|f| *f != [0.0; 3])
        .collect();
    let expected: Vec<[f64; 3]> = (0..50).map(|i| [0.01 * i as f64, 0.0, 0.5]).collect();
    assert_eq!(ticks, expected, "one force per tick, in order");
    // Every stop ends at zero, and nothing but zeros follows the last tick.
    assert_eq!(forces[forces.len() - 1], [0.0; 3]);
    let last_tick = forces.iter().rposition(|f| *f == expected[49]).unwrap();
    assert!(forces[last_tick + 1..].iter().all(|f| *f == [0.0; 3]));
}

/// A reply that comes after the I/O thread stopped waiting for it (a busy service) answers an older command,
/// and is labelled so: afterwards, every state the driver gives as answering this tick's force (age 0) holds
/// the position set before that force, never the one of a tick before. (A driver that takes a late
/// reply for the newest shifts every later state by one command for the rest of the session.)
#[test]
fn a_reply_that_comes_late_is_never_taken_for_a_newer_one() {
    let service = InverseService::start();
    let mut device = Lifecycle::new(HaplyInverse::new(config(
        &service.url(),
        &service.events_url(),
    )));
    device.open().unwrap();
    device.enable().unwrap();
    let position = |i: u32| [0.0001 * f64::from(i), -0.12, 0.15];
    let mut checked = 0;
    for i in 0..200u32 {
        service.set_position(position(i));
        if i == 20 {
            // Three times the I/O thread's 20 ms reply timeout.
            service
                .shared
                .delay_next_reply_ms
                .store(60, Ordering::Release);
        }
        device.write_force(DVec3::ZERO).unwrap();
        let Ok(state) = device.read_state() else {
            continue;
        };
        if i > 40 && device.device().state_age_ticks() == 0 {
            checked += 1;
            assert!(
                (state.position_m.x - position(i)[0]).abs() < 1e-12,
                "tick {i}: a state given as this tick's answer holds x = {} (tick {:.0})",
                state.position_m.x,
                state.position_m.x / 0.0001
            );
        }
    }
    device.disable().unwrap();
    device.close().unwrap();
    assert!(checked > 100, "only {checked} ticks answered in time");
}

/// The supervisor over the driver, with `driver` (`config` or `patient_config`) for each connection.
fn supervisor(
    service: &InverseService,
    driver: fn(&str, &str) -> HaplyInverseConfig,
) -> Supervisor<HaplyInverse, impl FnMut() -> Result<HaplyInverse, voxhap::device::DeviceError>> {
    let (url, events_url) = (service.url(), service.events_url());
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 50_000,
            max_force_n: 2.0,
            ..SafetyConfig::default()
        },
        reconnect_interval_us: 50_000,
        // Enable after 5 steady ticks (the default 50 is for real sessions).
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    };
    Supervisor::new(config, move || {
        Ok(HaplyInverse::new(driver(&url, &events_url)))
    })
    .unwrap()
}

#[test]
fn the_safety_pipeline_bounds_what_the_service_receives_and_malformed_frames_are_skipped() {
    let service = InverseService::start();
    let mut supervisor = supervisor(&service, patient_config);
    supervisor.connect(0).unwrap();
    let mut events = Vec::new();
    for tick in 0..400u64 {
        if tick == 200 {
            service.shared.malformed_replies.store(6, Ordering::Release);
        }
        // 100 N, its tick written into it (the clamp scales it as a whole, so the service's log says which
        // tick each force came from); every 40th with a NaN in y, to be rejected whole.
        let force = match tick {
            0..20 => DVec3::ZERO,
            _ if tick % 40 == 3 => tick_stamped_force(tick, 100.0).with_y(f64::NAN),
            _ => tick_stamped_force(tick, 100.0),
        };
        let out = supervisor.tick(TickInput::at(force, tick * 1000));
        events.extend(out.events.iter());
        std::thread::sleep(Duration::from_micros(500));
    }
    let shared = supervisor
        .device()
        .unwrap()
        .device()
        .link()
        .unwrap()
        .shared
        .clone();
    supervisor.stop();
    let malformed = shared.malformed.load(Ordering::Relaxed);
    // One message per tick, unless the I/O thread fell behind (a loaded test machine) and sent the newest.
    let sent_and_coalesced =
        shared.sent.load(Ordering::Relaxed) + shared.coalesced.load(Ordering::Relaxed);
    assert!(
        !events
            .iter()
            .any(|e| matches!(e, SupervisorEvent::Disconnected { .. })),
        "six malformed frames must not drop the link: {events:?}"
    );
    assert_eq!(malformed, 6);
    assert!(sent_and_coalesced >= 400, "{sent_and_coalesced}");
    // Everything sent has arrived, and the stop's zeros with it (or 2 s passed, and the asserts below say why).
    let forces = settle(&service, |f| {
        f.len() as u64 >= shared.sent.load(Ordering::Relaxed) && f.last() == Some(&[0.0; 3])
    });
    for f in &forces {
        let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        assert!(norm.is_finite() && norm <= 2.0 + 1e-9, "{f:?}");
    }
    assert!(forces.iter().any(|f| f[2] > 1.9), "the clamp is reached");
    assert_eq!(*forces.last().unwrap(), [0.0; 3]);
    // What the arm was sent for each rejected (NaN) request, from the service's log: nothing of it (no force
    // carries that tick's stamp, which its finite x and z hold), and the service received force from a later
    // tick, so the link carried messages past it.
    for rejected in (20..400u64).filter(|tick| tick % 40 == 3) {
        assert!(
            !forces.iter().any(|f| forced_tick(f) == Some(rejected)),
            "the arm received a force from tick {rejected}'s rejected request: {forces:?}"
        );
        assert!(
            forces
                .iter()
                .any(|f| forced_tick(f).is_some_and(|tick| tick > rejected)),
            "no force after tick {rejected}'s rejected request reached the service"
        );
    }
}

#[test]
fn a_service_restart_drops_the_link_and_the_driver_reconnects() {
    let mut service = InverseService::start();
    let mut supervisor = supervisor(&service, config);
    supervisor.connect(0).unwrap();
    let start = Instant::now();
    let (mut lost_at, mut back_at) = (None, None);
    let mut tick = 0u64;
    let (mut stopped, mut started_again) = (false, false);
    let mut lost_while_down = false;
    while start.elapsed() < Duration::from_millis(3000) && back_at.is_none() {
        // The service is down from 200 ms to 500 ms; the loop keeps ticking meanwhile.
        if !stopped && start.elapsed() > Duration::from_millis(200) {
            service.stop();
            stopped = true;
        }
        if !started_again && start.elapsed() > Duration::from_millis(500) {
            lost_while_down = lost_at.is_some();
            service.start_again();
            started_again = true;
        }
        let now_us = tick * 1000;
        let out = supervisor.tick(TickInput::at(tick_stamped_force(tick, 0.3), now_us));
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Disconnected { .. } => lost_at = Some(tick),
                SupervisorEvent::Connected if lost_at.is_some() => back_at = Some(tick),
                _ => {}
            }
        }
        tick += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
    supervisor.stop();
    assert!(
        lost_while_down,
        "the stop was noticed while the service was down"
    );
    assert!(
        back_at.is_some(),
        "the driver reconnected after the restart"
    );
    let connects = service
        .events()
        .iter()
        .filter(|e| **e == ServiceEvent::Connected)
        .count();
    assert_eq!(connects, 2);
    let forces = settle(&service, |f| f.last() == Some(&[0.0; 3]));
    assert_eq!(*forces.last().unwrap(), [0.0; 3]);
    // What the arm was sent after the drop, from the service's log (forces after its second `Connected`): the
    // new link begins with zero, and no non-zero force on it was requested before the link was back (the
    // supervisor ramps in afresh, from the reconnect on).
    let events = service.events();
    let second = events
        .iter()
        .rposition(|e| *e == ServiceEvent::Connected)
        .unwrap();
    let new_link: Vec<[f64; 3]> = events[second..]
        .iter()
        .filter_map(|e| match e {
            ServiceEvent::Force { vector, .. } => Some(*vector),
            _ => None,
        })
        .collect();
    assert_eq!(
        new_link.first(),
        Some(&[0.0; 3]),
        "the reconnected link's first force"
    );
    let back_at = back_at.unwrap();
    assert!(
        new_link
            .iter()
            .all(|f| forced_tick(f).is_none_or(|tick| tick > back_at)),
        "a force requested before the link was back (tick {back_at}) reached the arm: {new_link:?}"
    );
}

#[test]
fn nothing_listening_is_an_open_error_that_says_what_to_do() {
    // Bind and drop a listener to get a port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let url = format!("ws://127.0.0.1:{port}");
    let mut device = HaplyInverse::new(config(&url, &url));
    let message = device.open().unwrap_err().to_string();
    assert!(message.contains("refused"), "{message}");
    assert!(message.contains("Inverse Service running"), "{message}");
}

/// The service sends two state updates for every message and an unsolicited one every 100 ms; each carries
/// its index in its position. The driver must read them all (no backlog), report them, and every force that
/// leaves the host must come from a position the service wrote after the tick at most 4 before it had begun
/// (the state read at the previous tick, within the staleness bound of 3, docs/safety.md): whatever the
/// timing, since a TCP stream keeps the order. A driver that reads one message per command lets the rendered
/// position fall one message further behind on every tick (positions seconds old after a few thousand ticks,
/// while the labels say "fresh").
#[test]
fn extra_messages_from_the_service_never_make_force_from_stale_positions() {
    let service = InverseService::start();
    service.shared.stamp.store(true, Ordering::Release);
    service
        .shared
        .replies_per_message
        .store(2, Ordering::Release);
    service
        .shared
        .unsolicited_every_ms
        .store(100, Ordering::Release);
    let mut supervisor = supervisor(&service, config);
    supervisor.connect(0).unwrap();
    // written_before[t]: the index of the newest message the service had finished writing when tick t began.
    let mut written_before = vec![0u64];
    let mut rendered_from: Option<u64> = None;
    let (mut forces_sent, mut events) = (0u32, Vec::new());
    for tick in 1..=3000u64 {
        written_before.push(service.shared.written.load(Ordering::Acquire));
        // The scene: a constant push whenever the host has a position to render from.
        let force = if rendered_from.is_some() {
            DVec3::new(0.0, 0.0, 0.5)
        } else {
            DVec3::ZERO
        };
        let out = supervisor.tick(TickInput::at(force, tick * 1000));
        events.extend(out.events.iter());
        if out.sent_force_n != DVec3::ZERO {
            forces_sent += 1;
            let index = rendered_from.expect("force with no position to render from");
            let bound_tick = tick.saturating_sub(4);
            let bound = written_before[bound_tick as usize];
            assert!(
                index > bound,
                "tick {tick}: force {:?} rendered from message {index}, written before tick {bound_tick} began \
                 (the service had written {bound} messages by then, {} by this tick)",
                out.sent_force_n,
                written_before[tick as usize]
            );
        }
        rendered_from = out
            .state
            .map(|s| stamp_of(s.position_m.x))
            .filter(|_| out.connected);
        std::thread::sleep(Duration::from_micros(500));
    }
    let shared = supervisor
        .device()
        .unwrap()
        .device()
        .link()
        .unwrap()
        .shared
        .clone();
    let extra_counted = supervisor.counters().device_surplus;
    supervisor.stop();
    assert!(
        forces_sent > 100,
        "only {forces_sent} ticks sent force; events {events:?}"
    );
    // Detected, counted, reported: at least every second message of the service was one too many.
    let extra = shared.extra.load(Ordering::Relaxed);
    let states = shared.states.load(Ordering::Relaxed);
    assert!(extra * 3 >= states, "{extra} extra of {states} states");
    assert!(extra_counted > 0 && extra_counted <= extra);
    assert!(
        events.iter().any(
            |e| matches!(e, SupervisorEvent::Device(DeviceEvent::Surplus { total }) if *total >= 1)
        ),
        "{events:?}"
    );
    assert!(!shared.flooded.load(Ordering::Relaxed));
}

/// The connector's documented schedule (servo::device::reconnect, docs/safety.md): after the n-th failure in a
/// row it waits at least 0.75 · min(5 s, interval · 2^n). The most attempts that fit in `window`, the first at
/// its start.
fn most_attempts_within(window: Duration, interval: Duration) -> u32 {
    let (mut attempts, mut elapsed) = (1u32, Duration::ZERO);
    for n in 0..64u32 {
        let wait = interval
            .saturating_mul(1 << n.min(20))
            .min(Duration::from_secs(5))
            .mul_f64(0.75);
        elapsed += wait;
        if elapsed > window {
            break;
        }
        attempts += 1;
    }
    attempts
}

/// Runs a reconnecting Inverse3 (`reconnect_interval_us` 50 ms) against `service` for `window`, ticking every
/// millisecond; returns the TCP connections the service accepted.
fn connections_within(service: &InverseService, window: Duration) -> u32 {
    use voxhap::servo::device::{Reconnecting, ServoDevice};
    let (url, events_url) = (service.url(), service.events_url());
    let config = SupervisorConfig {
        reconnect_interval_us: 50_000,
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    };
    let mut device = Reconnecting::new(
        config,
        Box::new(move || Ok(HaplyInverse::new(self::config(&url, &events_url)))),
    )
    .unwrap();
    let start = Instant::now();
    let mut tick = 0u64;
    while start.elapsed() < window {
        tick += 1;
        device.exchange(TickInput::at(DVec3::ZERO, tick * 1000));
        std::thread::sleep(Duration::from_millis(1));
    }
    device.stop();
    service.shared.accepted.load(Ordering::Acquire)
}

/// A service that drops every connection at once (the open fails), and one that completes the handshake and
/// the session set-up and then drops it (the link is lost as soon as it is handed to the servo thread): either
/// way the connector backs off. Without the back-off the second one was reconnected to about 50 times a
/// second, and the first every 50 ms.
#[test]
fn reconnects_back_off_from_a_service_that_refuses_or_drops_every_connection() {
    let window = Duration::from_secs(3);
    let most = most_attempts_within(window, Duration::from_millis(50));
    // 37.5 + 75 + 150 + 300 + 600 + 1200 ms fit in 3 s: 7 attempts at most.
    assert_eq!(most, 7);
    for setup in ["refuse", "drop after set-up"] {
        let service = InverseService::start();
        match setup {
            "refuse" => service.shared.refuse.store(true, Ordering::Release),
            _ => service
                .shared
                .close_after_replies
                .store(1, Ordering::Release),
        }
        let connections = connections_within(&service, window);
        assert!(
            (2..=most).contains(&connections),
            "{setup}: {connections} connections in {window:?} (at most {most} by the schedule)"
        );
    }
}

/// The documented bound on how long `voxhap serve --no-http` takes to stop after a signal (docs/serve.md,
/// "Stopping"): the servo thread is waited for at most 3 s, its connector at most 1 s of that.
const DOCUMENTED_STOP_BOUND: Duration = Duration::from_secs(3);
/// What a busy test machine may add (process start-up excluded: the clock starts at the signal).
const STOP_MARGIN: Duration = Duration::from_secs(10);

/// `voxhap serve` on the Inverse3 behind the double; the double then stops answering (the link is dropped) and
/// answers every new connection's handshake one byte per 100 ms, without end. SIGINT while the connector is
/// inside that handshake: serve exits cleanly within the documented bound, and the last force the service
/// received is zero. Serve must not wait for the handshake, which has no end.
///
/// The connect deadline (`--connect-timeout`) is 60 s, not the default 3 s: the first connect, to a double
/// served by this test process's threads, must not miss it on a loaded machine (serve would exit before any
/// force), and the handshake the signal interrupts then outlasts the stop bound and its margin (13 s), so a
/// serve that waited for the connect to give up would fail here (with 3 s it would have passed).
#[test]
fn serve_stops_in_bounded_time_while_a_handshake_comes_one_byte_at_a_time() {
    use std::io::Read as _;
    use std::process::Stdio;
    let _turn = crate::util::spec_serve::take_turn();
    let service = InverseService::start();
    let mut child = crate::util::serve_headless(&format!("haply-inverse:{}", service.url()))
        .args(["--connect-timeout", "60"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start voxhap serve");
    let output = |child: &mut std::process::Child| {
        let mut text = String::new();
        if let Some(mut out) = child.stdout.take() {
            let _ = out.read_to_string(&mut text);
        }
        if let Some(mut err) = child.stderr.take() {
            let _ = err.read_to_string(&mut text);
        }
        text
    };
    let wait_until = |child: &mut std::process::Child, what: &str, done: &dyn Fn() -> bool| {
        let start = Instant::now();
        while !done() {
            if child.try_wait().unwrap().is_some() || start.elapsed() > Duration::from_secs(60) {
                let exited = child.try_wait().unwrap();
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "serve exited ({exited:?}) or 60 s passed before {what}; its output:\n{}",
                    output(child)
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    wait_until(&mut child, "100 forces reached the service", &|| {
        service.forces().len() >= 100
    });
    // From the next connection on, the handshake comes one byte at a time; this one goes quiet, so the host
    // drops it (zero force first) and the connector reconnects.
    let next = service.shared.accepted.load(Ordering::Acquire) + 1;
    service
        .shared
        .slow_handshake_from
        .store(next, Ordering::Release);
    service.shared.mute.store(true, Ordering::Release);
    wait_until(&mut child, "the connector's next connection", &|| {
        service.shared.accepted.load(Ordering::Acquire) >= next
    });
    // Inside the handshake (it never ends; its deadline is the 60 s of --connect-timeout).
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: plain kill(2) on our own child's pid.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) },
        0
    );
    let signalled = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if signalled.elapsed() > DOCUMENTED_STOP_BOUND + STOP_MARGIN {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "serve still ran {:?} after SIGINT; it said:\n{}",
                signalled.elapsed(),
                output(&mut child)
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let took = signalled.elapsed();
    let said = output(&mut child);
    assert!(status.success(), "serve failed ({status}): {said}");
    assert!(took <= DOCUMENTED_STOP_BOUND + STOP_MARGIN, "{took:?}");
    let forces = settle(&service, |f| f.last() == Some(&[0.0; 3]));
    assert_eq!(forces.last(), Some(&[0.0; 3]), "{said}");
    for f in &forces {
        let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        assert!(norm.is_finite() && norm <= 3.0 + 1e-9, "{f:?}");
    }
}

/// `serve --connect-timeout` reaches the Inverse3's connect: through the servo's own device wiring, a service
/// whose handshake comes one byte per 100 ms without end is given up on after the configured 2.5 s, and the
/// error says so (the driver's own default is 1 s).
#[test]
fn the_connect_timeout_reaches_the_inverse_connect() {
    use voxhap::servo::device::{open_device, DeviceSpec};
    use voxhap::servo::setup::SceneSetup;
    let service = InverseService::start();
    service
        .shared
        .slow_handshake_from
        .store(1, Ordering::Release);
    let setup = SceneSetup::builtin().unwrap();
    let config = SupervisorConfig {
        connect_timeout_us: 2_500_000,
        ..SupervisorConfig::default()
    };
    let mut device = open_device(
        &DeviceSpec::HaplyInverse(service.url()),
        config,
        (setup.arm.clone(), setup.start_m),
        1e-3,
    )
    .unwrap()
    .device;
    let error = device
        .connect(0)
        .expect_err("the handshake never ends")
        .to_string();
    device.stop();
    assert!(
        error.contains("2500000 µs"),
        "the error names another deadline: {error}"
    );
}
