//! The Novint Falcon driver against doubles written from libnifalcon (tests/util/falcon_firmware.rs): the
//! 16-byte frames over a real pseudo-terminal (homing, LEDs, torques, positions, the safety pipeline's zero on
//! stop), and the firmware upload over an in-memory line that carries baud rate, DTR, RTS and the latency timer.

use crate::util::falcon_firmware::{Bootloader, FalconDevice, Junk};
use crate::util::nifalcon::{self, nifalcon_exerted_force};
use crate::util::supervised::{
    check_exerted_forces, drive_through_glitches, supervisor_config, wait_for, ExertedBounds,
};
use glam::DVec3;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap::device::drivers::falcon::{
    upload_firmware, Falcon, FalconConfig, FalconPort, LOST_REPLY_AFTER,
};
use voxhap::device::drivers::in_flight::UNKNOWN_AGE;
use voxhap::device::supervisor::{Supervisor, TickInput};
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
fn last_command_settled(falcon: &FalconDevice) -> crate::util::falcon_firmware::FalconCommand {
    *falcon
        .commands_settled()
        .last()
        .expect("the double logged no command")
}

/// The double decoded every frame the driver wrote (it counts the ones it could not,
/// tests/util/falcon_firmware.rs, from libnifalcon's framing): checked once it has read them all.
fn assert_every_frame_decoded(falcon: &FalconDevice) {
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

/// The host's end of a late double's line, counting the frames the driver wrote: the index of the newest
/// command sent is what a state's age is counted against.
struct CountingPort {
    inner: SerialTransport,
    written: Arc<AtomicI64>,
}

impl CountingPort {
    fn open(falcon: &FalconDevice) -> (CountingPort, Arc<AtomicI64>) {
        let written = Arc::new(AtomicI64::new(0));
        let port = CountingPort {
            inner: SerialTransport::open(falcon.path(), 1_500_000).unwrap(),
            written: written.clone(),
        };
        (port, written)
    }
}

impl ByteTransport for CountingPort {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), voxhap::device::DeviceError> {
        self.inner.write_all(bytes)?;
        // The driver writes whole 16-byte frames.
        self.written
            .fetch_add(bytes.len() as i64 / 16, Ordering::AcqRel);
        Ok(())
    }
    fn read(
        &mut self,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, voxhap::device::DeviceError> {
        self.inner.read(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), voxhap::device::DeviceError> {
        self.inner.discard_input()
    }
}

impl FalconPort for CountingPort {
    fn set_baud(&mut self, baud: u32) -> Result<(), voxhap::device::DeviceError> {
        self.inner.set_baud(baud)
    }
    fn set_modem(&mut self, dtr: bool, rts: bool) -> Result<(), voxhap::device::DeviceError> {
        self.inner.set_modem(dtr, rts)
    }
    fn purge(&mut self) -> Result<(), voxhap::device::DeviceError> {
        self.inner.purge()
    }
    fn set_latency_timer(&mut self, ms: u8) -> Result<bool, voxhap::device::DeviceError> {
        self.inner.set_latency_timer(ms)
    }
    fn check_latency_timer(&self) -> Result<(), voxhap::device::DeviceError> {
        self.inner.check_latency_timer()
    }
}

/// A late double's driver at 1 kHz with the servo's own wait, opened and enabled, and the count of frames it
/// wrote.
fn open_late(falcon: &FalconDevice) -> (Lifecycle<Falcon<CountingPort>>, Arc<AtomicI64>) {
    *falcon.shared.homing.lock().unwrap() = 0x7;
    let (port, written) = CountingPort::open(falcon);
    let config = FalconConfig::for_period(Duration::from_millis(1));
    let mut device = Lifecycle::new(Falcon::new(port, config));
    device.open().unwrap();
    device.enable().unwrap();
    (device, written)
}

/// The state's age against the truth: the late double numbers each answer by the command it answers
/// (`[n, -n, 2n]`), so a state read when the newest command sent is number `sent` (the host's own count of
/// frames written, less one) answers command `n` and is `sent - n` ticks old. The driver may say a state is
/// older than it is (by one, after a frame it could not place), never younger; `UNKNOWN` (while it
/// resynchronises) is older than any. Returns the truth and whether the age was known.
fn check_age(
    device: &Lifecycle<Falcon<CountingPort>>,
    written: &AtomicI64,
    tick: i64,
) -> (i64, bool) {
    let answered = i64::from(device.device().last_reply().unwrap().encoders[0]);
    let sent = written.load(Ordering::Acquire) - 1;
    let truth = sent - answered;
    let reported = device.device().state_age_ticks();
    if reported == UNKNOWN_AGE {
        return (truth, false);
    }
    let reported = i64::from(reported);
    assert!(
        reported >= truth && reported <= truth + 1,
        "tick {tick}: the state answers command {answered} of {sent} ({truth} ticks old), the driver says {reported}"
    );
    (truth, true)
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
    let (mut device, written) = open_late(&falcon);
    // Every command open sent has reached the double (its answers may still be on their way).
    std::thread::sleep(Duration::from_millis(20));
    // Whether the previous tick's state was the answer to that tick's own command (on a loaded machine the
    // read can come after that answer arrived): then no earlier answer is left for this tick.
    let mut previous_was_its_own = false;
    for tick in 0..200i64 {
        let sent = written.load(Ordering::Acquire);
        wait_for("the answer to the previous command", || {
            falcon.shared.answered.load(Ordering::Acquire) >= sent as u64
        });
        device.write_force(DVec3::ZERO).unwrap();
        match device.read_state() {
            Ok(_) => {
                let (truth, known) = check_age(&device, &written, tick);
                assert!(known, "tick {tick}: an age unknown on a clean link");
                if tick > 0 {
                    assert!(truth <= 1, "tick {tick}: {truth} ticks old");
                }
                previous_was_its_own = truth == 0;
            }
            Err(e) if tick > 0 && !previous_was_its_own => {
                panic!("tick {tick}: the previous command's answer had come, yet no state: {e}")
            }
            Err(_) => previous_was_its_own = false,
        }
        device.input_checked(true);
    }
    assert_eq!(device.device().surplus_frames(), 0);
    assert_eq!(device.device().resyncs(), 0);
    assert_every_frame_decoded(&falcon);
}

/// What [`run_paced`] counted.
#[derive(Default)]
struct Paced {
    /// States whose age was checked against the truth ([`check_age`]), and states whose age the driver said
    /// was unknown.
    known: u32,
    unknown: u32,
    /// The known ones among states answering commands numbered above `clean_from`.
    known_after: u32,
    /// The newest damaged command: the line is clean after it.
    clean_from: i64,
    /// States not checked because the double had fallen behind since the driver last began a
    /// resynchronisation.
    unchecked: u32,
    /// Ticks on which the double was found to have fallen behind, and the answers garbled after that to make
    /// the driver start its count over.
    double_behind: u32,
    forced_resyncs: u32,
    /// Ticks run (20 000 when the cap ended the run before `done`).
    ticks: i64,
}

impl std::fmt::Display for Paced {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ticks: {} states of known age ({} after command {}), {} unknown, {} not checked; the double fell \
             behind on {} ticks, {} answers garbled after that",
            self.ticks,
            self.known,
            self.known_after,
            self.clean_from,
            self.unknown,
            self.unchecked,
            self.double_behind,
            self.forced_resyncs
        )
    }
}

/// Ticks a late double's driver in real time at 1 kHz with zero force until `done` (given the counts so far and
/// the commands sent) or 20 000 ticks, checking the age of every state against the truth ([`check_age`]).
///
/// Only while the double keeps up with its own model: should its thread fall `LOST_REPLY_AFTER / 2` behind on a
/// busy machine (`max_late_us`, taken every tick), its answers can come later than the link's bound, and once
/// the driver has counted from a quiet link in the meantime, an answer it reads may be one it was owed before:
/// the count is off until it resynchronises, and nothing the driver can see tells it so. States are not checked
/// from such a tick until the driver begins a resynchronisation after it. With `force_resync`, when that
/// happens on a clean line (commands above `clean_from`), the answer to a command two ahead is garbled, so the
/// driver starts its count over, and the clean line begins after it (`clean_from`, `known_after` counted
/// again).
fn run_paced(
    falcon: &FalconDevice,
    device: &mut Lifecycle<Falcon<CountingPort>>,
    written: &AtomicI64,
    clean_from: i64,
    force_resync: bool,
    done: impl Fn(&Paced, i64) -> bool,
) -> Paced {
    let period = Duration::from_millis(1);
    let behind_us = u64::try_from(LOST_REPLY_AFTER.as_micros()).unwrap() / 2;
    let start = std::time::Instant::now();
    let mut paced = Paced {
        clean_from,
        ..Paced::default()
    };
    // The driver's resynchronisations when the double was last found behind (`None`: it has kept up since the
    // driver last began one, or at all), and whether an answer was garbled for it.
    let mut behind_at_resyncs: Option<u64> = None;
    let mut forced = false;
    falcon.shared.max_late_us.store(0, Ordering::Release);
    // At most 20 000 ticks, whatever the load (a resynchronisation sends no command for 50 ms or more).
    while !done(&paced, written.load(Ordering::Acquire)) {
        if paced.ticks == 20_000 {
            break;
        }
        let tick = paced.ticks;
        let due = start + period * u32::try_from(tick).unwrap();
        if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(wait);
        }
        device.write_force(DVec3::ZERO).unwrap();
        let read = device.read_state().is_ok();
        // Taken after the read: the double records how far behind it is before it writes an answer.
        let resyncs = device.device().resyncs();
        if falcon.shared.max_late_us.swap(0, Ordering::AcqRel) >= behind_us {
            paced.double_behind += 1;
            behind_at_resyncs = Some(resyncs);
            forced = false;
        } else if behind_at_resyncs.is_some_and(|then| resyncs > then) {
            behind_at_resyncs = None;
        }
        if read && behind_at_resyncs.is_some() {
            paced.unchecked += 1;
        } else if read {
            if check_age(device, written, tick).1 {
                paced.known += 1;
                let answered = i64::from(device.device().last_reply().unwrap().encoders[0]);
                paced.known_after += u32::from(answered > paced.clean_from);
            } else {
                paced.unknown += 1;
            }
        }
        let sent = written.load(Ordering::Acquire);
        if force_resync && behind_at_resyncs.is_some() && !forced && sent > paced.clean_from {
            forced = true;
            paced.forced_resyncs += 1;
            paced.clean_from = sent + 2;
            paced.known_after = 0;
            falcon
                .shared
                .junk
                .lock()
                .unwrap()
                .insert(sent + 2, Junk::Garbled);
        }
        device.input_checked(true);
        paced.ticks += 1;
    }
    paced
}

/// The same late Falcon paced in real time at 1 kHz: every state the driver hands out is honest about its age
/// (never younger than the command it answers says), and the link's answers are all placed (none taken for a
/// frame nobody asked for).
#[test]
fn late_replies_at_a_real_1_khz_pace_carry_honest_ages() {
    let falcon = FalconDevice::start_late();
    let (mut device, written) = open_late(&falcon);
    std::thread::sleep(Duration::from_millis(20));
    let until = written.load(Ordering::Acquire) + 500;
    let paced = run_paced(&falcon, &mut device, &written, 0, false, |_, sent| {
        sent >= until
    });
    assert!(paced.known > 0, "no state checked in 500 ticks: {paced}");
    assert_eq!(device.device().surplus_frames(), 0);
    assert_every_frame_decoded(&falcon);
}

/// Damage on the line (libnifalcon's frame: 16 bytes, `<` to `>`, value bytes 0x41-0x50,
/// FalconFirmwareNovintSDK.h:29-34): junk bytes that answer nothing before an answer, answers garbled or cut
/// by inserted bytes, and a lost answer, at 1 kHz in real time. Junk and a garbled answer look alike to the
/// host; whatever it takes them for, no state it hands out may say it is younger than it is (the double numbers
/// its answers), and once the line is clean again the ages are known again: the run goes on until 10 states
/// answering commands after the last damage had their age known and checked, however late a busy machine
/// makes the double (`run_paced`), and fails if that takes 20 000 ticks.
#[test]
fn junk_on_the_line_never_makes_a_state_look_younger() {
    let falcon = FalconDevice::start_late();
    let (mut device, written) = open_late(&falcon);
    std::thread::sleep(Duration::from_millis(20));
    let first = written.load(Ordering::Acquire);
    let mut last_damaged = 0;
    {
        let mut junk = falcon.shared.junk.lock().unwrap();
        for round in 0..4i64 {
            let base = first + 50 + 150 * round;
            junk.insert(base, Junk::Before(vec![0x00, 0x41, 0x13]));
            junk.insert(base + 20, Junk::Before(vec![0x7f]));
            junk.insert(base + 21, Junk::Before(vec![0x41; 5]));
            junk.insert(base + 40, Junk::Garbled);
            junk.insert(base + 60, Junk::Inside(vec![0x13, 0x37]));
            junk.insert(base + 80, Junk::Lost);
            last_damaged = base + 80;
        }
    }
    let paced = run_paced(
        &falcon,
        &mut device,
        &written,
        last_damaged,
        true,
        |paced, _| paced.known_after >= 10,
    );
    eprintln!(
        "{paced}; {} resyncs, {} malformed frames",
        device.device().resyncs(),
        device.device().malformed_frames()
    );
    assert!(
        device.device().resyncs() >= 1,
        "the driver never doubted its count"
    );
    assert!(
        paced.known_after >= 10,
        "only {} states of known age after the line was clean again: {paced}",
        paced.known_after
    );
    // Whatever the damage on the way back, every frame the driver sent the Falcon was whole.
    assert_every_frame_decoded(&falcon);
}

/// What the Falcon receives, checked on the double's side against the settings and docs/safety.md (not the
/// driver's constants), while answers come late, then too late (5 ms: older than the staleness bound), and
/// with junk, garbled, cut and lost answers; the handle rests at a true pose, whose force libnifalcon's
/// Jacobian gives for each motor command. Every command: finite and within the 2 N limit the test sets (plus
/// the kinematic estimate's error); its rise from the previous command at most the slew limit, 0.5 N per 1 ms
/// tick (docs/safety.md, "0.5 N per ms"); zero until the host could have seen the Falcon homed (the driver's
/// only way to tell); and non-zero only if the host could have had a state at most 3 ticks old (docs/safety.md:
/// "3 periods"), i.e. an answer to one of the 4 commands before it had reached the host whole. Every 30th
/// request while force is on is not finite (infinity), and the checks hold through it.
#[test]
fn the_force_the_falcon_receives_stays_safe_through_late_and_damaged_answers() {
    let falcon = FalconDevice::start_late_at_pose();
    let pose = DVec3::new(0.005, -0.004, 0.11);
    let counts = nifalcon::ik(pose).map(|leg| nifalcon::count(leg[0]));
    *falcon.shared.encoders.lock().unwrap() = counts;
    let path = falcon.path().to_string();
    let period = Duration::from_millis(1);
    let mut supervisor = Supervisor::new(supervisor_config(2.0, 20_000), move || {
        let transport = SerialTransport::open(&path, 1_500_000)?;
        Ok(Falcon::new(transport, FalconConfig::for_period(period)))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let asked = DVec3::new(0.5, -0.3, 0.8).normalize() * 500.0;
    let start = std::time::Instant::now();
    let mut output = voxhap::device::supervisor::OutputState::Starting;
    let mut damaged = false;
    // After the scripted 3 s, a clean line until the Falcon has received 20 commands near the limit (a busy
    // machine's late answers can keep the force off for most of the script), for at most 60 s more.
    let near_limit = |c: &crate::util::falcon_firmware::Applied| {
        nifalcon_exerted_force(pose, c.motor).length() > 1.8
    };
    let (mut strong_so_far, mut counted) = (0, 0);
    for tick in 0..63_000u32 {
        if tick >= 3000 {
            let applied = falcon.shared.applied.lock().unwrap();
            strong_so_far += applied[counted..].iter().filter(|c| near_limit(c)).count();
            counted = applied.len();
            if strong_so_far >= 20 {
                break;
            }
        }
        let due = start + period * tick;
        if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(wait);
        }
        let received = falcon.shared.commands.lock().unwrap().len() as i64;
        match tick {
            // Homed after a while: the user pulls the grip out and pushes it in.
            200 => *falcon.shared.homing.lock().unwrap() = 0x7,
            // Answers 5 ms late: every state older than the bound.
            1200 => falcon.shared.extra_delay_us.store(5_000, Ordering::Release),
            1500 => falcon.shared.extra_delay_us.store(0, Ordering::Release),
            _ => {}
        }
        if tick >= 1300 && !damaged {
            damaged = true;
            let mut junk = falcon.shared.junk.lock().unwrap();
            // Junk before several answers in a row while they are too late, then more damage on time.
            for k in 0..4 {
                junk.insert(received + 2 * k, Junk::Before(vec![0x00, 0x41, 0x13]));
            }
            for (k, kind) in [Junk::Garbled, Junk::Inside(vec![0x13]), Junk::Lost]
                .into_iter()
                .enumerate()
            {
                junk.insert(received + 600 + 100 * k as i64, kind);
            }
            for k in 0..6 {
                junk.insert(received + 1000 + k, Junk::Before(vec![0x7f, 0x00]));
            }
        }
        let on = matches!(
            output,
            voxhap::device::supervisor::OutputState::RampingIn
                | voxhap::device::supervisor::OutputState::Engaged
        );
        // Every 30th request while on is not finite (a scene gone wrong): the pipeline sends zero for it
        // (docs/safety.md), and every check below holds through it.
        let force = match (on, tick % 30) {
            (false, _) => DVec3::ZERO,
            (true, 0) => DVec3::splat(f64::INFINITY),
            (true, _) => asked,
        };
        let now_us = u64::try_from(start.elapsed().as_micros()).unwrap();
        output = supervisor.tick(TickInput::at(force, now_us)).output_state;
    }
    let non_finite = supervisor.safety().counters().non_finite;
    supervisor.stop();
    last_command_settled(&falcon);
    assert!(
        non_finite > 0,
        "no request that is not finite reached the limits"
    );
    let applied = falcon.shared.applied.lock().unwrap().clone();
    let first_homed = applied
        .iter()
        .find(|c| c.homing == 0x7)
        .map(|c| c.number)
        .expect("the double never reported homed");
    let (limit_n, tolerance_n, slew_per_tick_n) = (2.0, 0.04, 0.5);
    let mut previous = 0.0f64;
    let mut strong = 0;
    for c in &applied {
        let force = nifalcon_exerted_force(pose, c.motor);
        let magnitude = force.length();
        let at = format!("command {} {:?} ({magnitude} N)", c.number, c.motor);
        assert!(force.is_finite(), "{at}");
        assert!(magnitude <= limit_n + tolerance_n, "{at} above the limit");
        assert!(
            magnitude <= previous + slew_per_tick_n + 2.0 * tolerance_n,
            "{at} rose from {previous} N"
        );
        if c.newest_delivered < first_homed {
            assert_eq!(c.motor, [0, 0, 0], "{at} before the host could see homed");
        }
        if c.motor != [0, 0, 0] {
            assert!(
                c.newest_delivered >= c.number - 4,
                "{at} while the newest answer the host could have had answers command {}",
                c.newest_delivered
            );
        }
        strong += u32::from(near_limit(c));
        previous = magnitude;
    }
    assert_eq!(
        applied.last().unwrap().motor,
        [0, 0, 0],
        "the last commands: {:?}; supervisor counters {:?}",
        &applied[applied.len().saturating_sub(5)..],
        supervisor.counters()
    );
    assert!(strong >= 20, "only {strong} commands near the limit");
    assert_every_frame_decoded(&falcon);
}
