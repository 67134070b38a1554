//! The Novint Falcon driver against doubles written from libnifalcon (tests/util/falcon_firmware.rs): the
//! 16-byte frames over a real pseudo-terminal (homing, LEDs, torques, positions, the safety pipeline's zero on
//! stop), and the firmware upload over an in-memory pipe.

use crate::util::falcon_firmware::{Bootloader, FalconDevice};
use glam::DVec3;
use std::time::Duration;
use voxhap::device::drivers::falcon::{
    forward_kinematics, leg_angle_rad, Falcon, FalconConfig, LED_GREEN, LED_RED,
};
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, TickInput};
use voxhap::device::transport::SerialTransport;
use voxhap::device::Lifecycle;

fn open(path: &str) -> Lifecycle<Falcon<SerialTransport>> {
    let transport = SerialTransport::open(path, 1_500_000).unwrap();
    let mut device = Lifecycle::new(Falcon::new(transport, FalconConfig::default()));
    device.open().unwrap();
    device
}

/// The last command the double has logged once its thread has caught up with what the host wrote: the double
/// logs from its own thread, so right after a write the log can still lack the final frame.
fn last_command_settled(falcon: &FalconDevice) -> crate::util::falcon_firmware::FalconCommand {
    let deadline = std::time::Instant::now() + Duration::from_secs(1);
    let mut count = falcon.commands().len();
    loop {
        std::thread::sleep(Duration::from_millis(20));
        let commands = falcon.commands();
        if commands.len() == count || std::time::Instant::now() > deadline {
            return *commands.last().expect("the double logged no command");
        }
        count = commands.len();
    }
}

#[test]
fn until_homed_torques_are_zero_and_the_host_asks_for_homing_with_the_red_led() {
    let falcon = FalconDevice::start();
    let mut device = open(falcon.path());
    device.enable().unwrap();
    for _ in 0..5 {
        device.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
        device.read_state().unwrap();
    }
    assert!(!device.device().is_homed());
    let commands = falcon.commands();
    assert!(commands.len() >= 6);
    assert!(commands
        .iter()
        .all(|c| c.motor == [0, 0, 0] && c.homing_requested && c.leds == LED_RED));
    // The user pulls the grip out and pushes it in: the firmware reports all three motors homed.
    *falcon.shared.homing.lock().unwrap() = 0x7;
    *falcon.shared.grip.lock().unwrap() = 0x4;
    device.write_force(DVec3::ZERO).unwrap();
    let state = device.read_state().unwrap();
    assert!(device.device().is_homed());
    assert_eq!(state.buttons, 0x4);
    device.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    device.read_state().unwrap();
    let last = *falcon.commands().last().unwrap();
    // Homing mode stays requested in every frame (libnifalcon: the Falcon stays homed only so).
    assert!(last.homing_requested && last.leds == LED_GREEN, "{last:?}");
    assert!(last.motor.iter().all(|&m| m != 0), "{last:?}");
    device.disable().unwrap();
    assert_eq!(last_command_settled(&falcon).motor, [0, 0, 0]);
}

#[test]
fn encoder_counts_become_the_libnifalcon_position() {
    let falcon = FalconDevice::start();
    let counts = [-500i16, 300, 200];
    *falcon.shared.encoders.lock().unwrap() = counts;
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let mut device = open(falcon.path());
    device.enable().unwrap();
    let mut state = None;
    // Newton steps continue from the previous position each tick, as libnifalcon's getPosition does.
    for _ in 0..20 {
        device.write_force(DVec3::ZERO).unwrap();
        state = Some(device.read_state().unwrap());
    }
    let theta = counts.map(leg_angle_rad);
    let (expected, converged) = forward_kinematics(theta, DVec3::new(0.0, 0.0, 0.08));
    assert!(converged);
    let position = state.unwrap().position_m;
    assert!(
        (position - expected).length() < 5e-3,
        "{position} vs {expected}"
    );
    assert!(position.z > 0.05 && position.z < 0.2, "{position}");
}

#[test]
fn the_supervisor_bounds_forces_and_ends_with_zero_torque() {
    let falcon = FalconDevice::start();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let path = falcon.path().to_string();
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 20_000,
            max_force_n: 2.0,
            ..SafetyConfig::default()
        },
        // Enable after 5 steady ticks (the default 50 is for real sessions).
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    };
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 1_500_000)?;
        Ok(Falcon::new(transport, FalconConfig::default()))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    for tick in 0..150u64 {
        let force = if tick < 20 {
            DVec3::ZERO
        } else if tick % 30 == 0 {
            DVec3::splat(f64::INFINITY)
        } else {
            DVec3::new(0.0, 0.0, 50.0)
        };
        supervisor.tick(TickInput::at(force, tick * 1000));
        std::thread::sleep(Duration::from_micros(500));
    }
    supervisor.stop();
    last_command_settled(&falcon);
    let commands = falcon.commands();
    // 2 N along z at the handle's pose gives this command; 50 N asked must never exceed it by much.
    let at_clamp = voxhap::device::drivers::falcon::motor_commands(
        DVec3::new(0.0, 0.0, 0.08),
        DVec3::new(0.0, 0.0, 2.0),
    );
    let bound = at_clamp.iter().map(|m| m.unsigned_abs()).max().unwrap() * 2;
    assert!(
        commands
            .iter()
            .all(|c| c.motor.iter().all(|m| m.unsigned_abs() <= bound)),
        "bound {bound}"
    );
    assert!(commands.iter().any(|c| c.motor != [0, 0, 0]));
    assert_eq!(commands.last().unwrap().motor, [0, 0, 0]);
}

#[test]
fn without_firmware_open_says_which_file_is_needed() {
    // A bootloader that never gets a file: frames go unanswered.
    let (_bootloader, pipe) = Bootloader::start(100);
    let mut device = Falcon::new(pipe, FalconConfig::default());
    let message = voxhap::device::HapticDevice::open(&mut device)
        .unwrap_err()
        .to_string();
    assert!(message.contains("firmware=FILE"), "{message}");
}

#[test]
fn the_firmware_upload_follows_libnifalcons_procedure_then_frames_flow() {
    let firmware: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("falcon_firmware.bin");
    std::fs::write(&file, &firmware).unwrap();
    let (bootloader, pipe) = Bootloader::start(firmware.len());
    *bootloader.shared.homing.lock().unwrap() = 0x7;
    let config = FalconConfig {
        firmware: Some(file),
        ..FalconConfig::default()
    };
    let mut device = Lifecycle::new(Falcon::new(pipe, config));
    device.open().unwrap();
    assert_eq!(*bootloader.shared.firmware.lock().unwrap(), firmware);
    device.enable().unwrap();
    device.write_force(DVec3::ZERO).unwrap();
    device.read_state().unwrap();
    assert!(device.device().is_homed());
}
