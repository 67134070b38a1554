//! The device benchmarks' shared steps (benches/device.rs, benches/inverse3.rs): bring a driver up to
//! enabled, and one round trip (write a force, read the state that answers it).

use glam::DVec3;
use voxhap::device::{HapticDevice, Lifecycle};

/// `device` opened and enabled, through the lifecycle wrapper the servo uses; panics naming the step that
/// failed (a benchmark has no one to report to).
pub fn enabled<D: HapticDevice>(device: D) -> Lifecycle<D> {
    let mut device = Lifecycle::new(device);
    device.open().expect("open the device");
    device.enable().expect("enable the device");
    device
}

/// One round trip: a 0.1 N force along x, then the state that answers it.
pub fn round_trip<D: HapticDevice>(device: &mut Lifecycle<D>) {
    device
        .write_force(DVec3::new(0.1, 0.0, 0.0))
        .expect("write");
    std::hint::black_box(device.read_state().expect("state"));
}
