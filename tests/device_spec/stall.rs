//! A watchdog that acts: a stalled servo thread is brought to zero by the stall monitor, seen from the device.

use crate::util::spec_device::{
    fault, types, HostMessage, SpecDevice, SpecDeviceConfig, SpecDeviceHandle,
};
use crate::util::spec_serve::{
    assert_slew_limited, enable_after, free_space, summary, take_turn, PATIENCE,
};
use std::sync::Arc;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// A watchdog that acts.

/// The stall monitor, from the device's side: a servo thread (this test thread, exchanging through the same
/// reconnecting wrapper, protocol driver and stop channel `serve` uses) renders a force, then stops ticking. The
/// real monitor thread must bring the device to zero force and Disable on its own, within its stated time (20
/// periods, 20 ms at 1 kHz) plus a margin for a loaded machine, and before the device's own 50 ms watchdog fires.
/// When the thread ticks again, force comes back only after a new Enable.
#[test]
fn a_stalled_servo_thread_is_brought_to_zero_by_the_monitor() {
    use glam::DVec3;
    use std::sync::atomic::{AtomicBool, Ordering};
    use voxhap::device::supervisor::{SupervisorConfig, TickInput};
    use voxhap::servo::device::{open_device, DeviceSpec};
    use voxhap::servo::monitor::{Monitor, MonitorConfig, StopSlot, EVENT_RING};
    use voxhap::servo::setup::SceneSetup;
    use voxhap::servo::stats::ServoStats;

    /// Scheduling slack on a shared 2-core machine, on top of the monitor's stated time.
    const MARGIN: Duration = Duration::from_millis(25);
    let _turn = take_turn();
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        handle: free_space(),
        ..SpecDeviceConfig::default()
    });
    let setup = SceneSetup::builtin().unwrap();
    let mut servo = open_device(
        &DeviceSpec::Serial(device.path().into()),
        SupervisorConfig::default(),
        (setup.arm.clone(), setup.start_m),
        1e-3,
    )
    .unwrap()
    .device;
    let slot = StopSlot::new();
    servo.set_stop_slot(slot.clone());
    servo.connect(0).unwrap();
    let stats = Arc::new(ServoStats::new(1000.0));
    let running = Arc::new(AtomicBool::new(true));
    let config = MonitorConfig {
        period: Duration::from_millis(1),
        stall_periods: 20,
    };
    let (_events_tx, events_rx) = rtrb::RingBuffer::new(EVENT_RING);
    let mut monitor = Monitor::spawn(config, stats.clone(), running, slot, events_rx).unwrap();

    // The servo thread: a 0.8 N rendered force (below the engage threshold, so it engages and ramps in).
    let start = Instant::now();
    let mut tick = 0u64;
    // Ticks until `done` holds for the device (checked every 10 ticks), for at most PATIENCE.
    let mut tick_until = |servo: &mut Box<dyn voxhap::servo::device::ServoDevice>,
                          what: &str,
                          done: &dyn Fn(&SpecDeviceHandle) -> bool| {
        let since = Instant::now();
        while !done(&device) {
            assert!(
                since.elapsed() < PATIENCE,
                "{PATIENCE:?} passed before {what}: {}",
                summary(&device.forces())
            );
            for _ in 0..10 {
                tick += 1;
                let deadline = start + Duration::from_micros(tick * 1_000);
                if let Some(wait) = deadline.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
                servo.exchange(TickInput::at(DVec3::new(0.8, 0.0, 0.0), tick * 1_000));
                stats.ticks.fetch_add(1, Ordering::Release);
            }
        }
    };
    // The whole 0.8 N (ramp done, up to f32 rounding) before the stall.
    tick_until(&mut servo, "the force ramped in", &|device| {
        device
            .last_force()
            .is_some_and(|f| f.enabled && f.magnitude_n() > 0.79)
    });
    let before_stall = device.forces();
    let last = *before_stall.last().expect("no SetForce before the stall");
    assert!(
        last.enabled && last.magnitude_n() > 0.5,
        "no force was being rendered before the stall: {}",
        summary(&before_stall)
    );

    // The stall: nobody ticks for 300 ms. (On a loaded machine this thread may already have overslept 20 ms
    // during the ticks above, and the monitor rightly acted then too: count only this stall.)
    let stops_before = stats.monitor_stops.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(300));
    let forces = device.forces();
    let zero = forces
        .iter()
        .find(|f| f.index > last.index && f.is_zero())
        .unwrap_or_else(|| panic!("no zero SetForce after the stall; {}", summary(&forces)));
    let took = zero.at.duration_since(last.at);
    assert!(
        took <= config.stall_after() + MARGIN,
        "the zero force came {took:?} after the last tick's force (monitor: {:?} + {MARGIN:?})",
        config.stall_after()
    );
    let messages = device.messages();
    let disable = messages
        .iter()
        .find(|m| m.index > last.index && m.message == HostMessage::Disable)
        .expect("no Disable from the monitor");
    let device_watchdog = device.sent().into_iter().find(|s| {
        s.index > last.index
            && s.message_type == types::FAULT
            && s.detail == u16::from(fault::WATCHDOG_EXPIRED)
    });
    if let Some(fired) = device_watchdog {
        assert!(
            fired.index > disable.index,
            "the device's own watchdog fired before the monitor's Disable"
        );
    }
    assert_eq!(
        stats.monitor_stops.load(Ordering::Relaxed),
        stops_before + 1,
        "one monitor stop for the stall"
    );

    // Ticking again: zero until a new Enable, then force ramps in again.
    tick_until(&mut servo, "a new Enable and force again", &|device| {
        enable_after(device, disable.index).is_some_and(|enable| {
            device
                .last_force()
                .is_some_and(|f| f.index > enable.index && f.magnitude_n() > 0.5)
        })
    });
    monitor.stop();
    servo.stop();
    device.stop();
    let forces = device.forces();
    let enable = enable_after(&device, disable.index).expect("no Enable after the stall");
    let early: Vec<_> = forces
        .iter()
        .filter(|f| f.index > disable.index && f.index < enable.index && !f.is_zero())
        .collect();
    assert!(
        early.is_empty(),
        "non-zero force before the new Enable: {early:?}"
    );
    assert!(
        forces
            .iter()
            .any(|f| f.index > enable.index && f.magnitude_n() > 0.5),
        "force never came back after the stall; {}",
        summary(&forces)
    );
    assert_slew_limited(&device);
}
