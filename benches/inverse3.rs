//! Haply Inverse3 host round trip over a loopback WebSocket: the real driver (its I/O thread and lock-free
//! hand-off) against the Inverse Service test double of tests/util/inverse_service.rs (written from Haply's
//! published service documentation), both in this process, on 127.0.0.1.
//!
//! One round trip = `write_force` (the command goes to the I/O thread, which sends `set_cursor_force`) then
//! `read_state` (waits for the state frame the service sends back for that message). Two measurements:
//! criterion's timing of back-to-back round trips (short: 1 s warm-up, 3 s measurement), and a paced run at
//! 1 kHz (the servo rate) printing p50, p99 and the maximum over 2 000 exchanges.
//!
//! Then the servo loop itself (docs/performance.md quotes its output): a `voxhap serve` session (the built-in scene,
//! 1 kHz, best-effort real time) on the simulated arm and on the Inverse3 through the same double, side by side
//! in one run, in alternating windows (sim, Inverse3, sim, Inverse3; 2 s each), printing the servo's lateness
//! p50/p99/max and the device exchange's p50/p99 of each window.

#[allow(dead_code)]
#[path = "../tests/util/inverse_service.rs"]
mod inverse_service;

#[path = "util/paced.rs"]
mod paced;
#[path = "util/round_trip.rs"]
mod round_trip;

use criterion::{criterion_group, criterion_main, Criterion};
use inverse_service::InverseService;
use std::time::Duration;
use voxhap::device::drivers::haply_inverse::{HaplyInverse, HaplyInverseConfig};
use voxhap::device::transport::inverse_service::ServiceConfig;
use voxhap::device::Lifecycle;
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{Session, SessionConfig};

type Device = Lifecycle<HaplyInverse>;

fn open(url: &str) -> Device {
    round_trip::enabled(HaplyInverse::new(HaplyInverseConfig {
        service: ServiceConfig {
            url: url.to_owned(),
            ..ServiceConfig::default()
        },
        // Wait for the answer to this very command (the servo default is 0.4 ms, after which it uses an
        // older state); the benchmark measures the full round trip.
        reply_wait: Duration::from_millis(50),
        ..HaplyInverseConfig::default()
    }))
}

/// One servo session of `seconds` on `device`; prints its lateness and device-exchange percentiles.
fn servo_window(label: &str, device: DeviceSpec, seconds: f64) {
    let setup = SceneSetup::builtin().expect("the built-in scene");
    let session =
        Session::start(SessionConfig::new(device, setup)).expect("start the servo session");
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let stats = session.stop().stats;
    println!(
        "servo/{label}: {} ticks at {} Hz: lateness p50 {:.1} us, p99 {:.1} us, max {:.1} us; device exchange \
         p50 {:.1} us, p99 {:.1} us; overruns {}, device errors {}",
        stats.ticks,
        stats.rate_hz,
        stats.lateness.p50_us,
        stats.lateness.p99_us,
        stats.lateness.max_us,
        stats.device.p50_us,
        stats.device.p99_us,
        stats.overruns,
        stats.device_errors
    );
}

fn bench(c: &mut Criterion) {
    let service = InverseService::start();
    for _ in 0..2 {
        servo_window("sim", DeviceSpec::Sim, 2.0);
        servo_window(
            "inverse3_loopback",
            DeviceSpec::HaplyInverse(service.url()),
            2.0,
        );
    }
    let mut device = open(&service.url());
    paced::paced_percentiles("device/inverse3_loopback_paced_1khz", 2_000, || {
        round_trip::round_trip(&mut device)
    });
    let mut group = c.benchmark_group("device");
    group
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3))
        .sample_size(20);
    group.bench_function("inverse3_loopback_round_trip", |b| {
        b.iter(|| round_trip::round_trip(&mut device))
    });
    group.finish();
    let _ = device.close();
}

criterion_group!(benches, bench);
criterion_main!(benches);
