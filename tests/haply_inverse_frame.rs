//! The Haply Inverse3 against the Inverse Service double (tests/util/inverse_service.rs, written from Haply's
//! documents) on what Haply documents about frames, configuration and safety: a handle anywhere in the
//! reachable box is never refused; a mount or workspace transform "another program" left is replaced by the
//! session's preset or reported, never silently used; a type drift is named; the force that reached the arm is
//! read beside the commanded one; an e-brake on the events channel zeroes the force on the next tick, as a
//! device fault that says it was an emergency stop.

use crate::util::inverse_service::{
    stamp_of, InverseService, Transform, REACHABLE_MAX_M, REACHABLE_MIN_M,
};
use crate::util::inverse_ticks::{forced_tick, received_after_tick, settle, tick_stamped_force};
use glam::{DQuat, DVec3};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use voxhap::device::drivers::haply_inverse::{
    HaplyInverse, HaplyInverseConfig, FAULT_EMERGENCY_STOP, FAULT_MOTOR_STALL,
    FAULT_STABILITY_CEILING,
};
use voxhap::device::safety::{SafetyConfig, SafetyFlags};
use voxhap::device::supervisor::{Supervisor, SupervisorConfig, SupervisorEvent, TickInput};
use voxhap::device::transport::inverse_service::{
    Configuration, ServiceConfig, KEEPALIVE_INTERVAL,
};
use voxhap::device::{DeviceError, DeviceEvent, HapticDevice, Lifecycle, LifecycleError};

fn config(service: &InverseService) -> HaplyInverseConfig {
    HaplyInverseConfig {
        service: ServiceConfig {
            url: service.url(),
            events_url: Some(service.events_url()),
            // Patient: these tests check what comes back, not how fast.
            reply_timeout: Duration::from_secs(1),
            ..ServiceConfig::default()
        },
        reply_wait: Duration::from_secs(1),
        ..HaplyInverseConfig::default()
    }
}

/// Haply's documented example pose (docs.haply.co "WebSocket Protocol", step 1), where the double starts.
const DOCUMENTED_POSE_M: [f64; 3] = [0.0, -0.12, 0.15];

/// The pushes' force along z, tick-stamped ([`tick_stamped_force`]): under 1 N as a whole for a million ticks,
/// so the limits take it as small enough to engage on (`engage_threshold_n`, 1 N by default).
const PUSH_N: f64 = 0.995;

/// The force flows at full strength (the pushes ask for [`PUSH_N`] along z) and the service double's events channel
/// has a client: the moment to send a safety event.
fn force_flows_and_events_connected(service: &InverseService, sent_force_n: DVec3) -> bool {
    sent_force_n.z > 0.99
        && service
            .shared
            .event_clients_accepted
            .load(Ordering::Acquire)
            > 0
}

/// A supervisor for the service double's tests: a 2 N limit, a 20 ms engage ramp, and enabled after 5 steady
/// ticks (the default 50 is for real sessions).
fn quick_supervisor() -> SupervisorConfig {
    SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 20_000,
            max_force_n: 2.0,
            ..SafetyConfig::default()
        },
        steady_ticks_before_enable: 5,
        ..SupervisorConfig::default()
    }
}

#[test]
fn a_mount_another_program_left_is_replaced_by_the_sessions_preset() {
    let service = InverseService::start();
    // Haply Hub (or another program) mounted the device turned and scaled, and it persists.
    service.set_mount(Transform {
        position: DVec3::new(0.05, 0.0, -0.1),
        rotation: DQuat::from_rotation_z(0.5),
        scale: DVec3::splat(2.0),
    });
    let mut device = Lifecycle::new(HaplyInverse::new(config(&service)));
    device.open().unwrap();
    let link = device.device().link().unwrap();
    assert_eq!(link.device.configuration, Configuration::Confirmed);
    assert_eq!(service.configuration().mount, Transform::IDENTITY);
    assert_eq!(service.configuration().preset, "defaults");
    device.enable().unwrap();
    device.write_force(DVec3::ZERO).unwrap();
    let state = device.read_state().unwrap();
    device.close().unwrap();
    // The position is Haply's default frame's, not the mounted one (which would be about twice as far).
    assert!(
        (state.position_m - DVec3::from_array(DOCUMENTED_POSE_M)).length() < 1e-12,
        "{state:?}"
    );
}

#[test]
fn a_configuration_the_service_keeps_is_reported_and_not_used() {
    type SetUp = fn(&InverseService);
    let cases: [(&str, SetUp); 2] = [
        ("mount", |service| {
            service.set_mount(Transform {
                position: DVec3::new(0.05, 0.0, 0.0),
                ..Transform::IDENTITY
            })
        }),
        ("workspace transform", |service| {
            service.set_workspace_transform(Transform {
                scale: DVec3::splat(2.0),
                ..Transform::IDENTITY
            })
        }),
    ];
    for (what, set) in cases {
        let service = InverseService::start();
        // A service that ignores the session's configure (or a program that puts its own back at once).
        service
            .shared
            .keep_configuration
            .store(true, Ordering::Release);
        set(&service);
        let mut device = HaplyInverse::new(config(&service));
        let message = device.open().unwrap_err().to_string();
        assert!(message.contains(what), "{what}: {message}");
        assert!(message.contains("did not ask for"), "{message}");
        assert!(message.contains("Haply Hub"), "{message}");
        // Nothing but the set-up's zero force was ever sent.
        assert!(service.forces().iter().all(|f| *f == [0.0; 3]));
    }
}

#[test]
fn a_type_drift_is_named_not_reported_as_a_timeout() {
    let service = InverseService::start();
    service
        .shared
        .drift_position_type
        .store(true, Ordering::Release);
    let mut device = HaplyInverse::new(config(&service));
    let message = device.open().unwrap_err().to_string();
    assert!(message.contains("cursor_position"), "{message}");
    assert!(message.contains("is a string"), "{message}");
    assert!(!message.contains("µs"), "{message}");
}

/// Ticks `force` as a servo loop does (a write, then a read) until the state the driver hands out is the service
/// double's reply to one of these forces, one the double logged after the first `since`; returns that reply's
/// index (the double stamps it into x: `stamp`). Message 1 is the inventory; message k ≥ 2 answers the (k-1)-th
/// force logged, the set-up's being the first (one reply per message, one connection). The only other messages
/// are the driver's zero keepalives, so a reply to a message with a force other than zero is one to these
/// (`force` is not zero; what the driver put in the message is not compared here: that is what is checked).
///
/// One write and one read are not enough whatever the timing. The driver labels a reply it reads before it has
/// found the socket empty behind the send as answering the force before (the reply may predate the send:
/// "Labels never younger than the state", crates/device/src/drivers/haply_inverse_link.rs), so when its I/O
/// thread is kept off the CPU between the send and its first read, the prompt reply to a lone force goes
/// unrecognised, and a read that waits on gets, 100 ms later, the reply to the I/O thread's zero keepalive
/// (which has zeroed the double's arm too). So each read here waits less than the keepalive interval, and the
/// ticks go on until the state read is the reply to one of these forces (a keepalive's reply, after a stall that
/// long, is passed over).
fn read_the_reply_to(
    device: &mut Lifecycle<HaplyInverse>,
    service: &InverseService,
    force: DVec3,
    since: usize,
) -> usize {
    assert_ne!(force, DVec3::ZERO, "a zero force is a keepalive's");
    let start = Instant::now();
    let mut ticks = 0u32;
    loop {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{ticks} ticks of {force:?} and no state read answered one; the double received {:?}",
            service.forces()
        );
        ticks += 1;
        device.write_force(force).unwrap();
        let state = match device.read_state() {
            Ok(state) => state,
            // No state answering a force within the wait (the first force's reply not recognised): tick again.
            Err(LifecycleError::Device(DeviceError::Timeout { .. })) => continue,
            Err(error) => panic!("{error}"),
        };
        let index = stamp_of(state.position_m.x) as usize;
        let answered = index
            .checked_sub(2)
            .filter(|&at| at >= since)
            .and_then(|at| service.forces().get(at).copied());
        if answered.is_some_and(|sent| sent != [0.0; 3]) {
            return index;
        }
    }
}

#[test]
fn the_force_that_reached_the_arm_is_read_beside_the_commanded_one() {
    let service = InverseService::start();
    service.shared.stamp.store(true, Ordering::Release);
    // A read waits less than the keepalive interval ([`read_the_reply_to`]).
    let config = HaplyInverseConfig {
        reply_wait: KEEPALIVE_INTERVAL / 5,
        ..config(&service)
    };
    let mut device = Lifecycle::new(HaplyInverse::new(config));
    device.open().unwrap();
    device.enable().unwrap();
    let commanded = DVec3::new(0.2, -0.1, 0.7);
    let index = read_the_reply_to(&mut device, &service, commanded, service.forces().len());
    // The double's arm got what was commanded (identity frame) and reported it as current_cursor_force in the
    // reply the driver read, and the driver gives it beside the commanded one.
    let reported = service.shared.reported_forces.lock().unwrap()[index - 1];
    assert_eq!(DVec3::from_array(reported), commanded);
    assert_eq!(device.device().arm_force_n(), Some(commanded));
    // After an e-brake the arm is locked and takes nothing, whatever is commanded. (Past one more force: a
    // message the double was taking while the brake engaged may still have reached the arm.)
    service.ebrake();
    read_the_reply_to(&mut device, &service, commanded, service.forces().len() + 1);
    assert_eq!(device.device().arm_force_n(), Some(DVec3::ZERO));
    device.close().unwrap();
}

/// Each documented safety event (docs.haply.co "Events & Monitoring": `device-safety-triggered` with
/// `safety_type` `ebrake_triggered`, `stall_detected`, `stability_ceiling`) drives the force to zero from the
/// tick after the one that read it, latches its own fault bit, and every such tick's force-off cause (the value
/// the trace's `force_off_cause` column and /api/state carry, computed by the servo's tracker from the same
/// tick output) is a device fault. The fault codes and their names are voxhap's fault table
/// (docs/safety.md): 1 emergency stop, 8 motor stall, 9 stability ceiling reached.
fn a_safety_event_zeroes_the_force_as_a_device_fault(safety_type: &str, code: u8, name: &str) {
    use voxhap::api::ForceOffCause;
    use voxhap::haptics::tick::TickStatus;
    use voxhap::servo::force_off::ForceOffTracker;
    let service = InverseService::start();
    let url = (service.url(), service.events_url());
    let supervisor_config = quick_supervisor();
    let mut supervisor = Supervisor::new(supervisor_config, move || {
        let mut config = HaplyInverseConfig::default();
        config.service.url = url.0.clone();
        config.service.events_url = Some(url.1.clone());
        config.reply_wait = Duration::from_millis(20);
        Ok(HaplyInverse::new(config))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    let mut tracker = ForceOffTracker::default();
    let start = Instant::now();
    let (mut tick, mut sent, mut faulted_at) = (0u64, false, None);
    let mut causes_before = Vec::new();
    let mut after_fault = Vec::new();
    while start.elapsed() < Duration::from_secs(30) {
        tick += 1;
        let out = supervisor.tick(TickInput::at(tick_stamped_force(tick, PUSH_N), tick * 1000));
        let cause = tracker.cause(&out, TickStatus::Certified, false);
        if let Some(at) = faulted_at {
            after_fault.push((
                tick - at,
                out.sent_force_n,
                out.flags,
                out.active_faults,
                cause,
            ));
            if after_fault.len() >= 200 {
                break;
            }
        } else if sent {
            causes_before.push(cause);
        }
        // Send the event once the force flows at full strength and the events channel is connected.
        if !sent && force_flows_and_events_connected(&service, out.sent_force_n) {
            assert_eq!(cause, ForceOffCause::None, "force flows before the event");
            if safety_type == "ebrake_triggered" {
                service.ebrake();
            } else {
                service.safety_event(safety_type);
            }
            sent = true;
        }
        for event in out.events.iter() {
            if let SupervisorEvent::Device(DeviceEvent::Fault { code: got, .. }) = event {
                assert_eq!(got, code, "{safety_type}");
                faulted_at.get_or_insert(tick);
            }
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    // The service has received messages sent after the tick that read the event (before the stop's zero).
    let received_before_stop = faulted_at.map_or(0, |at| {
        received_after_tick(
            &settle(&service, |f| !received_after_tick(f, at).is_empty()),
            at,
        )
        .len()
    });
    supervisor.stop();
    assert!(sent, "{safety_type}: the force never flowed");
    assert!(
        faulted_at.is_some(),
        "{safety_type}: the event never reached the fault path"
    );
    assert_eq!(voxhap::device::info::fault_name(code), name);
    // From the tick after the one that read the event: zero force, the fault's own bit, a device fault.
    assert_eq!(after_fault.len(), 200);
    for (ticks_after, force, flags, faults, cause) in after_fault {
        assert_eq!(
            force,
            DVec3::ZERO,
            "{safety_type}: {ticks_after} ticks after"
        );
        assert!(
            flags.contains(SafetyFlags::DEVICE_FAULTED),
            "{safety_type} {ticks_after}: {flags:?}"
        );
        assert_eq!(faults, 1 << code, "{safety_type} {ticks_after}");
        assert_eq!(
            cause,
            ForceOffCause::DeviceFault,
            "{safety_type} {ticks_after}"
        );
    }
    // What the arm was sent, from the service's own log (each force carries the tick it was requested at):
    // full force before the event, and after the tick that read it, messages that are all zero.
    let at = faulted_at.unwrap();
    let forces = settle(&service, |f| f.last() == Some(&[0.0; 3]));
    assert!(
        forces.iter().any(|f| f[2] > 0.99),
        "{safety_type}: the arm never received full force"
    );
    assert!(
        received_before_stop > 0,
        "{safety_type}: the arm received nothing after tick {at}, which read the event"
    );
    let after = received_after_tick(&forces, at);
    assert!(
        after.iter().all(|f| *f == [0.0; 3]),
        "{safety_type}: after tick {at}, which read the event, the arm received {after:?}"
    );
}

#[test]
fn an_ebrake_event_zeroes_the_force_on_the_next_tick_as_an_emergency_stop() {
    a_safety_event_zeroes_the_force_as_a_device_fault(
        "ebrake_triggered",
        FAULT_EMERGENCY_STOP,
        "emergency stop",
    );
}

#[test]
fn a_stall_event_zeroes_the_force_as_a_motor_stall_fault() {
    a_safety_event_zeroes_the_force_as_a_device_fault(
        "stall_detected",
        FAULT_MOTOR_STALL,
        "motor stall",
    );
}

#[test]
fn a_stability_ceiling_event_zeroes_the_force_as_its_own_fault() {
    a_safety_event_zeroes_the_force_as_a_device_fault(
        "stability_ceiling",
        FAULT_STABILITY_CEILING,
        "stability ceiling reached",
    );
}

/// A motor stall (`stall_detected`, docs.haply.co "Events & Monitoring") is a fault until the operator clears
/// it, not until the link happens to drop: with the service restarted after the stall (the link drops and the
/// supervisor reconnects through the same settings, as `serve` does), no force goes out between the stall and
/// the operator's clear, and the stall's fault is still reported on the reconnected link; after the clear, force
/// flows again (so the zero before it was the fault's). Counted in ticks and events, not timed. Fails when the
/// supervisor forgets a fault reported by event on reconnect (force ramps in again a few ticks after the new
/// link is up).
#[test]
fn a_safety_event_stays_latched_through_a_dropped_link_until_the_operator_clears_it() {
    let mut service = InverseService::start();
    let mut config = HaplyInverseConfig::default();
    config.service.url = service.url();
    config.service.events_url = Some(service.events_url());
    config.reply_wait = Duration::from_millis(20);
    let supervisor_config = SupervisorConfig {
        reconnect_interval_us: 50_000,
        ..quick_supervisor()
    };
    let mut supervisor = Supervisor::new(supervisor_config, move || {
        Ok(HaplyInverse::new(config.clone()))
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    #[derive(PartialEq, Debug)]
    enum Phase {
        Pushing,
        Stalled,
        Restarted,
        Reconnected(u32),
        Cleared,
    }
    let mut phase = Phase::Pushing;
    let (mut tick, mut forced_while_faulted) = (0u64, Vec::new());
    let (mut faults_after_reconnect, mut stall_sent, mut clear) = (0u16, false, None);
    // The ticks that read the stall and that asked for the clear.
    let (mut stalled_at, mut cleared_at) = (0u64, 0u64);
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(60) {
        tick += 1;
        let out = supervisor.tick(TickInput::at(tick_stamped_force(tick, PUSH_N), tick * 1000));
        let faulted = out.events.iter().any(|e| match e {
            SupervisorEvent::Device(DeviceEvent::Fault { code, .. }) => code == FAULT_MOTOR_STALL,
            _ => false,
        });
        let disconnected = out
            .events
            .iter()
            .any(|e| matches!(e, SupervisorEvent::Disconnected { .. }));
        if !matches!(phase, Phase::Pushing | Phase::Cleared) && out.sent_force_n != DVec3::ZERO {
            forced_while_faulted.push((tick, format!("{phase:?}"), out.sent_force_n));
        }
        phase = match phase {
            Phase::Pushing => {
                if !stall_sent && force_flows_and_events_connected(&service, out.sent_force_n) {
                    service.safety_event("stall_detected");
                    stall_sent = true;
                }
                if faulted {
                    stalled_at = tick;
                    service.start_again();
                    Phase::Stalled
                } else {
                    Phase::Pushing
                }
            }
            Phase::Stalled if disconnected => Phase::Restarted,
            Phase::Restarted if out.connected => Phase::Reconnected(0),
            Phase::Reconnected(ticks) if ticks >= 300 => {
                faults_after_reconnect = out.active_faults;
                clear = Some(supervisor.request_clear_fault());
                cleared_at = tick;
                Phase::Cleared
            }
            Phase::Reconnected(ticks) => Phase::Reconnected(ticks + 1),
            Phase::Cleared if out.sent_force_n.z > 0.99 => break,
            other => other,
        };
        std::thread::sleep(Duration::from_micros(500));
    }
    supervisor.stop();
    assert_eq!(
        phase,
        Phase::Cleared,
        "the run did not get through its phases in 60 s"
    );
    assert!(
        forced_while_faulted.is_empty(),
        "force between the stall and the clear: {:?}",
        &forced_while_faulted[..forced_while_faulted.len().min(5)]
    );
    assert_eq!(
        faults_after_reconnect,
        1 << FAULT_MOTOR_STALL,
        "the reconnected link's latched faults"
    );
    assert_eq!(
        clear,
        Some(voxhap::device::supervisor::ClearFaultOutcome::Requested),
        "the operator's clear"
    );
    // What the arm was sent, from the service's own log (each force carries the tick it was requested at):
    // between the last force requested up to the stall's tick and the first requested after the clear, the
    // arm received messages (both links' zeros), and all of them zero.
    let forces = settle(&service, |f| f.last() == Some(&[0.0; 3]));
    let after_stall = received_after_tick(&forces, stalled_at);
    let until_clear = after_stall
        .iter()
        .position(|f| forced_tick(f).is_some_and(|tick| tick > cleared_at))
        .unwrap_or(after_stall.len());
    let latched = &after_stall[..until_clear];
    assert!(
        !latched.is_empty(),
        "the arm received nothing between the stall (tick {stalled_at}) and the clear (tick {cleared_at})"
    );
    assert!(
        latched.iter().all(|f| *f == [0.0; 3]),
        "between the stall (tick {stalled_at}) and the clear (tick {cleared_at}) the arm received {latched:?}"
    );
}

/// Watches this process (where the service double runs) for stalls: how often a thread overslept a 1 ms sleep
/// by `at_least_us` or more, and the longest it overslept (µs), i.e. how long a busy machine kept the process
/// off the CPU. Stops when finished or dropped.
struct StallWatch {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<(u32, u64)>>,
}

impl StallWatch {
    fn start(at_least_us: u64) -> StallWatch {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let (mut stalls, mut longest) = (0u32, 0u64);
            while !flag.load(Ordering::Acquire) {
                let before = Instant::now();
                std::thread::sleep(Duration::from_millis(1));
                let over = before.elapsed().saturating_sub(Duration::from_millis(1));
                let over = u64::try_from(over.as_micros()).unwrap_or(u64::MAX);
                stalls += u32::from(over >= at_least_us);
                longest = longest.max(over);
            }
            (stalls, longest)
        });
        StallWatch {
            stop,
            thread: Some(thread),
        }
    }

    /// The stalls seen and the longest one (µs).
    fn finish(mut self) -> (u32, u64) {
        self.stop.store(true, Ordering::Release);
        self.thread.take().unwrap().join().unwrap()
    }
}

impl Drop for StallWatch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
    }
}

/// `voxhap serve` against the double while the handle sweeps the whole reachable box: no position is refused
/// as implausible and the link is never dropped for the workspace (the capability box was ±0.10 m about the
/// origin, which refused Haply's own documented pose and reconnected about every 10 ms). Count-based: it runs
/// until every face of the box has been reported (within 2 mm), however slow the machine.
///
/// What holds whatever the timing: no reading is refused for the workspace (the box the driver declares holds
/// the whole reachable box), the link is never dropped for implausible positions, and the double reports only
/// while serve is connected, so the whole box was swept through the link; any drop was for replies that did
/// not come in time, and the link came back after it (a new connection to the service each time, but for a
/// drop at the very end). What holds only on a machine that does not stall: no reading refused at all, and no
/// drop. A reading older than the tick it is checked at can be refused by the speed check (at most one per
/// connection, and one per stall of serve's servo thread of 11 ms or more, are allowed). A busy machine that keeps serve's
/// servo thread or this process (where the double answers) off the CPU for as long as the link's watchdog
/// (ten failed exchanges in a row, 10 ms at 1 kHz, or no valid state for `link_timeout_us`, 20 ms) makes the
/// link drop, so each drop must have a stall of its own that long (serve's stall monitor or lateness, this
/// process's own stall watch, or the double's thread that answers the link: the process's watch is one thread,
/// and a loaded machine keeps one thread off the CPU while it runs another).
#[test]
fn serve_keeps_the_link_while_the_handle_sweeps_the_whole_reachable_box() {
    use std::io::Read as _;
    use std::process::Stdio;
    let _turn = crate::util::spec_serve::take_turn();
    let service = InverseService::start();
    service.sweep();
    // The link's watchdog: the supervisor drops it after `max_consecutive_errors` failed exchanges in a row
    // (serve ticks at 1 kHz) or `link_timeout_us` without a valid state, whichever comes first.
    let supervisor = voxhap::device::supervisor::SupervisorConfig::default();
    let watchdog_us = supervisor
        .link_timeout_us
        .min(u64::from(supervisor.max_consecutive_errors) * 1_000);
    let watch = StallWatch::start(watchdog_us);
    let mut child = crate::util::serve_headless(&format!("haply-inverse:{}", service.url()))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start voxhap serve");
    let covered = || {
        let (low, high) = service.reached();
        (0..3).all(|axis| {
            low[axis] <= REACHABLE_MIN_M[axis] + 2e-3 && high[axis] >= REACHABLE_MAX_M[axis] - 2e-3
        })
    };
    let start = Instant::now();
    while !covered() {
        if child.try_wait().unwrap().is_some() || start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "serve exited or 120 s passed; reached {:?}",
                service.reached()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: plain kill(2) on our own child's pid.
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) },
        0
    );
    let status = child.wait().unwrap();
    let mut said = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut said)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut said)
        .unwrap();
    let (process_stalls, process_longest_us) = watch.finish();
    assert!(status.success(), "{said}");
    // Whatever the timing: no reading refused for the workspace (the box the driver declares, which the input
    // checks widen by a margin, holds the whole reachable box), the link never dropped for implausible positions.
    let info = HaplyInverse::new(config(&service)).info().clone();
    assert!(
        info.workspace_min_m
            .cmple(DVec3::from_array(REACHABLE_MIN_M))
            .all()
            && info
                .workspace_max_m
                .cmpge(DVec3::from_array(REACHABLE_MAX_M))
                .all(),
        "the driver's workspace {:?} ..= {:?} does not hold the reachable box",
        info.workspace_min_m,
        info.workspace_max_m
    );
    assert!(!said.contains("implausible positions"), "{said}");
    assert!(service.forces().len() > 100, "{said}");
    let count_after = |label: &str| -> u32 {
        said.split(label)
            .nth(1)
            .and_then(|rest| rest.split(',').next()?.parse().ok())
            .unwrap_or_else(|| panic!("no {label:?} count in {said}"))
    };
    let (rejected, disconnects) = (
        count_after("positions rejected "),
        count_after("disconnects "),
    );
    let accepted = service.shared.accepted.load(Ordering::Acquire);
    // Stalls of serve's servo thread at least `at_least_us` long: its stall monitor's reports ("the servo thread
    // has not ticked for 21.8 ms"), and at least one if its lateness got that high.
    let monitor_us: Vec<f64> = said
        .lines()
        .filter_map(|l| l.split("the servo thread has not ticked for ").nth(1))
        .filter_map(|rest| rest.split(" ms").next()?.parse::<f64>().ok())
        .map(|ms| ms * 1e3)
        .collect();
    // The summary's lateness row: count, p50, p99, p99.9, max (µs).
    let serve_late_us: f64 = said
        .lines()
        .find(|l| l.starts_with("lateness "))
        .and_then(|l| l.split_whitespace().last()?.parse().ok())
        .unwrap_or_else(|| panic!("no lateness row in {said}"));
    let serve_stalls = |at_least_us: f64| {
        let reported = monitor_us.iter().filter(|&&us| us >= at_least_us).count() as u32;
        reported.max(u32::from(serve_late_us >= at_least_us))
    };
    // The speed check times each reading from the force it answers to when serve's supervisor had it in hand, so
    // neither a reading that came late in its tick (serve's servo thread kept off the CPU during the exchange,
    // which refused readings here before, at start-up too) nor an earlier one handed out again looks like a
    // jump. What it cannot see is a stall of serve's servo thread after serve read its clock and before the
    // exchange began: a reading taken after such a stall of 11 ms or more looks like a jump at the sweep's
    // peak speed, about 0.48 m/s (the three axes' 0.30, 0.28 and 0.26 m/s together; 5 m/s × 1 ms + 0.5 mm). At
    // most one per stall of 11 ms or more; a refused workspace would refuse nearly every reading of the sweep.
    assert!(
        rejected <= serve_stalls(11_000.0),
        "{rejected} positions rejected, with serve's servo thread stalled 11 ms or more only {} times (stall \
         monitor {monitor_us:?} µs, lateness at most {serve_late_us} µs)\n{said}",
        serve_stalls(11_000.0)
    );
    if rejected > 0 {
        eprintln!("{rejected} positions rejected after stalls of serve's servo thread");
    }
    if disconnects == 0 {
        assert_eq!(accepted, 1, "{said}");
        return;
    }
    // Only for replies that did not come in time, and the link came back after each drop.
    for drop in said.lines().filter(|l| l.contains("device link dropped")) {
        assert!(
            drop.contains("no valid state within the link timeout")
                || drop.contains("too many failed exchanges in a row"),
            "a drop for another reason than a late reply: {drop}\n{said}"
        );
    }
    // (A drop in the last milliseconds, after the box was covered, may still be waiting for its reconnect.)
    assert!(accepted >= disconnects, "{said}");
    // Each only after the machine stalled a side of the link for the watchdog.
    let serve_stalls = serve_stalls(watchdog_us as f64);
    let service_stalls_us = service.shared.stalls_us.lock().unwrap().clone();
    let service_stalls = service_stalls_us
        .iter()
        .filter(|&&us| us >= watchdog_us)
        .count() as u32;
    assert!(
        disconnects <= serve_stalls + process_stalls + service_stalls,
        "{disconnects} disconnects, but only {serve_stalls} stalls of serve's servo thread, {process_stalls} of \
         this process and {service_stalls} of the double's threads that answer the link as long as the link's \
         watchdog ({watchdog_us} µs): serve's stall monitor saw {monitor_us:?} µs, its lateness was at most \
         {serve_late_us} µs, this process stalled at most {process_longest_us} µs, the double's threads \
         {service_stalls_us:?} µs\n{said}"
    );
    eprintln!(
        "{disconnects} disconnects after {serve_stalls} stalls of serve, {process_stalls} of this process and \
         {service_stalls} of the double's threads; the whole box was reported"
    );
}
