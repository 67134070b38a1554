//! The Haply Inverse3 driver against a double of the Inverse Service (tests/util/inverse_service.rs, written from
//! Haply's service documentation) over a real WebSocket on 127.0.0.1: identity and session set-up, one force per
//! tick, the safety pipeline's limits seen from the service's side, malformed frames, a service restart, and the
//! open error when nothing listens.

use crate::util::inverse_service::{InverseService, ServiceEvent, DEVICE_ID};
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use voxhap::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, SupervisorEvent, TickInput};
use voxhap::device::transport::inverse_service::ServiceConfig;
use voxhap::device::{HapticDevice, Lifecycle};

/// Waits (up to 2 s) until the service's log satisfies `done`: the service reads our last messages on its own
/// thread, after `close` has returned.
fn settle(service: &InverseService, done: impl Fn(&[[f64; 3]]) -> bool) -> Vec<[f64; 3]> {
    let start = Instant::now();
    loop {
        let forces = service.forces();
        if done(&forces) || start.elapsed() > Duration::from_secs(2) {
            return forces;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn config(url: &str) -> HaplyInverseConfig {
    HaplyInverseConfig {
        service: ServiceConfig {
            url: url.to_owned(),
            ..ServiceConfig::default()
        },
        // Generous for a shared 2-core test machine; the default is 0.4 ms.
        reply_wait: Duration::from_millis(20),
        ..HaplyInverseConfig::default()
    }
}

#[test]
fn open_reads_the_inventory_and_configures_the_identity_basis() {
    let service = InverseService::start();
    let mut device = Lifecycle::new(HaplyInverse::new(config(&service.url())));
    device.open().unwrap();
    assert_eq!(device.info().serial_number, DEVICE_ID);
    assert_eq!(device.info().model, "Haply inverse3 (Inverse Service)");
    let link = device.device().link().unwrap();
    assert_eq!(link.device.firmware.as_deref(), Some("7.4"));
    assert_eq!(link.device.session_id, Some(7));
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
    let mut device = Lifecycle::new(HaplyInverse::new(config(&service.url())));
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
    // I/O thread may coalesce queued zeros into one message.
    let forces = settle(&service, |f| {
        f.len() >= before + 51 && f.last() == Some(&[0.0; 3])
    });
    let ticks = &forces[before..before + 50];
    for (i, f) in ticks.iter().enumerate() {
        assert_eq!(*f, [0.01 * i as f64, 0.0, 0.5], "tick {i}");
    }
    // Every stop ends at zero, and nothing but zeros follows the last tick.
    assert_eq!(forces[forces.len() - 1], [0.0; 3]);
    assert!(forces[before + 50..].iter().all(|f| *f == [0.0; 3]));
}

/// A reply that comes after the I/O thread stopped waiting for it (a busy service) answers an older command,
/// and is labelled so: afterwards, every state the driver gives as answering this tick's force (age 0) holds
/// the position set before that force, never the one of a tick before. (Before issue 13's fix, each late
/// reply shifted every later state by one command for the rest of the session.)
#[test]
fn a_reply_that_comes_late_is_never_taken_for_a_newer_one() {
    let service = InverseService::start();
    let mut device = Lifecycle::new(HaplyInverse::new(config(&service.url())));
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

fn supervisor(
    url: &str,
) -> Supervisor<HaplyInverse, impl FnMut() -> Result<HaplyInverse, voxhap::device::DeviceError>> {
    let url = url.to_owned();
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
    Supervisor::new(config, move || Ok(HaplyInverse::new(self::config(&url)))).unwrap()
}

#[test]
fn the_safety_pipeline_bounds_what_the_service_receives_and_malformed_frames_are_skipped() {
    let service = InverseService::start();
    let mut supervisor = supervisor(&service.url());
    supervisor.connect(0).unwrap();
    let mut events = Vec::new();
    for tick in 0..400u64 {
        if tick == 200 {
            service.shared.malformed_replies.store(6, Ordering::Release);
        }
        let force = match tick {
            0..20 => DVec3::ZERO,
            _ if tick % 40 == 3 => DVec3::new(f64::NAN, 0.0, 1.0),
            _ => DVec3::new(0.0, 0.0, 100.0),
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
}

#[test]
fn a_service_restart_drops_the_link_and_the_driver_reconnects() {
    let mut service = InverseService::start();
    let mut supervisor = supervisor(&service.url());
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
        let out = supervisor.tick(TickInput::at(DVec3::new(0.0, 0.0, 0.3), now_us));
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Disconnected { .. } => lost_at = Some(now_us),
                SupervisorEvent::Connected if lost_at.is_some() => back_at = Some(now_us),
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
}

#[test]
fn nothing_listening_is_an_open_error_that_says_what_to_do() {
    // Bind and drop a listener to get a port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut device = HaplyInverse::new(config(&format!("ws://127.0.0.1:{port}")));
    let message = device.open().unwrap_err().to_string();
    assert!(message.contains("refused"), "{message}");
    assert!(message.contains("Inverse Service running"), "{message}");
}
