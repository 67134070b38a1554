//! Faults and refusals: a fault brings zero force within one period, a latching fault is never cleared by the
//! host, and a refused or faulted device gets only zero forces.

use crate::util::spec_device::{
    fault, reject, types, HostMessage, SpecDeviceConfig, SpecDeviceHandle,
};
use crate::util::spec_serve::{
    assert_force_invariants, assert_slew_limited, enable_after, enabled_again_after_trigger,
    forces_after_trigger, into_the_wall_after_spawn, run_until, run_until_ok, summary, take_turn,
    tapping_until, FLOWING, INSIDE_X_M,
};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// Faults and refusals.

/// After the Fault frame went out, at most one non-zero SetForce (already in flight), and none after the next
/// State, until the host sends Enable again.
/// The Fault frame is the first with `code` after the event with index `injected` (the trigger that raised it: on
/// a loaded machine the device's own watchdog may have tripped before, with the same code).
fn assert_zero_within_one_period_of(device: &SpecDeviceHandle, code: u8, injected: u64) {
    let sent = device.sent();
    let fault_frame = sent
        .iter()
        .find(|s| {
            s.index > injected && s.message_type == types::FAULT && s.detail == u16::from(code)
        })
        .unwrap_or_else(|| panic!("the device never sent Fault({code})"));
    let next_state = sent
        .iter()
        .find(|s| s.index > fault_frame.index && s.message_type == types::STATE)
        .expect("a State after the Fault");
    let forces = device.forces();
    let re_enable = enable_after(device, fault_frame.index).map_or(u64::MAX, |m| m.index);
    let before_fault = forces
        .iter()
        .rfind(|f| f.index < fault_frame.index)
        .expect("forces before the fault");
    assert!(
        before_fault.magnitude_n() > 0.5,
        "no force was being rendered when the fault came: {:?}",
        before_fault.force_n
    );
    let after_fault = forces
        .iter()
        .filter(|f| f.index > fault_frame.index && f.index < re_enable && !f.is_zero())
        .count();
    let after_state = forces
        .iter()
        .filter(|f| f.index > next_state.index && f.index < re_enable && !f.is_zero())
        .count();
    assert!(
        after_fault <= 1 && after_state == 0,
        "after Fault({code}): {after_fault} non-zero SetForce after the Fault frame, {after_state} after the next \
         State (allowed: 1 and 0); {}",
        summary(&forces)
    );
}

#[test]
fn a_watchdog_fault_brings_zero_within_one_period_then_a_new_enable() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        fault: Some((FLOWING, fault::WATCHDOG_EXPIRED)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the fault, and 50 host ticks after it",
        enabled_again_after_trigger(FLOWING, 50),
    );
    let injected = device.fired(FLOWING).unwrap().index;
    assert_zero_within_one_period_of(&device, fault::WATCHDOG_EXPIRED, injected);
    let enables = device.messages_like(HostMessage::Enable {
        watchdog_timeout_us: 0,
    });
    assert!(
        enables.len() >= 2,
        "the host did not enable again after a watchdog fault (Enables: {})",
        enables.len()
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn a_latching_fault_brings_zero_within_one_period_and_is_never_cleared_by_the_host() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        fault: Some((FLOWING, fault::OVER_CURRENT)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "500 host ticks after the fault",
        forces_after_trigger(FLOWING, 500),
    );
    let injected = device.fired(FLOWING).unwrap().index;
    assert_zero_within_one_period_of(&device, fault::OVER_CURRENT, injected);
    assert!(
        device.messages_like(HostMessage::ClearFault).is_empty(),
        "the host sent ClearFault by itself"
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_refused_enable_gets_only_zero_forces() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        handle: into_the_wall_after_spawn(0.8),
        refuse_enable: Some(reject::INVALID_ARGUMENT),
        ..SpecDeviceConfig::default()
    };
    // Past the refused Enable, and 300 host ticks with the handle in the wall.
    let in_the_wall = Instant::now() + Duration::from_millis(1200);
    let (device, _status, output) = run_until(
        config,
        0.0,
        "a refused Enable and 300 SetForce with the handle in the wall",
        |device| {
            device.force_count_after(in_the_wall) >= 300
                && !device
                    .messages_like(HostMessage::Enable {
                        watchdog_timeout_us: 0,
                    })
                    .is_empty()
        },
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        !device
            .messages_like(HostMessage::Enable {
                watchdog_timeout_us: 0
            })
            .is_empty(),
        "the host never tried Enable"
    );
    assert_eq!(
        device.max_force_while_not_enabled(),
        0.0,
        "{}",
        summary(&forces)
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_faulted_device_gets_only_zero_forces_and_no_clear_fault() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        handle: into_the_wall_after_spawn(0.8),
        start_faulted: Some(fault::EMERGENCY_STOP),
        ..SpecDeviceConfig::default()
    };
    let in_the_wall = Instant::now() + Duration::from_millis(1200);
    let (device, _status, output) = run_until(
        config,
        0.0,
        "300 SetForce with the handle in the wall",
        |device| device.force_count_after(in_the_wall) >= 300,
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        device.messages_like(HostMessage::ClearFault).is_empty(),
        "the host cleared an e-stop by itself"
    );
    assert_eq!(
        device.max_force_while_not_enabled(),
        0.0,
        "{}",
        summary(&forces)
    );
    assert_force_invariants(&device, 8.0);
}
