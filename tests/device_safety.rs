//! The safety pipeline and the supervisor on the servo path: no allocation per tick (counting allocator), and the
//! supervisor's handling of a lost device (replay device behind an opener that can fail).

use crate::util::count_allocations;
use glam::DVec3;
use std::cell::Cell;
use std::rc::Rc;
use voxhap::device::safety::{SafetyConfig, SafetyPipeline};
use voxhap::device::supervisor::{
    LossReason, Supervisor, SupervisorConfig, SupervisorEvent, TickInput,
};
use voxhap::device::{DeviceError, DeviceInfo, DeviceState, ErrorKind, HapticDevice};
use voxhap::record::{Trace, TraceSample};
use voxhap::servo::device::ReplayDevice;

#[test]
fn safety_pipeline_tick_does_not_allocate() {
    let mut pipeline = SafetyPipeline::new(SafetyConfig::default()).unwrap();
    pipeline.enable(0);
    let forces = [
        DVec3::ZERO,
        DVec3::new(10.0, 0.0, 0.0),
        DVec3::new(f64::NAN, 0.0, 0.0),
        DVec3::Y,
    ];
    let events = count_allocations(|| {
        for tick in 0..10_000u64 {
            let out = pipeline.process(forces[(tick % 4) as usize], tick * 1_000, true);
            std::hint::black_box(out);
        }
    });
    assert_eq!(events, 0);
    assert!(pipeline.counters().non_finite > 0 && pipeline.counters().clamped > 0);
}

fn trace(count: usize) -> Trace {
    Trace {
        mode_names: Vec::new(),
        samples: (0..count)
            .map(|i| TraceSample {
                tick: i as u64,
                t_s: i as f64 * 1e-3,
                probe_m: DVec3::new(i as f64 * 1e-5, 0.0, 0.0),
                ..TraceSample::zeroed(0)
            })
            .collect(),
        sidecar: None,
        warnings: Vec::new(),
    }
}

#[test]
fn supervisor_steady_state_tick_does_not_allocate() {
    let replay = trace(100);
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), || {
        ReplayDevice::new(&replay, true)
    })
    .unwrap();
    assert!(supervisor.connect(0).is_ok());
    supervisor.tick(TickInput::at(DVec3::ZERO, 1_000));
    let events = count_allocations(|| {
        for tick in 2..5_000u64 {
            std::hint::black_box(
                supervisor.tick(TickInput::at(DVec3::new(0.01, 0.0, 0.0), tick * 1_000)),
            );
        }
    });
    assert_eq!(events, 0);
}

/// A device that works until told to vanish.
struct Flaky {
    info: DeviceInfo,
    gone: Rc<Cell<bool>>,
    forces: Rc<Cell<DVec3>>,
}

impl HapticDevice for Flaky {
    type Error = DeviceError;
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if self.gone.get() {
            return Err(DeviceError::Disconnected {
                during: "writing",
                kind: std::io::ErrorKind::BrokenPipe,
            });
        }
        self.forces.set(force_n);
        Ok(())
    }
    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        Ok(DeviceState::at_rest(DVec3::ZERO))
    }
}

#[test]
fn supervisor_zeroes_reports_and_reconnects_after_a_disconnect() {
    let gone = Rc::new(Cell::new(false));
    let forces = Rc::new(Cell::new(DVec3::ZERO));
    let info = DeviceInfo {
        model: "flaky".into(),
        serial_number: String::new(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        workspace_min_m: DVec3::splat(-0.1),
        workspace_max_m: DVec3::splat(0.1),
        max_force_n: 1.0,
        max_stiffness_n_per_m: 1000.0,
        max_speed_m_per_s: 5.0,
        reports_velocity: false,
        state_rates_hz: Vec::new(),
    };
    let opener_gone = gone.clone();
    let opener_forces = forces.clone();
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 10_000,
            ..SafetyConfig::default()
        },
        reconnect_interval_us: 50_000,
        max_consecutive_errors: 5,
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    };
    let mut supervisor = Supervisor::new(config, move || {
        if opener_gone.get() {
            Err(DeviceError::Open {
                path: "flaky".into(),
                message: "not there".into(),
            })
        } else {
            Ok(Flaky {
                info: info.clone(),
                gone: opener_gone.clone(),
                forces: opener_forces.clone(),
            })
        }
    })
    .unwrap();
    let push = DVec3::new(5.0, 0.0, 0.0);
    let mut now_us = 0;
    let mut tick = |supervisor: &mut Supervisor<_, _>, force: DVec3| {
        now_us += 1_000;
        supervisor.tick(TickInput::at(force, now_us))
    };
    assert_eq!(
        tick(&mut supervisor, DVec3::ZERO).events.first(),
        Some(SupervisorEvent::Connected)
    );
    // Enabled after 5 steady ticks; engaged after 10 small ones; ramped in over 10 ms; then the push, whose
    // rise the slew limit spreads over a few ticks.
    for _ in 0..30 {
        tick(&mut supervisor, DVec3::ZERO);
    }
    for _ in 0..20 {
        tick(&mut supervisor, push);
    }
    // Ramped in, clamped to the device's 1 N.
    assert!((forces.get().x - 1.0).abs() < 1e-12, "{:?}", forces.get());
    gone.set(true);
    let out = tick(&mut supervisor, push);
    assert_eq!(
        out.events.first(),
        Some(SupervisorEvent::Disconnected {
            kind: ErrorKind::Disconnected,
            reason: LossReason::HungUp
        })
    );
    assert!(!out.connected);
    for _ in 0..100 {
        let out = tick(&mut supervisor, push);
        assert_eq!(out.sent_force_n, DVec3::ZERO);
        assert!(!out.connected);
    }
    assert!(supervisor.counters().failed_reconnects >= 1);
    gone.set(false);
    let mut reconnected = false;
    for _ in 0..100 {
        if tick(&mut supervisor, DVec3::ZERO).events.first() == Some(SupervisorEvent::Connected) {
            reconnected = true;
            break;
        }
    }
    assert!(reconnected);
    // Forces ramp in again from zero: the first tick after reconnection sends (nearly) nothing.
    let out = tick(&mut supervisor, DVec3::new(0.05, 0.0, 0.0));
    assert!(out.sent_force_n.length() < 0.01, "{:?}", out.sent_force_n);
    assert_eq!(supervisor.counters().disconnects, 1);
}
