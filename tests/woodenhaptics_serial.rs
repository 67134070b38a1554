//! The WoodenHaptics/Polhem serial driver against a double of the Teensy firmware (tests/util/woody_firmware.rs,
//! written from `firmware/woody_teensy_mini/woody_teensy_mini.ino`) over a real pseudo-terminal, with the
//! supervisor's full safety pipeline. Safety is checked from the device's side: the double's log of currents,
//! turned into the force the arm exerts at its true pose with hfabapi's own kinematics (below, not voxhap's).

use crate::util::supervised::{
    check_exerted_forces, drive_through_glitches, supervisor_config, wait_for, ExertedBounds,
};
use crate::util::woody_firmware::{FirmwareEvent, Glitch, WoodyFirmware};
use glam::{DMat3, DVec3};
use std::f64::consts::PI;
use std::sync::atomic::Ordering;
use std::time::Duration;
use voxhap::device::drivers::woodenhaptics_serial::{WoodenHapticsSerial, WoodyConfig, WoodyModel};
use voxhap::device::supervisor::{
    OutputState, Supervisor, SupervisorConfig, SupervisorEvent, TickInput,
};
use voxhap::device::transport::SerialTransport;
use voxhap::device::{DeviceEvent, HapticDevice, Lifecycle};

// hfabapi's WoodenHaptics (firmware model 3): `woodenhaptics_v2015()`, hfab_math.h:306-317, read in the order of
// the `configuration` constructor (hfab_math.h:252-271); the home offset of hfab_api.cpp:106.
const HFAB_CAPSTAN_M: [f64; 3] = [0.010, 0.010, 0.010];
const HFAB_LB_M: f64 = 0.205;
const HFAB_LC_M: f64 = 0.245;
const HFAB_BODY_M: [f64; 3] = [0.160, 0.120, 0.120];
const HFAB_TORQUE_CONSTANT: [f64; 3] = [0.0259, 0.0259, 0.0259];
const HFAB_CPR: [f64; 3] = [2000.0, 2000.0, 2000.0];
const HFAB_MOTOR_AND_BODY_ALIGNED: [bool; 3] = [false, true, true];
const HFAB_HOME: [i32; 3] = [0, 0, -6000];
const HFAB_LN_M: f64 = 0.080;
const HFAB_ORIGIN_M: [f64; 3] = [0.220, 0.000, 0.080];

/// The handle position at raw counts, hfab_kinematics.cpp:229-231 (the serial chain, origin subtracted).
fn hfab_position(raw: [i32; 3]) -> DVec3 {
    let [ta, tb, tc] = hfab_body_angles(raw);
    let reach = HFAB_LB_M * tb.sin() + HFAB_LC_M * tc.sin();
    DVec3::new(
        ta.cos() * reach - HFAB_ORIGIN_M[0],
        ta.sin() * reach - HFAB_ORIGIN_M[1],
        HFAB_LN_M + HFAB_LB_M * tb.cos() - HFAB_LC_M * tc.cos() - HFAB_ORIGIN_M[2],
    )
}

/// Body angles at raw encoder counts: hfab_api.cpp adds the home offset, then hfab_kinematics.cpp:109-111
/// (motor angle 2π e / cpr), 122-124 (dir = -1 where motor and body are aligned) and 137-139
/// (θ = dir · motor angle · d_capstan / d_body).
fn hfab_body_angles(raw: [i32; 3]) -> [f64; 3] {
    let mut theta = [0.0; 3];
    for i in 0..3 {
        let counts = f64::from(raw[i] + HFAB_HOME[i]);
        let dir = if HFAB_MOTOR_AND_BODY_ALIGNED[i] {
            -1.0
        } else {
            1.0
        };
        theta[i] = dir * (2.0 * PI * counts / HFAB_CPR[i]) * HFAB_CAPSTAN_M[i] / HFAB_BODY_M[i];
    }
    theta
}

/// The force (N) the arm exerts at raw counts `raw` when its motors carry `currents_ma`. hfabapi computes the
/// currents from a force as: joint torques t = Jᵀ f with the rows of hfab_kinematics.cpp:267-269, motor torques
/// t · dir · d_capstan / d_body (295-297), amperes = motor torque / k_t (301-303; gravity term zero, g = 0 in
/// this configuration), sent as int(A·1000) (hfab_api.cpp:244-246). This runs that chain backwards.
fn hfab_exerted_force(raw: [i32; 3], currents_ma: [i32; 3]) -> DVec3 {
    let [ta, tb, tc] = hfab_body_angles(raw);
    let mut joint = [0.0; 3];
    for i in 0..3 {
        let dir = if HFAB_MOTOR_AND_BODY_ALIGNED[i] {
            -1.0
        } else {
            1.0
        };
        let motor_torque = f64::from(currents_ma[i]) / 1000.0 * HFAB_TORQUE_CONSTANT[i];
        joint[i] = motor_torque / (dir * HFAB_CAPSTAN_M[i] / HFAB_BODY_M[i]);
    }
    let reach = HFAB_LB_M * tb.sin() + HFAB_LC_M * tc.sin();
    // Rows of Jᵀ (hfab_kinematics.cpp:267-269).
    let rows = [
        DVec3::new(-ta.sin() * reach, ta.cos() * reach, 0.0),
        DVec3::new(
            HFAB_LB_M * ta.cos() * tb.cos(),
            HFAB_LB_M * ta.sin() * tb.cos(),
            -HFAB_LB_M * tb.sin(),
        ),
        DVec3::new(
            HFAB_LC_M * ta.cos() * tc.cos(),
            HFAB_LC_M * ta.sin() * tc.cos(),
            HFAB_LC_M * tc.sin(),
        ),
    ];
    let jt = DMat3::from_cols(rows[0], rows[1], rows[2]).transpose();
    jt.inverse() * DVec3::from_array(joint)
}

fn open(path: &str) -> Lifecycle<WoodenHapticsSerial<SerialTransport>> {
    open_with(path, patient_config())
}

fn open_with(path: &str, config: WoodyConfig) -> Lifecycle<WoodenHapticsSerial<SerialTransport>> {
    let transport = SerialTransport::open(path, 115_200).unwrap();
    let mut device = Lifecycle::new(WoodenHapticsSerial::new(transport, config));
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
    let mut device = Lifecycle::new(WoodenHapticsSerial::new(transport, patient_config()));
    let error = device.open().unwrap_err().to_string();
    assert!(error.contains("unknown model"), "{error}");
}

#[test]
fn encoders_give_the_hfabapi_position_and_forces_the_jacobian_transpose_currents() {
    let firmware = WoodyFirmware::start(3);
    // Each read waits for the answer to its own command, however slow a busy machine makes it: this test checks
    // the kinematics, not the link's timing (5 ms was once too short for the double's first answer).
    let waiting = WoodyConfig {
        reply_timeout: Duration::from_secs(20),
        ..patient_config()
    };
    let mut device = open_with(firmware.path(), waiting);
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
    // The host's input checks accepted that pose (the supervisor says so every tick).
    device.input_checked(true);
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
    let expected = hfab_position([1000, 0, 0]);
    assert!((moved.position_m - expected).length() < 1e-12);
    device.disable().unwrap();
    device.close().unwrap();
    let currents = firmware.currents();
    // open's zero, the zero, the 1 N, two zeros, and the wrapper's zero on disable.
    assert_eq!(currents[0], [0, 0, 0]);
    assert!(currents.contains(&[0, -659, 0]), "{currents:?}");
    assert_eq!(*currents.last().unwrap(), [0, 0, 0]);
    // No current outside the firmware's ±6000 mA (ino:17, :510), which it would zero motor by motor.
    assert_eq!(firmware.shared.zeroed_by_check.load(Ordering::Acquire), 0);
}

#[test]
fn with_the_safety_pipeline_currents_ramp_in_stay_bounded_and_end_at_zero() {
    let firmware = WoodyFirmware::start(3);
    let path = firmware.path().to_string();
    let config = supervisor_config(3.0, 50_000);
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 115_200)?;
        Ok(WoodenHapticsSerial::new(transport, patient_config()))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    // Paced by ticks, not by the wall clock: zero while the output is not on (the engage rule), then a huge
    // force with a non-finite one now and then, which the pipeline must clamp and zero. A busy machine only
    // makes this take longer (timeouts, a dropped link and a reconnect restart the ramp).
    let mut output = OutputState::Starting;
    let mut engaged_ticks = 0;
    let mut tick = 0u64;
    while engaged_ticks < 100 && tick < 200_000 {
        let on = matches!(output, OutputState::RampingIn | OutputState::Engaged);
        let force = if !on {
            DVec3::ZERO
        } else if tick % 50 == 7 {
            DVec3::NAN
        } else {
            DVec3::new(500.0, 0.0, 0.0)
        };
        output = supervisor
            .tick(TickInput::at(force, tick * 1000))
            .output_state;
        engaged_ticks += u32::from(output == OutputState::Engaged);
        tick += 1;
    }
    assert_eq!(engaged_ticks, 100, "never engaged in {tick} ticks");
    supervisor.stop();
    // The firmware's watchdog cuts the amplifiers once the commands stop; by then it has logged every command.
    wait_for("the watchdog cut", || {
        firmware.events().last() == Some(&FirmwareEvent::WatchdogCut)
    });
    let currents = firmware.currents();
    // The pipeline clamps |f| to 3 N: at the home pose at most 3 N · Lb · (0.010/0.120) / 0.0259 A ≈ 1.98 A on
    // motor B, nothing on A and C.
    let limit_ma = (3.0 * 0.205 * (0.010 / 0.120) / 0.0259 * 1000.0) as i32 + 1;
    assert!(
        currents
            .iter()
            .all(|c| c.iter().all(|m| m.abs() <= limit_ma)),
        "{currents:?}"
    );
    // It ramps in (50 ms on the tick clock from the engaging tick; the force is asked for from the first tick
    // that ramps): the first push is at most a few ticks' share of the clamp; later ones reach the clamp.
    let first_push = currents
        .iter()
        .find(|c| c[1] != 0)
        .expect("engaged ticks sent force");
    assert!(first_push[1].abs() <= limit_ma * 3 / 50, "{first_push:?}");
    assert!(currents.iter().any(|c| c[1].abs() > limit_ma * 9 / 10));
    // Every stop ends with zero current.
    assert_eq!(*currents.last().unwrap(), [0, 0, 0]);
}

/// A constant request along an oblique direction, far above the 3 N limit: at every command, the force the arm
/// exerts at its true pose (hfabapi's kinematics, from the currents the firmware received) stays within the
/// limit and within a few degrees of the request, while replies carry glitched counts and unreadable lines.
#[test]
fn rejected_readings_never_steer_the_force_the_arm_exerts() {
    let firmware = WoodyFirmware::start(3);
    let path = firmware.path().to_string();
    let config = supervisor_config(3.0, 20_000);
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 115_200)?;
        // A reply waited for patiently: on a loaded machine the double may answer late, and a timeout here
        // would drop the link (what this test checks is the force, not the link's timing).
        let config = WoodyConfig {
            reply_timeout: Duration::from_secs(2),
            ..WoodyConfig::default()
        };
        Ok(WoodenHapticsSerial::new(transport, config))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let asked = DVec3::new(0.6, -0.48, 0.64);
    // The arm moves slowly (about 0.1 m/s at most) around a pose away from home.
    let true_counts = |tick: u64| {
        let phase = tick as f64 * 2.0 * PI / 400.0;
        [
            300 + (100.0 * phase.sin()) as i32,
            -400 + (80.0 * phase.cos()) as i32,
            500,
        ]
    };
    drive_through_glitches(&mut supervisor, asked, |tick| {
        let counts = true_counts(tick);
        firmware.set_encoders([counts[0], counts[1], counts[2], 0, 0, 0]);
        if tick % 37 == 11 {
            // Glitches far beyond what the hand can move in a few periods (3 000 counts on motor B is about
            // 16 cm), a burst of one to three, or a reading that is not numbers.
            let mut glitches = firmware.shared.glitches.lock().unwrap();
            match (tick / 37) % 4 {
                0 => glitches.push_back(Glitch::Counts([counts[0], counts[1] + 3000, counts[2]])),
                1 => glitches
                    .extend([Glitch::Counts([counts[0] - 2500, counts[1], counts[2] + 2500]); 3]),
                2 => glitches.extend([Glitch::Garbage; 2]),
                _ => glitches.extend([
                    Glitch::Counts([counts[0] + 4000, counts[1] - 3000, counts[2]]),
                    Glitch::Garbage,
                ]),
            }
        }
    });
    let applied = firmware.shared.applied.lock().unwrap().clone();
    // No current the firmware's range check (ino:17, :510) zeroed: that would change the force's direction.
    assert_eq!(firmware.shared.zeroed_by_check.load(Ordering::Acquire), 0);
    // Currents are whole milliamperes: a few mN of rounding.
    let bounds = ExertedBounds {
        limit_n: 3.0,
        tolerance_n: 0.02,
        direction_from_n: 0.3,
        max_angle_deg: 2.0,
        strong_from_n: 2.9,
    };
    check_exerted_forces(
        &applied,
        asked,
        &bounds,
        |c| Some(hfab_exerted_force(c.true_counts, c.currents_ma)),
        |c| {
            format!(
                "at the true pose {:?} from {:?}",
                c.true_counts, c.currents_ma
            )
        },
    );
}

/// A firmware that answers every message twice, or floods lines after each answer: the driver uses the reply
/// to the newest message every tick (no queue of old positions builds up), counts what it did not ask for and
/// reports it. Each step waits until the double has written all its answers to the tick's own message, so the
/// check holds whatever the machine's load.
///
/// The tick's message is counted here, not taken from the double's count of answers before the tick: the double
/// counts a message answered only after it has written the answers, and the driver may have read one already
/// (open returns on the hello's first answer), so a count read before the first tick could miss the hello's,
/// and the wait for one more answer then ended on the hello's instead of the tick's (the state then answered
/// message 2 while "the newest" was 1).
#[test]
fn a_firmware_that_answers_twice_or_floods_builds_no_backlog_and_is_reported() {
    for (answers, flood) in [(2u32, 0u32), (1, 40)] {
        let firmware = WoodyFirmware::start(3);
        firmware.shared.answers.store(answers, Ordering::Release);
        firmware.shared.flood.store(flood, Ordering::Release);
        firmware.shared.stamp.store(true, Ordering::Release);
        // Open sends one hello (one attempt, waited for as long as `wait_for` waits): message 1. Tick t sends
        // message t + 2. A read waits as long, for an answer already written (these checks are about which
        // answer the state is, not how fast it came).
        let config = WoodyConfig {
            hello_attempts: 1,
            hello_timeout: Duration::from_secs(20),
            reply_timeout: Duration::from_secs(20),
            ..patient_config()
        };
        let mut device = open_with(firmware.path(), config);
        device.enable().unwrap();
        let mut reported = Vec::new();
        let mut aged_ticks = 0u32;
        for tick in 0..300u64 {
            let newest = tick + 2;
            device.write_force(DVec3::ZERO).unwrap();
            // Every message so far is answered once the double has written its answers to this one.
            wait_for("the double's answers", || {
                firmware.shared.answered.load(Ordering::Acquire) >= newest
            });
            device.read_state().unwrap();
            // A device that answers more than asked may have its extra answer taken for the next reply, one tick
            // old: once the driver has seen an extra answer, it says so (never more than one tick).
            let age = device.device().state_age_ticks();
            assert!(age <= 1, "tick {tick}: age {age}");
            aged_ticks += u32::from(age == 1);
            device.input_checked(true);
            // Encoder 3 carries the number of the message the reply answers.
            let answered = device.device().last_report().unwrap().encoders[3];
            // No backlog: the state answers the newest message, or (when the previous message's extra answer
            // was still on its way at the drain, which scheduling decides) the one before; never older.
            let lag = newest as i64 - i64::from(answered);
            assert!(
                lag == 0 || lag == 1,
                "answers {answers}, flood {flood}, tick {tick}: the state answers message {answered}, the \
                 newest is {newest}"
            );
            while let Some(event) = device.take_event() {
                if let DeviceEvent::Surplus { total } = event {
                    reported.push(total);
                }
            }
        }
        // Every message brought (answers - 1) + flood lines nobody asked for (open's hello too).
        let per_message = u64::from(answers - 1 + flood);
        assert!(
            aged_ticks >= 1,
            "the driver never said a state may be a tick old"
        );
        let surplus = device.device().surplus_replies();
        assert!(surplus >= 300 * per_message, "{surplus}");
        // Reported at the first surplus and again as the count grows (not at every message).
        let most = 4 + surplus / 1000;
        assert!(
            reported.len() >= 2 && reported.len() as u64 <= most,
            "{reported:?}"
        );
        device.close().unwrap();
    }
}

/// Through the supervisor, the surplus is an event the session prints, and a counter.
#[test]
fn surplus_replies_reach_the_supervisors_events_and_counters() {
    let firmware = WoodyFirmware::start(3);
    firmware.shared.answers.store(2, Ordering::Release);
    let path = firmware.path().to_string();
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), move || {
        let transport = SerialTransport::open(&path, 115_200)?;
        Ok(WoodenHapticsSerial::new(transport, patient_config()))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let mut events = Vec::new();
    let mut tick = 0u64;
    while supervisor.counters().device_surplus < 10 && tick < 200_000 {
        let out = supervisor.tick(TickInput::at(DVec3::ZERO, tick * 1000));
        events.extend(out.events.iter());
        tick += 1;
    }
    supervisor.stop();
    assert!(
        supervisor.counters().device_surplus >= 10,
        "{:?}",
        supervisor.counters()
    );
    assert!(
        events.iter().any(
            |e| matches!(e, SupervisorEvent::Device(DeviceEvent::Surplus { total }) if *total >= 1)
        ),
        "{events:?}"
    );
    let text = voxhap::servo::monitor::describe(SupervisorEvent::Device(DeviceEvent::Surplus {
        total: 10,
    }));
    assert!(
        text.contains("10 message(s) more than the host asked for"),
        "{text}"
    );
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

/// A firmware that misses three replies in a row (muted) and then answers again: the first state after it may be
/// the late reply of the first of the three commands, three commands old, and the driver says so
/// (`state_age_ticks`, which the supervisor holds to its staleness bound of 3 ticks); the next clean exchange
/// is fresh again. Each step waits for the double, so this holds whatever the load.
#[test]
fn after_missed_replies_the_driver_reports_how_old_the_state_may_be() {
    let firmware = WoodyFirmware::start(3);
    // A reply waited for 1 s: the muted firmware never answers (each muted exchange costs the wait), and an
    // answering one must not time out on a loaded machine.
    let transport = SerialTransport::open(firmware.path(), 115_200).unwrap();
    let config = WoodyConfig {
        reply_timeout: Duration::from_secs(1),
        ..WoodyConfig::default()
    };
    let mut device = Lifecycle::new(WoodenHapticsSerial::new(transport, config));
    device.open().unwrap();
    device.enable().unwrap();
    let exchange = |device: &mut Lifecycle<WoodenHapticsSerial<SerialTransport>>| {
        device.write_force(DVec3::ZERO).unwrap();
        device.read_state()
    };
    exchange(&mut device).unwrap();
    assert_eq!(device.device().state_age_ticks(), 0);
    firmware.shared.mute.store(true, Ordering::Release);
    for _ in 0..3 {
        assert!(exchange(&mut device).is_err(), "a muted firmware answered");
    }
    firmware.shared.mute.store(false, Ordering::Release);
    exchange(&mut device).unwrap();
    assert_eq!(device.device().state_age_ticks(), 3);
    exchange(&mut device).unwrap();
    assert_eq!(device.device().state_age_ticks(), 0);
}

/// Under the supervisor: a state that may be older than the staleness bound (3 ticks) never computes force.
/// The firmware misses four replies in a row and answers again; the state after the gap may be the late reply
/// of the first missed command, four ticks old, so the supervisor holds the output at `StaleState` and the
/// next tick sends zero current, however hard the scene pushes. Ticks run on a virtual clock and each waits
/// for the double (2 s reply timeout), so this holds whatever the load.
#[test]
fn a_state_older_than_the_staleness_bound_never_computes_force() {
    let firmware = WoodyFirmware::start(3);
    let path = firmware.path().to_string();
    let mut config = supervisor_config(3.0, 0);
    config.max_consecutive_errors = 100;
    config.link_timeout_us = 1_000_000;
    let mut supervisor = Supervisor::new(config, move || {
        let transport = SerialTransport::open(&path, 115_200)?;
        Ok(WoodenHapticsSerial::new(
            transport,
            WoodyConfig {
                reply_timeout: Duration::from_millis(200),
                ..WoodyConfig::default()
            },
        ))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    firmware.set_encoders([300, -400, 500, 0, 0, 0]);
    let push = DVec3::new(0.0, 0.0, 1.0);
    let mut tick = 0u64;
    let mut step = |supervisor: &mut Supervisor<_, _>, force: DVec3| {
        tick += 1;
        supervisor.tick(TickInput::at(force, tick * 1000))
    };
    // Engage: zero until engaged, then a push.
    let mut engaged = false;
    for _ in 0..5_000 {
        if step(&mut supervisor, DVec3::ZERO).output_state == OutputState::Engaged {
            engaged = true;
            break;
        }
    }
    assert!(engaged, "never engaged");
    // The slew limit lets the push rise over a few ticks.
    let pushing = (0..1_000).any(|_| step(&mut supervisor, push).sent_force_n.length() > 0.5);
    assert!(pushing, "the push never reached the device");
    firmware.shared.mute.store(true, Ordering::Release);
    for _ in 0..4 {
        step(&mut supervisor, push);
    }
    firmware.shared.mute.store(false, Ordering::Release);
    let after_gap = step(&mut supervisor, push);
    assert!(after_gap.state.is_some(), "{after_gap:?}");
    assert_eq!(after_gap.output_state, OutputState::StaleState);
    let next = step(&mut supervisor, push);
    assert_eq!(next.sent_force_n, DVec3::ZERO, "{next:?}");
    supervisor.stop();
}

/// The driver's settings with the reply wait these tests were written for (5 ms, the old default): what they
/// check is not the link's timing, and a busy machine must not turn a late reply into a failure. The servo's
/// own wait derives from its period (`WoodyConfig::for_period`).
fn patient_config() -> WoodyConfig {
    WoodyConfig {
        reply_timeout: Duration::from_millis(5),
        ..WoodyConfig::default()
    }
}
