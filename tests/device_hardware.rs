//! Tests on real hardware, compiled only with `--features hardware-tests` (serialport-rs style). Device paths come
//! from the environment; a test whose variable is unset prints why and returns.
//!
//! - `VOXHAP_TEST_SERIAL`: a serial port with voxhap-protocol firmware;
//! - `VOXHAP_TEST_HAPLY`: the serial port of a Haply 2DIY;
//! - `VOXHAP_TEST_WOODENHAPTICS=1`: a WoodenHaptics 1.5 is plugged in (opened by its USB id).
//!
//! Every test only reads positions and sends zero force.

#![cfg(feature = "hardware-tests")]

use glam::DVec3;
use voxhap::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap::device::drivers::protocol::{ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::drivers::woodenhaptics::{self, WoodenHaptics, WoodenHapticsConfig};
use voxhap::device::transport::{HidTransport, SerialTransport};
use voxhap::device::{HapticDevice, Lifecycle};

fn env(name: &str) -> Option<String> {
    let value = std::env::var(name).ok();
    if value.is_none() {
        eprintln!("skipping: set {name} to run this hardware test");
    }
    value
}

fn exchange_zero_forces<D: HapticDevice>(device: &mut Lifecycle<D>) {
    device.open().unwrap();
    device.enable().unwrap();
    for _ in 0..100 {
        device.write_force(DVec3::ZERO).unwrap();
        assert!(device.read_state().unwrap().position_m.is_finite());
    }
    device.close().unwrap();
}

#[test]
fn voxhap_protocol_device_answers() {
    let Some(path) = env("VOXHAP_TEST_SERIAL") else {
        return;
    };
    let transport = SerialTransport::open(&path, 1_000_000).unwrap();
    let mut device = Lifecycle::new(ProtocolDevice::new(
        SerialLink::new(transport),
        ProtocolConfig::default(),
    ));
    exchange_zero_forces(&mut device);
}

#[test]
fn haply_2diy_answers() {
    let Some(path) = env("VOXHAP_TEST_HAPLY") else {
        return;
    };
    let transport = SerialTransport::open(&path, 0).unwrap();
    let mut device = Lifecycle::new(Haply2Diy::new(transport, Haply2DiyConfig::default()));
    exchange_zero_forces(&mut device);
}

#[test]
fn woodenhaptics_answers() {
    if env("VOXHAP_TEST_WOODENHAPTICS").is_none() {
        return;
    }
    let transport =
        HidTransport::open_vid_pid(woodenhaptics::VENDOR_ID, woodenhaptics::PRODUCT_ID).unwrap();
    let mut device =
        Lifecycle::new(WoodenHaptics::new(transport, WoodenHapticsConfig::default()).unwrap());
    exchange_zero_forces(&mut device);
}
