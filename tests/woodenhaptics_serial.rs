//! The WoodenHaptics/Polhem serial driver against a double of the Teensy firmware (tests/util/woody_firmware.rs,
//! written from `firmware/woody_teensy_mini/woody_teensy_mini.ino`) over a real pseudo-terminal, with the
//! supervisor's full safety pipeline. Safety is checked from the device's side: the double's log of currents.

use crate::util::woody_firmware::{FirmwareEvent, WoodyFirmware};
use glam::DVec3;
use std::time::{Duration, Instant};
use voxhap::device::drivers::woodenhaptics_serial::{
    WoodenHapticsSerial, WoodyConfig, WoodyKinematics, WoodyModel, MAX_CURRENT_MA,
};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, TickInput};
use voxhap::device::transport::SerialTransport;
use voxhap::device::Lifecycle;

fn open(path: &str) -> Lifecycle<WoodenHapticsSerial<SerialTransport>> {
    let transport = SerialTransport::open(path, 115_200).unwrap();
    let mut device = Lifecycle::new(WoodenHapticsSerial::new(transport, WoodyConfig::default()));
    device.open().unwrap();
    device
}

#[test]
fn the_model_comes_from_the_devices_report() {
    for (number, model) in [
        (1, WoodyModel::Polhem),
        (2, WoodyModel::VintagePhantom),
        (3, WoodyModel::WoodenHaptics),
    ] {
        let firmware = WoodyFirmware::start(number);
        let mut device = open(firmware.path());
        assert_eq!(device.device().model(), Some(model));
        assert_eq!(device.device().kinematics(), &model.config());
        assert_eq!(device.info().model, model.name());
        device.close().unwrap();
    }
}

#[test]
fn an_unknown_model_is_refused_at_open() {
    let firmware = WoodyFirmware::start(7);
    let transport = SerialTransport::open(firmware.path(), 115_200).unwrap();
    let mut device = Lifecycle::new(WoodenHapticsSerial::new(transport, WoodyConfig::default()));
    let error = device.open().unwrap_err().to_string();
    assert!(error.contains("unknown model"), "{error}");
}

#[test]
fn encoders_give_the_hfabapi_position_and_forces_the_jacobian_transpose_currents() {
    let firmware = WoodyFirmware::start(3);
    let mut device = open(firmware.path());
    device.enable().unwrap();
    // Home pose: hfab_api.cpp:106 adds (0, 0, -6000), so raw zeros are the right-angle pose; hfab_kinematics.cpp
    // 229-231 put the handle at (Lc - ox, 0, Ln + Lb - oz) = (0.025, 0, 0.205).
    device.write_force(DVec3::ZERO).unwrap();
    let state = device.read_state().unwrap();
    assert!(
        (state.position_m - DVec3::new(0.025, 0.0, 0.205)).length() < 1e-9,
        "{}",
        state.position_m
    );
    // 1 N along +x at that pose: motor B gets -659 mA (see the unit test's derivation from hfab_kinematics.cpp
    // 267-303 and hfab_api.cpp:245).
    device.write_force(DVec3::X).unwrap();
    device.read_state().unwrap();
    // A moved encoder changes the position as the published kinematics say.
    firmware.set_encoders([1000, 0, 0, 0, 0, 0]);
    device.write_force(DVec3::ZERO).unwrap();
    device.read_state().unwrap(); // answers with the new counts
    device.write_force(DVec3::ZERO).unwrap();
    let moved = device.read_state().unwrap();
    let k = WoodyKinematics::WOODENHAPTICS_V2015;
    let expected = k.position_m(k.joint_angles_rad([1000, 0, 0])).unwrap();
    assert!((moved.position_m - expected).length() < 1e-12);
    device.disable().unwrap();
    device.close().unwrap();
    let currents = firmware.currents();
    // open's zero, the zero, the 1 N, two zeros, and the wrapper's zero on disable.
    assert_eq!(currents[0], [0, 0, 0]);
    assert!(currents.contains(&[0, -659, 0]), "{currents:?}");
    assert_eq!(*currents.last().unwrap(), [0, 0, 0]);
    assert!(currents
        .iter()
        .all(|c| c.iter().all(|m| m.abs() <= MAX_CURRENT_MA)));
}

#[test]
fn with_the_safety_pipeline_currents_ramp_in_stay_bounded_and_end_at_zero() {
    let firmware = WoodyFirmware::start(3);
    let path = firmware.path().to_string();
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 50_000,
            max_force_n: 3.0,
            ..SafetyConfig::default()
        },
        // Enable after 5 steady ticks (the default 50 is for real sessions).
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    };
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 115_200)?;
        Ok(WoodenHapticsSerial::new(transport, WoodyConfig::default()))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let start = Instant::now();
    let mut tick = 0u64;
    while start.elapsed() < Duration::from_millis(300) {
        // Zero first (the engage rule), then a huge force with a non-finite one now and then: the pipeline must
        // clamp and zero them.
        let force = if tick < 20 {
            DVec3::ZERO
        } else if tick % 50 == 7 {
            DVec3::NAN
        } else {
            DVec3::new(500.0, 0.0, 0.0)
        };
        supervisor.tick(TickInput::at(force, tick * 1000));
        tick += 1;
        std::thread::sleep(Duration::from_millis(1));
    }
    supervisor.stop();
    let currents = firmware.currents();
    assert!(currents.len() > 100, "only {} commands", currents.len());
    // The pipeline clamps |f| to 3 N: at the home pose at most 3 N · Lb · (0.010/0.120) / 0.0259 A ≈ 1.98 A on
    // motor B, nothing on A and C.
    let limit_ma = (3.0 * 0.205 * (0.010 / 0.120) / 0.0259 * 1000.0) as i32 + 1;
    assert!(
        currents
            .iter()
            .all(|c| c.iter().all(|m| m.abs() <= limit_ma)),
        "{currents:?}"
    );
    // It ramps in (engaged at the first zero-force tick, 50 ms ramp): the first push, 20 ticks in, is at most
    // 20/50 of the clamp (plus a tick of slack); later ones reach the clamp.
    let first_push = currents.iter().find(|c| c[1] != 0).unwrap();
    assert!(first_push[1].abs() <= limit_ma * 21 / 50, "{first_push:?}");
    assert!(currents.iter().any(|c| c[1].abs() > limit_ma * 9 / 10));
    // Every stop ends with zero current.
    assert_eq!(*currents.last().unwrap(), [0, 0, 0]);
    // After the commands stop, the firmware's watchdog cuts the amplifiers.
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(firmware.events().last(), Some(&FirmwareEvent::WatchdogCut));
}

#[test]
fn a_silent_device_times_out_and_stale_replies_are_discarded_on_open() {
    let firmware = WoodyFirmware::start(3);
    let mut device = open(firmware.path());
    device.enable().unwrap();
    firmware
        .shared
        .mute
        .store(true, std::sync::atomic::Ordering::Release);
    device.write_force(DVec3::ZERO).unwrap();
    let error = device.read_state().unwrap_err();
    assert!(error.to_string().contains("did not answer"), "{error}");
    device.mark_lost();
    drop(device); // closes the port (it is opened exclusively)
    firmware
        .shared
        .mute
        .store(false, std::sync::atomic::Ordering::Release);
    // Reopen: the driver discards whatever is queued and reads the model again.
    let mut device = open(firmware.path());
    assert_eq!(device.device().model(), Some(WoodyModel::WoodenHaptics));
    device.close().unwrap();
}
