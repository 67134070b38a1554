//! The device-side safety invariants under random misbehaviour, in process and fast: the real servo loop
//! (`ServoLoop::step`: the scene, the pure tick, the coupling, the supervisor with its safety pipeline) on a
//! mock clock, driving a device double that logs every force it receives. Proptest draws sequences of device
//! faults (watchdog and latching), refused Enables, silences (no state for a while), hang-ups, position
//! glitches, absurd velocities, late servo ticks and operator `clear_fault` commands; every case asserts, on
//! the double's log, that no force was non-finite, above the device's maximum, rising faster than the slew
//! limit per tick, or non-zero while the device was not enabled.
//!
//! The double follows protocol/SPEC.md's device rules, not the host's code: Enable is refused while a
//! latching fault is active, its own force watchdog trips 50 ms after the last force while enabled (code 0,
//! not latching), a latching fault (code >= 1) drops Enabled and stays until ClearFault, a new session starts
//! not enabled, and every reply carries the status bits.

use glam::DVec3;
use proptest::prelude::*;
use std::collections::VecDeque;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use voxhap::clock::{Clock, MockClock};
use voxhap::device::info::MESSAGE_TYPE_ENABLE;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig};
use voxhap::device::{
    DeviceError, DeviceEvent, DeviceInfo, DeviceState, DeviceStatus, HapticDevice,
};
use voxhap::servo::runner::{CommandEnvelope, LoopIo, LoopTiming, ServoCommand, ServoLoop};
use voxhap::servo::schedule::MockWaiter;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::stats::ServoStats;

const PERIOD_NS: u64 = 1_000_000;
/// The host's default slew limit (N per ms) times the 1 ms period: the largest rise of |f| per SetForce.
const MAX_RISE_N: f64 = 0.5;
/// SPEC: the device's watchdog drops the force this long after the last SetForce while enabled.
const DEVICE_WATCHDOG_NS: u64 = 50_000_000;
const TICKS: u64 = 1_500;

/// One misbehaviour of the device, due when it has answered `at_reply` times.
#[derive(Debug, Clone, Copy)]
enum Misbehaviour {
    /// A fault: code 0 is the device watchdog (not latching), 1..=7 latch until ClearFault.
    Fault(u8),
    /// The next Enables are refused (reason 3 faulted or 4 invalid argument).
    RefuseEnables { count: u8, reason: u8 },
    /// No state for this many requests (the host times out).
    Silence(u16),
    /// The port hangs up once (the host drops the link and reopens it).
    HangUp,
    /// One sample's position is off by this much (m).
    Glitch(DVec3),
    /// The reported velocity is this (m/s) for a number of samples.
    Velocity(DVec3, u16),
}

/// One force as the device received it.
#[derive(Debug, Clone, Copy)]
struct ForceRecord {
    force_n: DVec3,
    /// The device was applying forces when this one arrived.
    enabled: bool,
}

/// The device's side: its drive state and everything it received (shared by every handle the opener makes).
struct ArmState {
    clock: Arc<MockClock>,
    script: VecDeque<(u64, Misbehaviour)>,
    replies: u64,
    enabled: bool,
    latched_faults: u16,
    watchdog_tripped: bool,
    last_force_ns: u64,
    refuse_enables: (u8, u8),
    silent_for: u16,
    hang_up: bool,
    glitch: Option<DVec3>,
    velocity: Option<(DVec3, u16)>,
    events: VecDeque<DeviceEvent>,
    log: Vec<ForceRecord>,
    info: DeviceInfo,
}

impl ArmState {
    /// Where the hand holds the handle: sweeping through the built-in scene's volume, so the rendered force
    /// reaches the device's maximum.
    fn position_m(&self, centre_m: DVec3) -> DVec3 {
        let t_s = self.clock.now_ns() as f64 * 1e-9;
        centre_m + DVec3::new(0.03 * (t_s * 4.0).sin(), 0.02 * (t_s * 3.0).cos(), 0.0)
    }

    fn velocity_m_per_s(&self) -> DVec3 {
        let t_s = self.clock.now_ns() as f64 * 1e-9;
        DVec3::new(0.12 * (t_s * 4.0).cos(), -0.06 * (t_s * 3.0).sin(), 0.0)
    }

    fn fault(&mut self, code: u8) {
        self.enabled = false;
        if code == 0 {
            self.watchdog_tripped = true;
        } else {
            self.latched_faults |= 1 << code;
        }
        self.events.push_back(DeviceEvent::Fault {
            code,
            active_faults: self.latched_faults,
        });
    }

    fn status(&self) -> DeviceStatus {
        DeviceStatus {
            enabled: self.enabled,
            faulted: self.latched_faults != 0,
            watchdog_tripped: self.watchdog_tripped,
            force_clamped: false,
            active_faults: self.latched_faults,
        }
    }
}

/// A handle of the double (the opener makes a new one per connection; all share one [`ArmState`]).
struct Arm {
    state: Arc<Mutex<ArmState>>,
    info: DeviceInfo,
    centre_m: DVec3,
}

impl HapticDevice for Arm {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn open(&mut self) -> Result<(), DeviceError> {
        let mut arm = self.state.lock().unwrap();
        arm.enabled = false;
        arm.watchdog_tripped = false;
        Ok(())
    }

    fn enable(&mut self) -> Result<(), DeviceError> {
        let mut arm = self.state.lock().unwrap();
        let refusal = if arm.latched_faults != 0 {
            Some(3)
        } else if arm.refuse_enables.0 > 0 {
            arm.refuse_enables.0 -= 1;
            Some(arm.refuse_enables.1)
        } else {
            None
        };
        match refusal {
            Some(reason) => arm.events.push_back(DeviceEvent::Rejected {
                message_type: MESSAGE_TYPE_ENABLE,
                reason,
            }),
            None => {
                arm.enabled = true;
                arm.watchdog_tripped = false;
                arm.last_force_ns = arm.clock.now_ns();
            }
        }
        Ok(())
    }

    fn disable(&mut self) -> Result<(), DeviceError> {
        self.state.lock().unwrap().enabled = false;
        Ok(())
    }

    fn close(&mut self) -> Result<(), DeviceError> {
        self.state.lock().unwrap().enabled = false;
        Ok(())
    }

    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.state.lock().unwrap().latched_faults = 0;
        Ok(())
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let mut arm = self.state.lock().unwrap();
        let now_ns = arm.clock.now_ns();
        if arm.enabled && now_ns.saturating_sub(arm.last_force_ns) > DEVICE_WATCHDOG_NS {
            arm.fault(0);
        }
        arm.last_force_ns = now_ns;
        let enabled = arm.enabled;
        arm.log.push(ForceRecord { force_n, enabled });
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let mut arm = self.state.lock().unwrap();
        arm.replies += 1;
        while arm.script.front().is_some_and(|(at, _)| *at <= arm.replies) {
            let (_, misbehaviour) = arm.script.pop_front().unwrap();
            match misbehaviour {
                Misbehaviour::Fault(code) => arm.fault(code),
                Misbehaviour::RefuseEnables { count, reason } => {
                    arm.refuse_enables = (count, reason)
                }
                Misbehaviour::Silence(requests) => arm.silent_for = requests,
                Misbehaviour::HangUp => arm.hang_up = true,
                Misbehaviour::Glitch(offset_m) => arm.glitch = Some(offset_m),
                Misbehaviour::Velocity(v, samples) => arm.velocity = Some((v, samples)),
            }
        }
        if std::mem::take(&mut arm.hang_up) {
            return Err(DeviceError::Disconnected {
                during: "reading a state",
                kind: std::io::ErrorKind::BrokenPipe,
            });
        }
        if arm.silent_for > 0 {
            arm.silent_for -= 1;
            return Err(DeviceError::Timeout {
                waited_us: 500,
                waiting_for: "a state",
            });
        }
        let mut position_m = arm.position_m(self.centre_m);
        if let Some(offset_m) = arm.glitch.take() {
            position_m += offset_m;
        }
        let velocity_m_per_s = match arm.velocity {
            Some((v, left)) => {
                arm.velocity = (left > 1).then_some((v, left - 1));
                v
            }
            None if arm.info.reports_velocity => arm.velocity_m_per_s(),
            None => DVec3::ZERO,
        };
        Ok(DeviceState {
            position_m,
            velocity_m_per_s,
            buttons: 0,
            device_time_us: Some(arm.clock.now_ns() / 1000),
            sequence: Some(arm.replies as u32),
            status: Some(arm.status()),
        })
    }

    fn take_event(&mut self) -> Option<DeviceEvent> {
        self.state.lock().unwrap().events.pop_front()
    }
}

/// What one case does to the host: the device's misbehaviour, late ticks and the operator's clear_faults.
#[derive(Debug, Clone)]
struct Case {
    max_force_n: f64,
    reports_velocity: bool,
    script: Vec<(u64, Misbehaviour)>,
    /// (tick, lateness in ms)
    late_ticks: Vec<(u64, u64)>,
    clear_fault_ticks: Vec<u64>,
}

/// Runs `case` through the servo loop for [`TICKS`] ticks and returns the device's force log.
fn run(case: &Case) -> Vec<ForceRecord> {
    let setup = SceneSetup::builtin().unwrap();
    let (min_m, max_m) = setup.volumes[0].volume.grid().bounds_world();
    let centre_m = (min_m + max_m) * 0.5;
    let bundle = setup.bundle(PERIOD_NS, 0.3, 1).unwrap();
    let clock = Arc::new(MockClock::new(0));
    let info = DeviceInfo {
        max_force_n: case.max_force_n,
        reports_velocity: case.reports_velocity,
        max_speed_m_per_s: 2.0,
        ..DeviceInfo::basic("property double", min_m - 0.5, max_m + 0.5)
    };
    let mut script = case.script.clone();
    script.sort_by_key(|(at, _)| *at);
    let state = Arc::new(Mutex::new(ArmState {
        clock: clock.clone(),
        script: script.into(),
        replies: 0,
        enabled: false,
        latched_faults: 0,
        watchdog_tripped: false,
        last_force_ns: 0,
        refuse_enables: (0, 0),
        silent_for: 0,
        hang_up: false,
        glitch: None,
        velocity: None,
        events: VecDeque::new(),
        log: Vec::new(),
        info: info.clone(),
    }));
    let opener_state = state.clone();
    let mut device = Box::new(
        Supervisor::new(SupervisorConfig::default(), move || {
            Ok(Arm {
                state: opener_state.clone(),
                info: info.clone(),
                centre_m,
            })
        })
        .unwrap(),
    );
    voxhap::servo::device::ServoDevice::connect(&mut *device, 0).unwrap();
    let (mut commands, command_rx) = rtrb::RingBuffer::new(16);
    let (events, _events_rx) = rtrb::RingBuffer::new(256);
    let (retire_tx, _retired) = rtrb::RingBuffer::new(4);
    let (sample_tx, mut samples) = rtrb::RingBuffer::new(64);
    let (snapshot_in, _snapshot) = triple_buffer::triple_buffer(&None);
    // Scene frames for the recorder: nobody reads them here; a full ring only skips frames.
    let (scene_frames, _scene_frames_rx) = rtrb::RingBuffer::new(4);
    let mut servo = ServoLoop::new(
        Box::new(bundle),
        device,
        LoopIo {
            commands: command_rx,
            command_claim: Arc::new(AtomicU64::new(0)),
            retired: retire_tx,
            samples: sample_tx,
            snapshot: snapshot_in,
            events,
            scene_frames,
        },
        Arc::new(ServoStats::new(1000.0)),
        LoopTiming {
            period_ns: PERIOD_NS,
            compute_budget_ns: 600_000,
            warm_lead_ns: 0,
        },
        PERIOD_NS,
        None,
    );
    let mut waiter = MockWaiter::new(clock.clone());
    let mut next_command_id = 0;
    let mut tick = 0;
    while tick < TICKS {
        if let Some((_, late_ms)) = case.late_ticks.iter().find(|(at, _)| *at == tick) {
            waiter.script_lateness(&[late_ms * 1_000_000]);
        }
        if case.clear_fault_ticks.contains(&tick) {
            next_command_id += 1;
            let _ = commands.push(CommandEnvelope {
                id: next_command_id,
                command: ServoCommand::ClearFault,
            });
        }
        tick = servo.step(&mut waiter) + 1;
        while samples.pop().is_ok() {}
        // The events ring is drained by the session's monitor thread; here nobody reads it, and a full ring
        // is counted, never waited on.
    }
    servo.shutdown();
    drop(servo);
    let log = std::mem::take(&mut state.lock().unwrap().log);
    log
}

/// The device-side invariants over one force log; `Err` names the first violation.
fn check_invariants(log: &[ForceRecord], max_force_n: f64) -> Result<(), String> {
    let mut previous_n = 0.0;
    for (index, record) in log.iter().enumerate() {
        let f = record.force_n;
        if !f.is_finite() {
            return Err(format!("SetForce {index}: non-finite {f:?}"));
        }
        let magnitude_n = f.length();
        if magnitude_n > max_force_n * (1.0 + 1e-9) {
            return Err(format!(
                "SetForce {index}: |f| = {magnitude_n} N above the device's {max_force_n} N"
            ));
        }
        if magnitude_n > previous_n + MAX_RISE_N + 1e-9 {
            return Err(format!(
                "SetForce {index}: |f| rose from {previous_n} N to {magnitude_n} N in one SetForce"
            ));
        }
        if !record.enabled && magnitude_n != 0.0 {
            return Err(format!(
                "SetForce {index}: {f:?} N sent while the device was not enabled"
            ));
        }
        previous_n = magnitude_n;
    }
    Ok(())
}

fn misbehaviour() -> impl Strategy<Value = Misbehaviour> {
    let axis = prop_oneof![
        Just(DVec3::X),
        Just(DVec3::Y),
        Just(DVec3::new(0.6, -0.8, 0.0))
    ];
    prop_oneof![
        (0u8..8).prop_map(Misbehaviour::Fault),
        (1u8..4, prop_oneof![Just(3u8), Just(4u8)])
            .prop_map(|(count, reason)| Misbehaviour::RefuseEnables { count, reason }),
        (1u16..60).prop_map(Misbehaviour::Silence),
        Just(Misbehaviour::HangUp),
        (axis.clone(), -0.05f64..0.05).prop_map(|(a, d)| Misbehaviour::Glitch(a * d)),
        (
            axis,
            prop_oneof![
                Just(1e30),
                Just(-1e6),
                Just(0.5),
                Just(f64::NAN),
                Just(f64::INFINITY)
            ],
            1u16..200
        )
            .prop_map(|(a, speed, samples)| Misbehaviour::Velocity(a * speed, samples)),
    ]
}

fn case() -> impl Strategy<Value = Case> {
    (
        1.0f64..8.0,
        any::<bool>(),
        proptest::collection::vec((1u64..TICKS, misbehaviour()), 0..8),
        proptest::collection::vec((1u64..TICKS, 0u64..80), 0..4),
        proptest::collection::vec(1u64..TICKS, 0..3),
    )
        .prop_map(
            |(max_force_n, reports_velocity, script, late_ticks, clear_fault_ticks)| Case {
                max_force_n,
                reports_velocity,
                script,
                late_ticks,
                clear_fault_ticks,
            },
        )
}

proptest! {
    // Each case is 1 500 servo ticks (about 15 ms optimised, a few times that in plain debug builds).
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_misbehaviour_keeps_the_device_side_invariants_in_process(case in case()) {
        let log = run(&case);
        prop_assert!(!log.is_empty(), "the device never received a force");
        if let Err(violation) = check_invariants(&log, case.max_force_n) {
            return Err(TestCaseError::fail(violation));
        }
    }
}

/// Without misbehaviour the same rig renders real force (so the invariants above are not met by a silent
/// host), and the checker catches each kind of violation.
#[test]
fn the_property_rig_renders_force_and_its_checker_catches_violations() {
    let case = Case {
        max_force_n: 3.0,
        reports_velocity: true,
        script: Vec::new(),
        late_ticks: Vec::new(),
        clear_fault_ticks: Vec::new(),
    };
    let log = run(&case);
    let peak_n = log.iter().map(|r| r.force_n.length()).fold(0.0, f64::max);
    assert!(
        peak_n > 1.0,
        "peak force {peak_n} N: the rig renders almost nothing"
    );
    assert_eq!(check_invariants(&log, 3.0), Ok(()));
    let record = |x: f64, enabled: bool| ForceRecord {
        force_n: DVec3::new(x, 0.0, 0.0),
        enabled,
    };
    for (bad, what) in [
        (vec![record(f64::NAN, true)], "non-finite"),
        (
            vec![
                record(0.4, true),
                record(0.8, true),
                record(1.2, true),
                record(1.6, true),
                record(2.0, true),
                record(2.4, true),
                record(2.8, true),
                record(3.2, true),
            ],
            "above",
        ),
        (vec![record(0.0, true), record(0.9, true)], "rose"),
        (vec![record(0.1, false)], "not enabled"),
    ] {
        let error = check_invariants(&bad, 3.0).unwrap_err();
        assert!(error.contains(what), "{error}");
    }
}
