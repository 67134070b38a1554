//! Tests on real hardware, compiled only with `--features hardware-tests` (serialport-rs style). Device paths come
//! from the environment. Each test is ignored unless asked for, so a plain run lists it as ignored (with the
//! variable it needs), never as passed; asked for (`-- --include-ignored`, or `--ignored` with a test name), a
//! test whose variable is unset fails, naming the variable.
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
use voxhap::device::drivers::woodenhaptics::{self, WoodenHaptics};
use voxhap::device::transport::{HidTransport, SerialTransport};
use voxhap::device::{HapticDevice, Lifecycle};

/// The variable's value; a test asked for without it fails, naming it.
fn env(name: &str) -> String {
    std::env::var(name)
        .unwrap_or_else(|_| panic!("this hardware test needs {name}: set it (see the module docs)"))
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
#[ignore = "needs a voxhap-protocol device: set VOXHAP_TEST_SERIAL and pass --include-ignored"]
fn voxhap_protocol_device_answers() {
    let path = env("VOXHAP_TEST_SERIAL");
    let transport = SerialTransport::open(&path, 1_000_000).unwrap();
    let mut device = Lifecycle::new(ProtocolDevice::new(
        SerialLink::new(transport),
        ProtocolConfig::default(),
    ));
    exchange_zero_forces(&mut device);
}

#[test]
#[ignore = "needs a Haply 2DIY: set VOXHAP_TEST_HAPLY and pass --include-ignored"]
fn haply_2diy_answers() {
    let path = env("VOXHAP_TEST_HAPLY");
    let transport = SerialTransport::open(&path, 0).unwrap();
    let mut device = Lifecycle::new(Haply2Diy::new(transport, Haply2DiyConfig::default()));
    exchange_zero_forces(&mut device);
}

#[test]
#[ignore = "needs a WoodenHaptics 1.5: set VOXHAP_TEST_WOODENHAPTICS=1 and pass --include-ignored"]
fn woodenhaptics_answers() {
    env("VOXHAP_TEST_WOODENHAPTICS");
    let transport =
        HidTransport::open_vid_pid(woodenhaptics::VENDOR_ID, woodenhaptics::PRODUCT_ID).unwrap();
    let mut device =
        Lifecycle::new(WoodenHaptics::new(transport, woodenhaptics::KINEMATICS).unwrap());
    exchange_zero_forces(&mut device);
}
