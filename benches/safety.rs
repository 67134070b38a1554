//! What the safety pipeline costs per tick (the goal: at most about 200 ns): one device exchange through the
//! supervisor (device status, input plausibility and velocity estimate, clamp, slew limit, engage rule, link
//! health, events) against the same exchange written straight to the driver, side by side in one run.
//!
//! The device is an in-memory driver whose handle moves 0.05 mm per tick and which reports a status, so every
//! check runs its full path; the supervisor is enabled and engaged before measuring. The difference of the two
//! medians is the pipeline's cost.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, TickInput};
use voxhap::device::{DeviceError, DeviceInfo, DeviceState, DeviceStatus, HapticDevice};

/// A handle moving on a circle, reporting its velocity and an enabled status.
struct Circling {
    info: DeviceInfo,
    tick: u64,
    enabled: bool,
    force_n: DVec3,
}

impl Circling {
    fn new() -> Circling {
        Circling {
            info: DeviceInfo {
                reports_velocity: true,
                ..DeviceInfo::basic("bench", DVec3::splat(-0.1), DVec3::splat(0.1))
            },
            tick: 0,
            enabled: false,
            force_n: DVec3::ZERO,
        }
    }
}

impl HapticDevice for Circling {
    type Error = DeviceError;
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
    fn enable(&mut self) -> Result<(), DeviceError> {
        self.enabled = true;
        Ok(())
    }
    fn disable(&mut self) -> Result<(), DeviceError> {
        self.enabled = false;
        Ok(())
    }
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        self.force_n = force_n;
        self.tick += 1;
        Ok(())
    }
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let t = self.tick as f64 * 1e-3;
        let omega = 1.0;
        let radius = 0.05;
        Ok(DeviceState {
            position_m: DVec3::new(radius * (omega * t).cos(), radius * (omega * t).sin(), 0.0),
            velocity_m_per_s: DVec3::new(
                -radius * omega * (omega * t).sin(),
                radius * omega * (omega * t).cos(),
                0.0,
            ),
            buttons: 0,
            device_time_us: Some(self.tick * 1000),
            sequence: Some(self.tick as u32),
            status: Some(DeviceStatus {
                enabled: self.enabled,
                ..DeviceStatus::default()
            }),
        })
    }
}

fn bench_safety(c: &mut Criterion) {
    let mut group = c.benchmark_group("exchange");
    let force = DVec3::new(0.3, -0.2, 0.1);

    let mut raw = Circling::new();
    group.bench_function("raw", |b| {
        b.iter(|| {
            raw.write_force(black_box(force)).unwrap();
            black_box(raw.read_state().unwrap())
        })
    });

    let mut supervisor =
        Supervisor::new(SupervisorConfig::default(), || Ok(Circling::new())).unwrap();
    supervisor.connect(0).unwrap();
    let mut now_us = 0u64;
    // Enabled after 50 steady ticks, engaged after 10 small ones, ramped in over 0.5 s.
    for _ in 0..2_000 {
        now_us += 1_000;
        supervisor.tick(TickInput::at(DVec3::ZERO, now_us));
    }
    assert!(supervisor.safety().is_engaged());
    group.bench_function("supervised", |b| {
        b.iter(|| {
            now_us += 1_000;
            black_box(supervisor.tick(TickInput::at(black_box(force), now_us)))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_safety);
criterion_main!(benches);
