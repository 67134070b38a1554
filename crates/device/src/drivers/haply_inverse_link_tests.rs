//! Unit tests of the Inverse3 link's protocol core. The expected labels and ages are worked out by hand from
//! Haply's contract, not from the core: after the inventory "the server sends exactly one State Update message
//! for each message received from the client" (docs.haply.co/inverseSDK/service/api/simulation, "Core
//! contract"; docs.haply.co/inverseSDK/service/realtime/websocket-protocol, "Core rule: one response per
//! message"), so the i-th message after the inventory answers the i-th message sent, and TCP keeps the order.
//! State fields left out keep their value ("partial updates"; the documented example state is Haply's,
//! "Step 1 — Initial inventory": `cursor_position` (0.0, -0.12, 0.15) m).

use super::*;
use crate::transport::inverse_service::{parse_frame_text, WireFrame};

const ID: &str = "049D";

fn start() -> (LinkCore, Instant) {
    let t0 = Instant::now();
    let snapshot = ServiceSnapshot {
        answers_sequence: 0,
        position_m: DVec3::new(0.0, -0.12, 0.15),
        velocity_m_per_s: DVec3::ZERO,
        arm_force_n: None,
    };
    (LinkCore::new(snapshot, t0), t0)
}

/// A state update for the documented device with the handle at x (m).
fn update(x: f64) -> WireFrame {
    parse_frame_text(&format!(
        r#"{{"inverse3":[{{"device_id":"{ID}","state":{{"cursor_position":{{"x":{x},"y":-0.12,"z":0.15}}}},"status":{{}}}}]}}"#
    ))
    .unwrap()
}

fn take(core: &mut LinkCore, x: f64) -> Took {
    core.message(Incoming::Frame(&update(x)), ID).unwrap()
}

/// The I/O thread's round up to the send: the drain finds the socket empty, then force `n` goes out.
fn send(core: &mut LinkCore, n: u64, at: Instant) {
    core.socket_empty();
    core.command_sent(n, at);
}

fn label(took: Took) -> u64 {
    match took {
        Took::State(s) => s.answers_sequence,
        Took::Unused { .. } => panic!("not used: {took:?}"),
    }
}

/// Lockstep as Haply documents it: each force's reply, read after the socket was found empty behind the send,
/// answers that force and is 0 ticks old.
#[test]
fn each_reply_answers_its_own_force_in_lockstep() {
    let (mut core, t0) = start();
    for n in 1..=3u64 {
        send(&mut core, n, t0);
        assert!(core.awaiting());
        core.socket_empty();
        let took = take(&mut core, n as f64 * 0.01);
        assert_eq!(label(took), n);
        assert!(!core.awaiting());
        assert_eq!(judge(n, n, false, 3), Verdict::Use { age_ticks: 0 });
    }
    assert_eq!(core.snapshot().position_m.x, 0.03);
    assert_eq!(
        core.counters(),
        LinkCounters {
            sent: 3,
            states: 3,
            ..LinkCounters::default()
        }
    );
}

/// A message read before the socket was found empty behind force 2 may have been written before the service
/// read force 2 (an unsolicited update that slipped in after the last drain): counted as force 2's reply it
/// is labelled 1, never 2. Force 2's real reply then comes as an extra: position updated, label kept.
#[test]
fn a_message_that_may_predate_the_force_is_labelled_older() {
    let (mut core, t0) = start();
    send(&mut core, 1, t0);
    core.socket_empty();
    assert_eq!(label(take(&mut core, 0.01)), 1);
    send(&mut core, 2, t0);
    assert_eq!(label(take(&mut core, 0.02)), 1);
    core.socket_empty();
    assert_eq!(label(take(&mut core, 0.03)), 1);
    assert_eq!(core.snapshot().position_m.x, 0.03);
    assert_eq!(core.counters().extra, 1);
    // The servo thread wants force 2's answer: the newest it has answers force 1, one tick old, usable only
    // once its wait is over.
    assert_eq!(judge(1, 2, false, 3), Verdict::Wait);
    assert_eq!(judge(1, 2, true, 3), Verdict::Use { age_ticks: 1 });
}

/// Two replies that missed their round: the message read after force 3 answers force 1 (the oldest
/// unanswered), two ticks older than force 3; past the staleness bound a state is late, and a state that
/// answers no force (label 0, the inventory's) is never used once a force was sent.
#[test]
fn late_replies_answer_the_oldest_force_and_age_by_the_forces_since() {
    let (mut core, t0) = start();
    for n in 1..=3u64 {
        send(&mut core, n, t0);
    }
    core.socket_empty();
    assert_eq!(label(take(&mut core, 0.01)), 1);
    assert!(core.awaiting(), "forces 2 and 3 still await their replies");
    assert_eq!(judge(1, 3, true, 3), Verdict::Use { age_ticks: 2 });
    assert_eq!(judge(1, 5, true, 3), Verdict::Late);
    assert_eq!(judge(0, 1, true, 3), Verdict::Late);
    assert_eq!(judge(0, 1, false, 3), Verdict::Wait);
    assert_eq!(label(take(&mut core, 0.02)), 2);
    assert_eq!(label(take(&mut core, 0.03)), 3);
    assert!(!core.awaiting());
}

/// Messages without a usable state for the driven device still use up a reply slot (one response per message,
/// whatever it holds) and are counted; a type drift is told apart.
#[test]
fn unusable_messages_take_their_slot_and_are_counted() {
    let (mut core, t0) = start();
    core.socket_empty();
    for n in 1..=4u64 {
        core.command_sent(n, t0);
    }
    core.socket_empty();
    let other = parse_frame_text(
        r#"{"inverse3":[{"device_id":"0A11","state":{"cursor_position":{"x":0.2,"y":0,"z":0.1}}}]}"#,
    )
    .unwrap();
    assert_eq!(
        core.message(Incoming::Frame(&other), ID),
        Ok(Took::Unused { drift: false })
    );
    let drift = parse_frame_text(
        r#"{"inverse3":[{"device_id":"049D","state":{"cursor_position":"0.1"}}]}"#,
    )
    .unwrap_err();
    assert_eq!(
        core.message(Incoming::Undecodable(&drift), ID),
        Ok(Took::Unused { drift: true })
    );
    assert_eq!(
        core.message(Incoming::Binary, ID),
        Ok(Took::Unused { drift: false })
    );
    assert_eq!(label(take(&mut core, 0.01)), 4);
    let c = core.counters();
    assert_eq!((c.malformed, c.drifted, c.states, c.extra), (3, 1, 1, 0));
    // The position is the documented one until a usable state moved it.
    assert_eq!(core.snapshot().position_m.x, 0.01);
}

/// A partial update keeps the fields it leaves out (Haply's partial-update semantics); a non-finite position
/// is not used.
#[test]
fn partial_updates_keep_what_they_leave_out() {
    let (mut core, t0) = start();
    send(&mut core, 1, t0);
    core.command_sent(2, t0);
    core.socket_empty();
    let velocity_only = parse_frame_text(
        r#"{"inverse3":[{"device_id":"049D","state":{"cursor_velocity":{"x":2.0},"current_cursor_force":{"z":1.5}}}]}"#,
    )
    .unwrap();
    let Ok(Took::State(s)) = core.message(Incoming::Frame(&velocity_only), ID) else {
        panic!("the partial update was not used");
    };
    assert_eq!(s.position_m, DVec3::new(0.0, -0.12, 0.15));
    assert_eq!(s.velocity_m_per_s, DVec3::new(2.0, 0.0, 0.0));
    assert_eq!(s.arm_force_n, Some(DVec3::new(0.0, 0.0, 1.5)));
    let mut nan = update(0.0);
    nan.inverse3[0].state.as_mut().unwrap().cursor_position = Some(DVec3::NAN);
    assert_eq!(
        core.message(Incoming::Frame(&nan), ID),
        Ok(Took::Unused { drift: false })
    );
}

/// More than the drain bound read without the socket once found empty is a flood; the same number spread over
/// drains is not.
#[test]
fn a_service_that_never_lets_the_socket_empty_floods_the_link() {
    let (mut core, _) = start();
    let frame = update(0.0);
    for _ in 0..MAX_DRAIN_MESSAGES {
        assert!(core.message(Incoming::Frame(&frame), ID).is_ok());
    }
    core.socket_empty();
    for _ in 0..MAX_DRAIN_MESSAGES {
        assert!(core.message(Incoming::Frame(&frame), ID).is_ok());
    }
    assert_eq!(
        core.message(Incoming::Frame(&frame), ID),
        Err(LinkFault::Flooded)
    );
}

/// The newest queued force goes out (older ones counted as coalesced); with none queued, a zero keepalive
/// only once 100 ms passed since the last message; a non-finite force never goes out.
#[test]
fn commands_coalesce_keepalives_wait_and_nan_never_leaves() {
    let (mut core, t0) = start();
    assert_eq!(core.next_command(None, 0, t0), None);
    let ms = Duration::from_millis;
    let out = |sequence, force_n| Some(Outgoing { sequence, force_n });
    assert_eq!(
        core.next_command(None, 0, t0 + ms(100)),
        out(0, DVec3::ZERO)
    );
    let force = ForceCommand {
        sequence: 7,
        force_n: DVec3::new(0.5, 0.0, -1.0),
    };
    assert_eq!(
        core.next_command(Some(force), 2, t0 + ms(100)),
        out(7, force.force_n)
    );
    core.command_sent(7, t0 + ms(100));
    assert_eq!(core.counters().coalesced, 2);
    assert_eq!(core.next_command(None, 0, t0 + ms(199)), None);
    assert_eq!(
        core.next_command(None, 0, t0 + ms(200)),
        out(7, DVec3::ZERO)
    );
    let nan = ForceCommand {
        sequence: 8,
        force_n: DVec3::new(f64::NAN, 0.0, 1.0),
    };
    assert_eq!(
        core.next_command(Some(nan), 0, t0 + ms(200))
            .unwrap()
            .force_n,
        DVec3::ZERO
    );
}

/// With the ring of unanswered messages full the oldest is forgotten: the next reply answers the second.
#[test]
fn a_full_ring_forgets_the_oldest_unanswered_message() {
    let (mut core, t0) = start();
    core.socket_empty();
    for n in 1..=(FORCE_RING_CAPACITY as u64 + 1) {
        core.command_sent(n, t0);
    }
    core.socket_empty();
    assert_eq!(label(take(&mut core, 0.0)), 2);
}

/// Haply's safety types to voxhap's fault table (docs/safety.md: 1 emergency stop, 8 motor stall, 9 stability
/// ceiling reached).
#[test]
fn safety_events_are_the_documented_faults() {
    let name = |event| crate::info::fault_name(fault_code(event));
    assert_eq!(name(SafetyEvent::EbrakeTriggered), "emergency stop");
    assert_eq!(name(SafetyEvent::StallDetected), "motor stall");
    assert_eq!(
        name(SafetyEvent::StabilityCeiling),
        "stability ceiling reached"
    );
}

/// The servo thread's wait is under half a period at every rate: 0.4 ms at 1 kHz, 0.1 ms at 4 kHz.
#[test]
fn the_reply_wait_fits_in_half_a_period() {
    let configured = Duration::from_micros(400);
    assert_eq!(
        reply_wait_for(configured, Duration::from_millis(1)),
        Duration::from_micros(400)
    );
    assert_eq!(
        reply_wait_for(configured, Duration::from_micros(250)),
        Duration::from_micros(100)
    );
    for period_us in [100u64, 250, 500, 1_000, 2_000] {
        let period = Duration::from_micros(period_us);
        assert!(reply_wait_for(configured, period) * 2 <= period);
    }
}
