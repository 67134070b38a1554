//! The device state machine (handshake, enable, watchdog, faults, clamping, state schedule) and the host
//! bookkeeping (handshake, sequence numbers, lost and stale states), message by message with a hand-advanced clock.

use voxhap_protocol::{
    message_type, DeviceInfo, DeviceSample, DeviceSession, DeviceToHost, DriveState, Enable, Fault,
    FaultCode, FaultFlags, ForceFlags, Heartbeat, Hello, HostEvent, HostPhase, HostSession,
    HostToDevice, Label, RateSet, RejectReason, Rejected, SetForce, SetStateRate, State,
    StatusFlags, Version, DEFAULT_WATCHDOG_TIMEOUT_US, PROTOCOL_VERSION,
};

const MAX_FORCE_N: f32 = 4.0;

fn info() -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("test-arm").expect("valid label"),
        serial_number: Label::new("T-1").expect("valid label"),
        position_dof: 3,
        force_dof: 3,
        button_count: 1,
        supported_rates: RateSet::from_rates_hz(&[500, 1000]).expect("standard rates"),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: MAX_FORCE_N,
        max_stiffness_n_per_m: 1500.0,
    }
}

fn drain(device: &mut DeviceSession) -> Vec<DeviceToHost> {
    std::iter::from_fn(|| device.poll_transmit()).collect()
}

fn force(sequence: u32, force_n: [f32; 3]) -> HostToDevice {
    HostToDevice::SetForce(SetForce {
        sequence,
        force_n,
        flags: ForceFlags::EMPTY,
    })
}

fn hello() -> HostToDevice {
    HostToDevice::Hello(Hello {
        version: PROTOCOL_VERSION,
    })
}

fn enable(watchdog_timeout_us: u32) -> HostToDevice {
    HostToDevice::Enable(Enable {
        watchdog_timeout_us,
    })
}

/// A device after hello and enable at t = 0, outbox drained.
fn enabled_device() -> DeviceSession {
    let mut device = DeviceSession::new(info());
    device.on_message(&hello(), 0);
    device.on_message(&enable(0), 0);
    drain(&mut device);
    device
}

fn rejected(message_type: u8, reason: RejectReason) -> DeviceToHost {
    DeviceToHost::Rejected(Rejected {
        message_type,
        reason,
    })
}

#[test]
fn hello_answers_with_info_and_opens_the_session() {
    let mut device = DeviceSession::new(info());
    assert!(!device.is_session_open());
    device.on_message(&hello(), 10);
    assert!(device.is_session_open());
    assert_eq!(drain(&mut device), vec![DeviceToHost::DeviceInfo(info())]);
}

#[test]
fn hello_with_another_major_version_is_answered_and_refused() {
    let mut device = DeviceSession::new(info());
    let newer = Version {
        major: PROTOCOL_VERSION.major + 1,
        minor: 0,
    };
    device.on_message(&HostToDevice::Hello(Hello { version: newer }), 10);
    assert!(!device.is_session_open());
    assert_eq!(
        drain(&mut device),
        vec![
            DeviceToHost::DeviceInfo(info()),
            rejected(message_type::HELLO, RejectReason::VERSION_MISMATCH)
        ]
    );
    // A newer minor version is fine.
    let newer_minor = Version {
        major: PROTOCOL_VERSION.major,
        minor: PROTOCOL_VERSION.minor + 3,
    };
    device.on_message(
        &HostToDevice::Hello(Hello {
            version: newer_minor,
        }),
        20,
    );
    assert!(device.is_session_open());
}

#[test]
fn messages_before_hello_are_refused_and_forces_ignored() {
    let mut device = DeviceSession::new(info());
    device.on_message(&enable(0), 0);
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 0);
    device.on_message(&HostToDevice::Heartbeat(Heartbeat { counter: 5 }), 0);
    let sent = drain(&mut device);
    assert_eq!(
        sent[0],
        rejected(message_type::ENABLE, RejectReason::NO_SESSION)
    );
    assert!(matches!(sent[1], DeviceToHost::Heartbeat(reply) if reply.counter == 5));
    assert_eq!(
        sent.len(),
        2,
        "set-force before hello is counted, not answered"
    );
    assert_eq!(device.stats().forces_ignored, 1);
    assert_eq!(device.poll(1, &DeviceSample::default()), [0.0; 3]);
    assert_eq!(device.drive_state(), DriveState::Idle);
}

#[test]
fn enabled_device_applies_forces_and_answers_in_lockstep() {
    let mut device = enabled_device();
    device.on_message(&force(1, [1.0, -2.0, 0.5]), 100);
    let sample = DeviceSample {
        position_m: [0.01, 0.02, 0.03],
        velocity_m_per_s: [0.0; 3],
        buttons: 1,
    };
    assert_eq!(device.poll(150, &sample), [1.0, -2.0, 0.5]);
    let sent = drain(&mut device);
    let [DeviceToHost::State(state)] = sent[..] else {
        panic!("expected one state, got {sent:?}")
    };
    assert_eq!(state.last_force_sequence, 1);
    assert_eq!(state.position_m, sample.position_m);
    assert_eq!(state.device_time_us, 150);
    assert_eq!(state.buttons, 1);
    assert!(state
        .status
        .contains(StatusFlags::ENABLED | StatusFlags::SESSION_OPEN | StatusFlags::LOCKSTEP));
    // No set-force, no state in lockstep.
    device.poll(1_000, &sample);
    assert!(drain(&mut device).is_empty());
}

#[test]
fn watchdog_drops_force_after_the_timeout_and_reports_once() {
    let mut device = enabled_device();
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10_000);
    let sample = DeviceSample::default();
    let deadline_us = 10_000 + u64::from(DEFAULT_WATCHDOG_TIMEOUT_US);
    assert_eq!(
        device.poll(deadline_us, &sample),
        [1.0, 0.0, 0.0],
        "exactly at the timeout still holds"
    );
    drain(&mut device);
    assert_eq!(
        device.poll(deadline_us + 1, &sample),
        [0.0; 3],
        "one microsecond later it drops"
    );
    assert_eq!(device.drive_state(), DriveState::Idle);
    assert!(device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
    assert_eq!(
        drain(&mut device),
        vec![DeviceToHost::Fault(Fault {
            code: FaultCode::WATCHDOG_EXPIRED,
            active_faults: FaultFlags::EMPTY,
            device_time_us: deadline_us + 1
        })]
    );
    assert_eq!(device.stats().watchdog_trips, 1);
    // Late set-forces are not applied: the host must enable again.
    device.on_message(&force(2, [1.0, 0.0, 0.0]), deadline_us + 2);
    assert_eq!(device.poll(deadline_us + 3, &sample), [0.0; 3]);
    assert!(
        drain(&mut device)
            .iter()
            .all(|m| !matches!(m, DeviceToHost::Fault(_))),
        "reported once"
    );
    device.on_message(&enable(0), deadline_us + 4);
    assert!(!device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
    device.on_message(&force(3, [0.0, 1.0, 0.0]), deadline_us + 5);
    assert_eq!(device.poll(deadline_us + 6, &sample), [0.0, 1.0, 0.0]);
}

#[test]
fn watchdog_starts_at_enable_and_its_timeout_is_configurable() {
    let mut device = DeviceSession::new(info());
    device.on_message(&hello(), 0);
    device.on_message(&enable(5_000), 1_000);
    assert_eq!(device.watchdog_timeout_us(), 5_000);
    let sample = DeviceSample::default();
    device.poll(6_000, &sample);
    assert_eq!(device.drive_state(), DriveState::Enabled);
    device.poll(6_001, &sample);
    assert_eq!(
        device.drive_state(),
        DriveState::Idle,
        "no set-force within 5 ms of enable"
    );
}

#[test]
fn out_of_range_watchdog_timeouts_are_refused() {
    for timeout_us in [1, 999, 1_000_001, u32::MAX] {
        let mut device = DeviceSession::new(info());
        device.on_message(&hello(), 0);
        drain(&mut device);
        device.on_message(&enable(timeout_us), 0);
        assert_eq!(
            drain(&mut device),
            vec![rejected(
                message_type::ENABLE,
                RejectReason::INVALID_ARGUMENT
            )]
        );
        assert_eq!(device.drive_state(), DriveState::Idle);
    }
}

#[test]
fn forces_above_the_maximum_are_scaled_keeping_direction() {
    let mut device = enabled_device();
    device.on_message(&force(1, [30.0, 40.0, 0.0]), 10);
    let applied = device.poll(20, &DeviceSample::default());
    let norm = applied.iter().map(|f| f * f).sum::<f32>().sqrt();
    assert!((norm - MAX_FORCE_N).abs() < 1e-5, "norm {norm}");
    assert!(
        (applied[0] / applied[1] - 0.75).abs() < 1e-6,
        "direction changed: {applied:?}"
    );
    assert!(device.status().contains(StatusFlags::FORCE_CLAMPED));
    device.on_message(&force(2, [f32::MAX, -f32::MAX, f32::MAX]), 30);
    let applied = device.poll(40, &DeviceSample::default());
    let norm = applied.iter().map(|f| f * f).sum::<f32>().sqrt();
    assert!(
        (norm - MAX_FORCE_N).abs() < 1e-5,
        "huge forces clamp too: {applied:?}"
    );
    device.on_message(&force(3, [1.0, 0.0, 0.0]), 50);
    assert_eq!(device.poll(60, &DeviceSample::default()), [1.0, 0.0, 0.0]);
    assert!(!device.status().contains(StatusFlags::FORCE_CLAMPED));
}

#[test]
fn force_clamped_is_reported_only_while_a_clamped_force_is_applied() {
    let mut device = enabled_device();
    device.on_message(&force(1, [30.0, 40.0, 0.0]), 10);
    device.poll(20, &DeviceSample::default());
    assert!(device.status().contains(StatusFlags::FORCE_CLAMPED));
    // Disable applies zero: nothing is being scaled down any more (SPEC section 6, status bits).
    device.on_message(&HostToDevice::Disable, 30);
    device.poll(40, &DeviceSample::default());
    assert!(!device.status().contains(StatusFlags::FORCE_CLAMPED));
    // A latching fault likewise.
    let mut device = enabled_device();
    device.on_message(&force(1, [30.0, 40.0, 0.0]), 10);
    device.poll(20, &DeviceSample::default());
    device.raise_fault(FaultCode::OVER_CURRENT, 30);
    assert!(!device.status().contains(StatusFlags::FORCE_CLAMPED));
    assert!(device.status().contains(StatusFlags::FAULTED));
}

#[test]
fn non_finite_forces_from_a_caller_that_skipped_the_codec_are_ignored() {
    let mut device = enabled_device();
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10);
    device.on_message(&force(2, [f32::NAN, 0.0, 0.0]), 20);
    assert_eq!(device.poll(30, &DeviceSample::default()), [1.0, 0.0, 0.0]);
    assert_eq!(device.stats().forces_ignored, 1);
}

#[test]
fn latched_faults_hold_until_cleared() {
    let mut device = enabled_device();
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10);
    device.raise_fault(FaultCode::EMERGENCY_STOP, 20);
    assert_eq!(device.poll(30, &DeviceSample::default()), [0.0; 3]);
    assert_eq!(device.drive_state(), DriveState::Faulted);
    let estop = FaultFlags::of(FaultCode::EMERGENCY_STOP);
    let sent = drain(&mut device);
    assert!(sent.contains(&DeviceToHost::Fault(Fault {
        code: FaultCode::EMERGENCY_STOP,
        active_faults: estop,
        device_time_us: 20
    })));
    device.on_message(&enable(0), 40);
    assert_eq!(
        drain(&mut device),
        vec![rejected(message_type::ENABLE, RejectReason::FAULTED)]
    );
    device.on_message(&HostToDevice::Disable, 45);
    assert_eq!(
        device.drive_state(),
        DriveState::Faulted,
        "disable does not clear a fault"
    );
    device.on_message(&HostToDevice::ClearFault, 50);
    assert_eq!(
        (device.drive_state(), device.faults()),
        (DriveState::Idle, FaultFlags::EMPTY)
    );
    device.on_message(&enable(0), 60);
    assert_eq!(device.drive_state(), DriveState::Enabled);
}

#[test]
fn non_finite_samples_raise_an_encoder_fault_instead_of_a_state() {
    let mut device = enabled_device();
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10);
    let bad = DeviceSample {
        position_m: [f32::NAN, 0.0, 0.0],
        ..DeviceSample::default()
    };
    assert_eq!(device.poll(20, &bad), [0.0; 3]);
    let sent = drain(&mut device);
    assert!(
        matches!(
            sent[..],
            [DeviceToHost::Fault(Fault {
                code: FaultCode::ENCODER,
                ..
            })]
        ),
        "{sent:?}"
    );
    device.poll(30, &bad);
    assert!(
        drain(&mut device).is_empty(),
        "the same fault is not reported every cycle"
    );
}

#[test]
fn streaming_rate_sends_states_on_schedule_without_bursts() {
    let mut device = enabled_device();
    device.on_message(
        &HostToDevice::SetStateRate(SetStateRate {
            state_rate_hz: 1000,
        }),
        0,
    );
    assert!(drain(&mut device).is_empty());
    let sample = DeviceSample::default();
    let mut states = 0;
    for tick in 0..40u64 {
        let now_us = tick * 250;
        device.on_message(&force(tick as u32 + 1, [0.0; 3]), now_us);
        device.poll(now_us, &sample);
        states += drain(&mut device)
            .iter()
            .filter(|m| matches!(m, DeviceToHost::State(_)))
            .count();
    }
    assert_eq!(states, 10, "one state per millisecond over 0..10 ms");
    assert!(!device.status().contains(StatusFlags::LOCKSTEP));
    // A 20 ms stall gives one state, not twenty.
    device.on_message(&force(100, [0.0; 3]), 30_000);
    device.poll(30_000, &sample);
    assert_eq!(drain(&mut device).len(), 1);
    device.poll(30_500, &sample);
    assert!(drain(&mut device).is_empty(), "next state is due at 31 ms");
    device.poll(31_000, &sample);
    assert_eq!(drain(&mut device).len(), 1);
    // REQUEST_STATE asks for one more in between.
    let request = SetForce {
        sequence: 101,
        force_n: [0.0; 3],
        flags: ForceFlags::REQUEST_STATE,
    };
    device.on_message(&HostToDevice::SetForce(request), 31_100);
    device.poll(31_100, &sample);
    assert_eq!(drain(&mut device).len(), 1);
}

#[test]
fn unsupported_state_rates_are_refused() {
    let mut device = enabled_device();
    device.on_message(
        &HostToDevice::SetStateRate(SetStateRate { state_rate_hz: 250 }),
        0,
    );
    assert_eq!(
        drain(&mut device),
        vec![rejected(
            message_type::SET_STATE_RATE,
            RejectReason::INVALID_ARGUMENT
        )]
    );
    assert_eq!(device.state_rate_hz(), 0);
}

#[test]
fn a_new_hello_disables_and_resets_the_session() {
    let mut device = enabled_device();
    device.on_message(
        &HostToDevice::SetStateRate(SetStateRate { state_rate_hz: 500 }),
        0,
    );
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10);
    device.on_message(&hello(), 20);
    assert_eq!(device.drive_state(), DriveState::Idle);
    assert_eq!(device.state_rate_hz(), 0);
    assert_eq!(device.poll(30, &DeviceSample::default()), [0.0; 3]);
}

#[test]
fn a_full_outbox_drops_and_counts() {
    let mut device = DeviceSession::new(info());
    for counter in 0..20 {
        device.on_message(&HostToDevice::Heartbeat(Heartbeat { counter }), 0);
    }
    let sent = drain(&mut device);
    assert_eq!(sent.len(), voxhap_protocol::device::OUTBOX_CAPACITY);
    assert!(
        matches!(sent[0], DeviceToHost::Heartbeat(reply) if reply.counter == 0),
        "oldest kept first"
    );
    assert_eq!(device.stats().outbox_overflows, 20 - sent.len() as u64);
}

fn state(sequence: u32, last_force_sequence: u32) -> DeviceToHost {
    DeviceToHost::State(State {
        sequence,
        device_time_us: 0,
        position_m: [0.0; 3],
        velocity_m_per_s: [0.0; 3],
        last_force_sequence,
        buttons: 0,
        status: StatusFlags::EMPTY,
        faults: FaultFlags::EMPTY,
    })
}

#[test]
fn host_handshake_tracks_compatibility() {
    let mut host = HostSession::new();
    assert_eq!(host.hello(), hello());
    assert_eq!(host.phase(), HostPhase::AwaitingInfo);
    assert_eq!(
        host.on_message(&DeviceToHost::DeviceInfo(info())),
        HostEvent::Connected(info())
    );
    assert_eq!(host.phase(), HostPhase::Ready);
    let other = DeviceInfo {
        version: Version { major: 9, minor: 0 },
        ..info()
    };
    assert_eq!(
        host.on_message(&DeviceToHost::DeviceInfo(other)),
        HostEvent::Incompatible(other)
    );
    assert_eq!(host.phase(), HostPhase::Incompatible);
}

#[test]
fn host_counts_lost_and_stale_states_across_wrap_around() {
    let mut host = HostSession::new();
    let lost_of = |event| match event {
        HostEvent::State { lost, .. } => Some(lost),
        _ => None,
    };
    assert_eq!(lost_of(host.on_message(&state(u32::MAX - 1, 0))), Some(0));
    assert_eq!(lost_of(host.on_message(&state(u32::MAX, 0))), Some(0));
    assert_eq!(
        lost_of(host.on_message(&state(2, 0))),
        Some(2),
        "0 and 1 lost across the wrap"
    );
    assert!(matches!(
        host.on_message(&state(1, 0)),
        HostEvent::StaleState(_)
    ));
    assert!(
        matches!(host.on_message(&state(2, 0)), HostEvent::StaleState(_)),
        "duplicate"
    );
    assert_eq!(lost_of(host.on_message(&state(3, 0))), Some(0));
    let stats = host.stats();
    assert_eq!(
        (stats.states_received, stats.states_lost, stats.states_stale),
        (4, 2, 2)
    );
}

#[test]
fn host_numbers_forces_and_tracks_acknowledgements() {
    let mut host = HostSession::new();
    for expected in 1..=5u32 {
        let HostToDevice::SetForce(set_force) = host.set_force([0.0; 3], ForceFlags::EMPTY) else {
            panic!("set_force builds a set-force")
        };
        assert_eq!(set_force.sequence, expected);
    }
    assert_eq!(host.forces_in_flight(), 5);
    host.on_message(&state(1, 3));
    assert_eq!(host.forces_in_flight(), 2);
    host.on_message(&state(2, 9)); // echo of a sequence never sent: ignored
    assert_eq!(host.forces_in_flight(), 2);
    host.on_message(&state(3, 5));
    assert_eq!(host.forces_in_flight(), 0);
}

/// Firmware budgets: the decoder and the session must fit comfortably in a small microcontroller's RAM.
#[test]
fn firmware_footprint_is_small() {
    let decoder = std::mem::size_of::<voxhap_protocol::FrameDecoder<HostToDevice>>();
    let session = std::mem::size_of::<DeviceSession>();
    println!("FrameDecoder<HostToDevice>: {decoder} bytes, DeviceSession: {session} bytes");
    assert!(decoder <= 256, "decoder is {decoder} bytes");
    assert!(session <= 1024, "session is {session} bytes");
}

/// SPEC 6.3: an ENCODER outage stops State frames but not HeartbeatReply, and one State follows once the sample is
/// finite again, echoing the last SetForce received meanwhile.
#[test]
fn an_encoder_outage_stops_states_then_one_state_catches_up() {
    let mut device = enabled_device();
    let bad = DeviceSample {
        position_m: [f32::NAN, 0.0, 0.0],
        ..DeviceSample::default()
    };
    device.on_message(&force(1, [1.0, 0.0, 0.0]), 10);
    device.on_message(&force(2, [1.0, 0.0, 0.0]), 20);
    assert_eq!(device.poll(30, &bad), [0.0; 3]);
    device.on_message(&HostToDevice::Heartbeat(Heartbeat { counter: 5 }), 40);
    let replies = drain(&mut device);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::Fault(f), DeviceToHost::Heartbeat(h)]
            if f.code == FaultCode::ENCODER && h.counter == 5),
        "{replies:?}"
    );
    device.on_message(&force(3, [1.0, 0.0, 0.0]), 50);
    device.poll(60, &bad);
    assert!(drain(&mut device).is_empty(), "no second Fault, no State");
    device.poll(70, &DeviceSample::default());
    let replies = drain(&mut device);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::State(s)] if s.last_force_sequence == 3
            && s.status.contains(StatusFlags::FAULTED)),
        "{replies:?}"
    );
}

/// SPEC 6.3 and 6.1: a Fault is sent without a session; Hello keeps Faulted and WATCHDOG_TRIPPED.
#[test]
fn faults_are_sent_without_a_session_and_hello_clears_neither_faulted_nor_watchdog_tripped() {
    let mut device = DeviceSession::new(info());
    device.raise_fault(FaultCode::EMERGENCY_STOP, 5);
    assert!(matches!(
        drain(&mut device).as_slice(),
        [DeviceToHost::Fault(_)]
    ));
    device.on_message(&hello(), 10);
    drain(&mut device);
    assert!(device.status().contains(StatusFlags::FAULTED));

    let mut device = enabled_device();
    device.poll(
        DEFAULT_WATCHDOG_TIMEOUT_US as u64 + 10,
        &DeviceSample::default(),
    );
    assert!(device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
    device.on_message(&hello(), 100_000);
    assert!(device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
    device.on_message(&enable(0), 100_010);
    assert!(!device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
}

/// SPEC 6.6: in lockstep REQUEST_STATE changes nothing: one State per SetForce, never two.
#[test]
fn request_state_in_lockstep_still_gives_one_state() {
    let mut device = enabled_device();
    device.on_message(
        &HostToDevice::SetForce(SetForce {
            sequence: 1,
            force_n: [0.0; 3],
            flags: ForceFlags::REQUEST_STATE,
        }),
        10,
    );
    device.poll(20, &DeviceSample::default());
    device.poll(30, &DeviceSample::default());
    let replies = drain(&mut device);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::State(s)] if s.last_force_sequence == 1),
        "{replies:?}"
    );
}
