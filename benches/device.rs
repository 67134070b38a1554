//! Host round trip over a pseudo-terminal pair: write a force, read the State that answers it (lockstep), with the
//! mock device (crates/device/src/mock.rs, the simulated arm behind the real protocol) serving in a thread of this process.
//!
//! Two measurements: criterion's timing of back-to-back round trips, and a paced run at 1 kHz (the servo rate)
//! that prints the p50, p99 and maximum round-trip latency over 5 000 exchanges.

#[path = "util/paced.rs"]
mod paced;
#[path = "util/round_trip.rs"]
mod round_trip;

use criterion::{criterion_group, criterion_main, Criterion};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::Duration;
use voxhap::device::drivers::protocol::{ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::mock::{default_arm_config, run_mock, FaultConfig, MockEvent, ServeOn};
use voxhap::device::transport::SerialTransport;
use voxhap::device::Lifecycle;

type Device = Lifecycle<ProtocolDevice<SerialLink<SerialTransport>>>;

fn start_mock() -> (Arc<AtomicBool>, std::thread::JoinHandle<()>, String) {
    let shutdown = Arc::new(AtomicBool::new(false));
    let (sender, receiver) = mpsc::channel();
    let flag = shutdown.clone();
    let handle = std::thread::spawn(move || {
        let mut on_event = |event: MockEvent| {
            if let MockEvent::Serving(path) = event {
                let _ = sender.send(path);
            }
        };
        let result = run_mock(
            default_arm_config(),
            FaultConfig::default(),
            &ServeOn::Pty,
            None,
            &flag,
            &mut on_event,
        );
        if let Err(error) = result {
            eprintln!("mock device failed: {error}");
        }
    });
    let path = receiver
        .recv_timeout(Duration::from_secs(5))
        .expect("mock device path");
    (shutdown, handle, path)
}

fn open(path: &str) -> Device {
    let config = ProtocolConfig {
        state_timeout: Duration::from_millis(100),
        ..ProtocolConfig::default()
    };
    let transport = SerialTransport::open(path, 1_000_000).expect("open the pseudo-terminal");
    round_trip::enabled(ProtocolDevice::new(SerialLink::new(transport), config))
}

fn bench(c: &mut Criterion) {
    let (shutdown, handle, path) = start_mock();
    let mut device = open(&path);
    paced::paced_percentiles("device/pty_round_trip_paced_1khz", 5_000, || {
        round_trip::round_trip(&mut device)
    });
    c.bench_function("device/pty_round_trip", |b| {
        b.iter(|| round_trip::round_trip(&mut device))
    });
    let _ = device.close();
    shutdown.store(true, Ordering::Relaxed);
    let _ = handle.join();
}

criterion_group!(benches, bench);
criterion_main!(benches);
