//! The Novint Falcon driver against doubles written from libnifalcon (tests/util/falcon_firmware.rs): the
//! 16-byte frames over a real pseudo-terminal (homing, LEDs, torques, positions, the safety pipeline's zero on
//! stop), and the firmware upload over an in-memory line that carries baud rate, DTR, RTS and the latency timer.
//! Late, repeated and damaged answers are in `falcon_late`.

use crate::util::falcon_firmware::{Bootloader, FalconDevice};
use crate::util::nifalcon::{self, nifalcon_exerted_force};
use crate::util::supervised::{
    check_exerted_forces, drive_through_glitches, supervisor_config, wait_for, ExertedBounds,
};
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::time::Duration;
use voxhap::device::drivers::falcon::{upload_firmware, Falcon, FalconConfig, FalconPort};
use voxhap::device::supervisor::Supervisor;
use voxhap::device::transport::{ByteTransport, SerialTransport};
use voxhap::device::{DeviceEvent, HapticDevice, Lifecycle};

/// libnifalcon's LED bits, include/falcon/core/FalconFirmware.h:68-70, which FalconFirmwareNovintSDK.cpp:92 puts
/// into the control byte as they are (the comment in FalconFirmwareNovintSDK.h:55-59 lists other values; the
/// code is what the firmware receives).
const GREEN_LED: u8 = 0x2;
const RED_LED: u8 = 0x8;

fn open(path: &str) -> Lifecycle<Falcon<SerialTransport>> {
    let transport = SerialTransport::open(path, 1_500_000).unwrap();
    let mut device = Lifecycle::new(Falcon::new(transport, patient_config()));
    device.open().unwrap();
    device
}

/// The last command the double has logged once it has read every frame the host wrote
/// ([`FalconDevice::commands_settled`]): the double logs from its own thread, so right after a write the log can
/// still lack the final frame, for as long as a busy machine delays it.
pub(crate) fn last_command_settled(
    falcon: &FalconDevice,
) -> crate::util::falcon_firmware::FalconCommand {
    *falcon
        .commands_settled()
        .last()
        .expect("the double logged no command")
}

/// The double decoded every frame the driver wrote (it counts the ones it could not,
/// tests/util/falcon_firmware.rs, from libnifalcon's framing): checked once it has read them all.
pub(crate) fn assert_every_frame_decoded(falcon: &FalconDevice) {
    falcon.commands_settled();
    assert_eq!(
        falcon.undecodable_frames(),
        0,
        "the Falcon received frames it could not decode"
    );
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
        .all(|c| c.motor == [0, 0, 0] && c.homing_requested && c.leds == RED_LED));
    // The user pulls the grip out and pushes it in: the firmware reports all three motors homed.
    *falcon.shared.homing.lock().unwrap() = 0x7;
    *falcon.shared.grip.lock().unwrap() = 0x4;
    device.write_force(DVec3::ZERO).unwrap();
    let state = device.read_state().unwrap();
    assert!(device.device().is_homed());
    assert_eq!(state.buttons, 0x4);
    // The host's input checks accepted that position (the supervisor says so every tick).
    device.input_checked(true);
    device.write_force(DVec3::new(0.0, 0.0, 2.0)).unwrap();
    device.read_state().unwrap();
    let last = *falcon.commands().last().unwrap();
    // Homing mode stays requested in every frame (libnifalcon: the Falcon stays homed only so).
    assert!(last.homing_requested && last.leds == GREEN_LED, "{last:?}");
    assert!(last.motor.iter().all(|&m| m != 0), "{last:?}");
    device.disable().unwrap();
    assert_eq!(last_command_settled(&falcon).motor, [0, 0, 0]);
    assert_every_frame_decoded(&falcon);
}

#[test]
fn encoder_counts_become_the_libnifalcon_position() {
    // A true handle position, its leg angles from libnifalcon's inverse kinematics (reimplemented above from
    // FalconKinematicStamper.cpp, not the driver's) and the encoder counts that give them (FalconKinematic.h).
    let expected = DVec3::new(0.01, -0.005, 0.12);
    let counts = nifalcon::ik(expected).map(|[theta1, _, _]| nifalcon::count(theta1));
    let falcon = FalconDevice::start();
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
    let position = state.unwrap().position_m;
    assert!(
        (position - expected).length() < 5e-3,
        "{position} vs {expected}"
    );
    assert!(position.z > 0.05 && position.z < 0.2, "{position}");
    assert_every_frame_decoded(&falcon);
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
    // libnifalcon's latency timer: 16 ms for the load, 1 ms after (FalconComm.h:48, :72); both queues purged
    // before the load and after it (:47, :74).
    let line = &device.device().port().state;
    let latency = line.latency_ms.lock().unwrap().clone();
    assert_eq!(latency[latency.len() - 2..], [16, 1], "{latency:?}");
    assert!(line.purges.load(std::sync::atomic::Ordering::Acquire) >= 2);
    device.enable().unwrap();
    device.write_force(DVec3::ZERO).unwrap();
    device.read_state().unwrap();
    assert!(device.device().is_homed());
}

/// A port that gets one line setting wrong: DTR never pulsed low (`skip_dtr`), or the upload rate libnifalcon
/// calls 140 000 taken literally instead of FTDI divisor 0x15 (3 MHz / 21 = 142 857 baud).
struct WrongLine {
    line: crate::util::falcon_firmware::FalconLine,
    skip_dtr: bool,
    round_upload_baud: bool,
}

impl ByteTransport for WrongLine {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), voxhap::device::DeviceError> {
        self.line.write_all(bytes)
    }
    fn read(
        &mut self,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, voxhap::device::DeviceError> {
        self.line.read(buf, timeout)
    }
}

impl FalconPort for WrongLine {
    fn set_baud(&mut self, baud: u32) -> Result<(), voxhap::device::DeviceError> {
        let baud = if self.round_upload_baud && baud == 142_857 {
            140_000
        } else {
            baud
        };
        self.line.set_baud(baud)
    }
    fn set_modem(&mut self, dtr: bool, rts: bool) -> Result<(), voxhap::device::DeviceError> {
        if self.skip_dtr {
            return Ok(());
        }
        self.line.set_modem(dtr, rts)
    }
    fn purge(&mut self) -> Result<(), voxhap::device::DeviceError> {
        self.line.purge()
    }
    fn set_latency_timer(&mut self, ms: u8) -> Result<bool, voxhap::device::DeviceError> {
        self.line.set_latency_timer(ms)
    }
    fn check_latency_timer(&self) -> Result<(), voxhap::device::DeviceError> {
        self.line.check_latency_timer()
    }
}

/// The bootloader double can see a wrong line setting: without the DTR pulse the check is never answered,
/// at 140 000 baud the `A` is never echoed.
#[test]
fn the_bootloader_double_refuses_a_wrong_dtr_or_baud() {
    for (skip_dtr, round_upload_baud, expected) in [
        (true, false, "did not answer the check"),
        (false, true, "did not echo 'A'"),
    ] {
        let (_bootloader, line) = Bootloader::start(4);
        let mut port = WrongLine {
            line,
            skip_dtr,
            round_upload_baud,
        };
        let error = upload_firmware(&mut port, &[1, 2, 3, 4])
            .unwrap_err()
            .to_string();
        assert!(error.contains(expected), "{error}");
    }
}

/// A constant request far above the 2 N limit: at every command the Falcon receives, the force it exerts at its
/// true handle position (libnifalcon's kinematics, not voxhap's) stays within the limit and close to the
/// request, while frames carry encoder glitches and jumps.
#[test]
fn rejected_readings_never_steer_the_force_the_falcon_exerts() {
    let falcon = FalconDevice::start();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let path = falcon.path().to_string();
    let config = supervisor_config(2.0, 20_000);
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 1_500_000)?;
        // A frame waited for patiently: on a loaded machine the double may answer late, and a timeout here
        // would drop the link (what this test checks is the force, not the link's timing).
        let config = FalconConfig {
            reply_timeout: Duration::from_secs(2),
            ..FalconConfig::default()
        };
        Ok(Falcon::new(transport, config))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let asked = DVec3::new(0.5, -0.3, 0.8).normalize();
    let truth = |tick: u64| {
        let phase = tick as f64 * 2.0 * std::f64::consts::PI / 2000.0;
        DVec3::new(0.01 * phase.sin(), 0.01 * phase.cos(), 0.11)
    };
    let mut true_positions = std::collections::HashMap::new();
    drive_through_glitches(&mut supervisor, asked, |tick| {
        let p = truth(tick);
        let counts = nifalcon::ik(p).map(|leg| nifalcon::count(leg[0]));
        true_positions.insert(counts, p);
        *falcon.shared.encoders.lock().unwrap() = counts;
        if tick % 37 == 11 {
            let mut glitches = falcon.shared.glitches.lock().unwrap();
            match (tick / 37) % 3 {
                0 => glitches.push_back([counts[0] + 400, counts[1], counts[2]]),
                1 => glitches.extend([[counts[0] - 300, counts[1] + 300, counts[2]]; 3]),
                _ => glitches.extend([[counts[0], counts[1] - 500, counts[2] + 500]; 2]),
            }
        }
    });
    let applied = falcon.shared.applied.lock().unwrap().clone();
    // The driver's position is libnifalcon's Newton estimate (joint error below 0.01 rad, a few millimetres),
    // so the force it computes is exact only up to that error.
    let bounds = ExertedBounds {
        limit_n: 2.0,
        tolerance_n: 0.04,
        direction_from_n: 0.2,
        max_angle_deg: 3.0,
        strong_from_n: 1.8,
    };
    check_exerted_forces(
        &applied,
        asked,
        &bounds,
        |c| match true_positions.get(&c.true_encoders) {
            Some(&p) => Some(nifalcon_exerted_force(p, c.motor)),
            None => {
                // Before the test set a pose (open's exchanges): nothing but zero was sent.
                assert_eq!(c.motor, [0, 0, 0]);
                None
            }
        },
        |c| {
            format!(
                "at the true encoders {:?} from {:?}",
                c.true_encoders, c.motor
            )
        },
    );
    assert_every_frame_decoded(&falcon);
}

/// A Falcon that answers every frame twice: each tick's state is the frame answering that tick's command
/// (its counts are this tick's), never an older one queued behind; the extra frames are counted and reported.
/// Each step waits until the double has written its answers, so this holds whatever the load.
#[test]
fn a_falcon_that_answers_twice_builds_no_backlog_and_is_reported() {
    let falcon = FalconDevice::start();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    falcon.shared.extra_answers.store(1, Ordering::Release);
    let mut device = open(falcon.path());
    device.enable().unwrap();
    let mut reported = Vec::new();
    let mut aged_ticks = 0u32;
    for tick in 0..300i16 {
        let counts = [tick, -tick, 2 * tick];
        *falcon.shared.encoders.lock().unwrap() = counts;
        let before = falcon.shared.answered.load(Ordering::Acquire);
        device.write_force(DVec3::ZERO).unwrap();
        wait_for("the Falcon's answers", || {
            falcon.shared.answered.load(Ordering::Acquire) > before
        });
        device.read_state().unwrap();
        // A device that answers more than asked may have its extra answer taken for the next reply, one tick
        // old: once the driver has seen an extra answer, it says so (never more than one tick).
        let age = device.device().state_age_ticks();
        assert!(age <= 1, "tick {tick}: age {age}");
        aged_ticks += u32::from(age == 1);
        device.input_checked(true);
        let reply = device.device().last_reply().unwrap();
        assert_eq!(
            reply.encoders, counts,
            "tick {tick}: the state is not the answer to this tick's command"
        );
        while let Some(event) = device.take_event() {
            if let DeviceEvent::Surplus { total } = event {
                reported.push(total);
            }
        }
    }
    assert!(
        aged_ticks >= 1,
        "the driver never said a state may be a tick old"
    );
    assert!(device.device().surplus_frames() >= 299);
    assert!(reported.len() >= 2 && reported.len() <= 10, "{reported:?}");
    assert_every_frame_decoded(&falcon);
}

/// The driver's settings with the frame wait these tests were written for (5 ms, the old default): what they
/// check is not the link's timing. The servo's own wait derives from its period (`FalconConfig::for_period`).
fn patient_config() -> FalconConfig {
    FalconConfig {
        reply_timeout: Duration::from_millis(5),
        ..FalconConfig::default()
    }
}
