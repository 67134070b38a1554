//! The Novint Falcon driver against a double that answers late, twice or with junk
//! (tests/util/falcon_firmware.rs, written from libnifalcon): each state's age against the newest command sent,
//! the host's count of late and surplus frames, and the force the Falcon exerts through late and damaged answers.

use crate::falcon::{assert_every_frame_decoded, last_command_settled};
use crate::util::falcon_firmware::{FalconDevice, Junk};
use crate::util::nifalcon::{self, nifalcon_exerted_force};
use crate::util::supervised::{supervisor_config, wait_for};
use glam::DVec3;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap::device::drivers::falcon::{Falcon, FalconConfig, FalconPort, LOST_REPLY_AFTER};
use voxhap::device::drivers::in_flight::UNKNOWN_AGE;
use voxhap::device::supervisor::{Supervisor, TickClock, TickInput};
use voxhap::device::transport::{ByteTransport, SerialTransport};
use voxhap::device::{HapticDevice, Lifecycle};

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
        output = supervisor
            .tick(TickInput {
                clock: TickClock::Monotonic,
                ..TickInput::at(force, now_us)
            })
            .output_state;
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
