//! The Novint Falcon driver against doubles written from libnifalcon (tests/util/falcon_firmware.rs): the
//! 16-byte frames over a real pseudo-terminal (homing, LEDs, torques, positions, the safety pipeline's zero on
//! stop), and the firmware upload over an in-memory line that carries baud rate, DTR, RTS and the latency timer.

use crate::util::falcon_firmware::{Bootloader, FalconDevice};
use crate::util::supervised::{
    check_exerted_forces, drive_through_glitches, supervisor_config, wait_for, ExertedBounds,
};
use glam::{DMat3, DVec3};
use std::sync::atomic::Ordering;
use std::time::Duration;
use voxhap::device::drivers::falcon::{
    upload_firmware, Falcon, FalconConfig, FalconPort, LED_GREEN, LED_RED, LOST_REPLY_AFTER,
};
use voxhap::device::supervisor::{Supervisor, TickInput};
use voxhap::device::transport::{ByteTransport, SerialTransport};
use voxhap::device::{DeviceEvent, HapticDevice, Lifecycle};

// libnifalcon's geometry, include/falcon/core/FalconGeometry.h:20-36.
mod nifalcon {
    use glam::{DMat3, DVec3};
    use std::f64::consts::PI;
    const A: f64 = 0.060;
    const B: f64 = 0.1025;
    const C: f64 = 0.01443;
    const D: f64 = 0.01125;
    const E: f64 = D;
    const F: f64 = -0.025;
    const R: f64 = 0.0400;
    const S: f64 = -0.02309;
    const OFFSET_ANGLE: f64 = PI / 12.0;
    const PHY: [f64; 3] = [
        PI / 2.0 + OFFSET_ANGLE,
        -PI / 6.0 + OFFSET_ANGLE,
        -5.0 * PI / 6.0 + OFFSET_ANGLE,
    ];

    /// (θ1, θ2, θ3) of each leg at handle position `p`: FalconKinematicStamper.cpp:28-94 (`IK`).
    pub fn ik(p: DVec3) -> [[f64; 3]; 3] {
        let mut legs = [[0.0; 3]; 3];
        for (leg, phy) in PHY.iter().enumerate() {
            let u = phy.cos() * p.x + phy.sin() * p.y - R;
            let v = -phy.sin() * p.x + phy.cos() * p.y - S;
            let w = p.z;
            let t3 = ((v + F) / B).acos();
            let s3 = t3.sin();
            let shared = w * w + u * u + 2.0 * C * u + A * A + C * C
                - D * D
                - E * E
                - B * B * s3 * s3
                - 2.0 * B * E * s3
                - 2.0 * B * D * s3
                - 2.0 * D * E;
            let l0 = shared - 2.0 * A * u - 2.0 * A * C;
            let l1 = -4.0 * A * w;
            let l2 = shared + 2.0 * A * u + 2.0 * A * C;
            let t1 = ((-l1 - (l1 * l1 - 4.0 * l0 * l2).sqrt()) / (2.0 * l2)).atan() * 2.0;
            let t2 = ((-u + A * t1.cos() - C) / (-D - E - B * s3)).acos();
            legs[leg] = [t1, t2, t3];
        }
        legs
    }

    /// The rows of joint rate per handle velocity before libnifalcon inverts them
    /// (FalconKinematicStamper.cpp:101-133, `jacobian`; it returns their inverse, line 135).
    pub fn joint_rate_rows(legs: [[f64; 3]; 3]) -> DMat3 {
        let mut rows = [DVec3::ZERO; 3];
        for (leg, [t1, t2, t3]) in legs.into_iter().enumerate() {
            let den = -A * t3.sin() * (t1.sin() * t2.cos() - t2.sin() * t1.cos());
            let (sp, cp) = PHY[leg].sin_cos();
            rows[leg] = DVec3::new(
                cp * t2.cos() * t3.sin() / den - sp * t3.cos() / den,
                sp * t2.cos() * t3.sin() / den + cp * t3.cos() / den,
                t2.sin() * t2.sin() / den,
            );
        }
        DMat3::from_cols(rows[0], rows[1], rows[2]).transpose()
    }

    /// Encoder count of leg angle θ1 (inverse of FalconKinematic.h:59-62, `getTheta`).
    pub fn count(theta1: f64) -> i16 {
        let per_count_deg = (0.01425 * PI / (320.0 * 4.0)) / (PI * 0.110 / 360.0);
        ((theta1.to_degrees() - 35.0) / per_count_deg).round() as i16
    }
}

/// The force the Falcon exerts at true handle position `p` for motor commands `motor`: libnifalcon sends
/// -(J⁻¹)ᵀ f · 10 000 with J the joint-rate rows (FalconKinematicStamper.cpp:244-279), so the torque is
/// τ = -motor / 10 000 and the force f = Jᵀ τ.
fn nifalcon_exerted_force(p: DVec3, motor: [i16; 3]) -> DVec3 {
    let tau = DVec3::new(
        -f64::from(motor[0]),
        -f64::from(motor[1]),
        -f64::from(motor[2]),
    ) / 10_000.0;
    let rows: DMat3 = nifalcon::joint_rate_rows(nifalcon::ik(p));
    rows.transpose() * tau
}

fn open(path: &str) -> Lifecycle<Falcon<SerialTransport>> {
    let transport = SerialTransport::open(path, 1_500_000).unwrap();
    let mut device = Lifecycle::new(Falcon::new(transport, patient_config()));
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
    // The host's input checks accepted that position (the supervisor says so every tick).
    device.input_checked(true);
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
}

#[test]
fn the_supervisor_bounds_forces_and_ends_with_zero_torque() {
    let falcon = FalconDevice::start();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let path = falcon.path().to_string();
    let config = supervisor_config(2.0, 20_000);
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 1_500_000)?;
        Ok(Falcon::new(transport, patient_config()))
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
}

/// The driver's settings with the frame wait these tests were written for (5 ms, the old default): what they
/// check is not the link's timing. The servo's own wait derives from its period (`FalconConfig::for_period`).
fn patient_config() -> FalconConfig {
    FalconConfig {
        reply_timeout: Duration::from_millis(5),
        ..FalconConfig::default()
    }
}

/// The state's age against the truth: the late double numbers each answer by the command it answers
/// (`[n, -n, 2n]`), so a state read after command `sent` answers command `n` and is `sent - n` ticks old. The
/// driver may say a state is older than it is (by one, after a frame it could not place), never younger.
fn check_age(device: &Lifecycle<Falcon<SerialTransport>>, sent: i64, tick: i64) -> i64 {
    let answered = i64::from(device.device().last_reply().unwrap().encoders[0]);
    let truth = sent - answered;
    let reported = i64::from(device.device().state_age_ticks());
    assert!(
        reported >= truth && reported <= truth + 1,
        "tick {tick}: the state answers command {answered} of {sent} ({truth} ticks old), the driver says {reported}"
    );
    truth
}

/// A Falcon whose answers come as late as on libnifalcon's link (1-2 ms after the command: the FTDI latency
/// timer, then a USB frame; `libnifalcon_arrival`), driven at 1 kHz with the servo's own wait (0.75 ms): before
/// each command the answer to the previous one has arrived (the step waits for it, so this holds whatever the
/// load), and this tick's answer cannot come within the wait. From the second tick on (open read the answer to
/// its own command, so the first tick has no earlier one), every tick gives a state, the previous command's
/// answer, and says it is one tick old: never a miss.
#[test]
fn a_reply_later_than_the_tick_is_a_one_tick_old_state_not_a_miss() {
    let falcon = FalconDevice::start_late();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let transport = SerialTransport::open(falcon.path(), 1_500_000).unwrap();
    let config = FalconConfig::for_period(Duration::from_millis(1));
    let mut device = Lifecycle::new(Falcon::new(transport, config));
    device.open().unwrap();
    device.enable().unwrap();
    // Every command open sent has reached the double (its answers may still be on their way).
    std::thread::sleep(Duration::from_millis(20));
    let first = falcon.commands().len() as i64;
    for tick in 0..200i64 {
        let sent = first + tick;
        wait_for("the answer to the previous command", || {
            falcon.shared.answered.load(Ordering::Acquire) >= sent as u64
        });
        device.write_force(DVec3::ZERO).unwrap();
        match device.read_state() {
            Ok(_) => {
                let truth = check_age(&device, sent, tick);
                if tick > 0 {
                    assert!(truth <= 1, "tick {tick}: {truth} ticks old");
                }
            }
            Err(e) if tick > 0 => {
                panic!("tick {tick}: the previous command's answer had come, yet no state: {e}")
            }
            Err(_) => {}
        }
        device.input_checked(true);
    }
    assert_eq!(device.device().surplus_frames(), 0);
}

/// The same late Falcon paced in real time at 1 kHz: every state the driver hands out is honest about its age
/// (never younger than the command it answers says), and the link's answers are all placed (none taken for a
/// frame nobody asked for). The driver writes a reply off as lost 50 ms after its command
/// (`LOST_REPLY_AFTER`); should the double's own thread fall that far behind its model on a busy machine, its
/// answers stop being the Falcon's, and the ages are checked only up to then.
#[test]
fn late_replies_at_a_real_1_khz_pace_carry_honest_ages() {
    let falcon = FalconDevice::start_late();
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let transport = SerialTransport::open(falcon.path(), 1_500_000).unwrap();
    let period = Duration::from_millis(1);
    let mut device = Lifecycle::new(Falcon::new(transport, FalconConfig::for_period(period)));
    device.open().unwrap();
    device.enable().unwrap();
    std::thread::sleep(Duration::from_millis(20));
    let first = falcon.commands().len() as i64;
    let start = std::time::Instant::now();
    let mut states = 0;
    for tick in 0..500i64 {
        let due = start + period * u32::try_from(tick).unwrap();
        if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(wait);
        }
        device.write_force(DVec3::ZERO).unwrap();
        let double_on_time = falcon.shared.max_late_us.load(Ordering::Acquire)
            < u64::try_from(LOST_REPLY_AFTER.as_micros()).unwrap() / 2;
        if device.read_state().is_ok() && double_on_time {
            check_age(&device, first + tick, tick);
            states += 1;
        }
        device.input_checked(true);
    }
    assert!(states > 0, "no state checked in 500 ticks");
    assert_eq!(device.device().surplus_frames(), 0);
}
