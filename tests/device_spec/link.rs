//! Link health: silence, line noise, late replies, a device reset and a frozen host, each keeping every force
//! invariant the SPEC promises.

use crate::util::spec_device::{fault, types, HostMessage, SpecDevice, SpecDeviceConfig, Trigger};
use crate::util::spec_serve::{
    assert_force_invariants, assert_force_invariants_across_a_reset, assert_slew_limited,
    ball_scene, enable_after, enabled_again_after, enabled_again_after_trigger,
    forces_after_trigger, nonzero_while_not_enabled, run_until, run_until_ok, signaller, summary,
    take_turn, tapping_until, Serve, FLOWING, INSIDE_X_M, PATIENCE,
};
use std::sync::atomic::AtomicI32;
use std::sync::Arc;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// Link health.

#[test]
fn a_silent_device_gets_no_stale_force_beyond_the_link_window_then_hello() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        silence: Some((FLOWING, Duration::from_millis(400))),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the silence",
        enabled_again_after_trigger(FLOWING, 0),
    );
    let silence = device.fired(FLOWING).unwrap();
    let silence_start = silence.at;
    let forces = device.forces();
    let messages = device.messages();
    // Forces stay legitimate again once the host has enabled the device anew after the silence.
    let re_enabled = enable_after(&device, silence.index).unwrap().index;
    let stale: Vec<_> = forces
        .iter()
        .filter(|f| f.index > silence.index && f.index < re_enabled && !f.is_zero())
        .collect();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < silence.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the device fell silent: {}",
        summary(&forces)
    );
    // The link window is 20 ms at 1 kHz: 20 forces, and nothing non-zero after it (40 ms allowed for a late servo).
    let late = stale
        .iter()
        .filter(|f| f.at > silence_start + Duration::from_millis(40))
        .count();
    assert!(device.nonzero_forces_after_index(silence.index) >= stale.len());
    assert!(
        stale.len() <= 25 && late == 0,
        "{} non-zero SetForce after the device fell silent, {late} of them more than 40 ms after; {}",
        stale.len(),
        summary(&forces)
    );
    assert!(
        messages
            .iter()
            .any(|m| m.index > silence.index && matches!(m.message, HostMessage::Hello { .. })),
        "no Hello after the link was lost"
    );
    assert_force_invariants(&device, 8.0);
}

#[test]
fn a_noisy_link_keeps_every_force_invariant() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        corrupt_fraction: 0.002,
        partial_frame_every: Some(97),
        seed: 12,
        noise_from: Some(Trigger::AfterFirstEnable(Duration::ZERO)),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let (device, _status, output) = run_until(
        config,
        0.0,
        "force flowing through the noise, then 500 host ticks",
        forces_after_trigger(FLOWING, 500),
    );
    let forces = device.forces();
    assert!(
        forces.len() > 200,
        "too few SetForce: {}; serve said {output}",
        summary(&forces)
    );
    assert!(
        device.sent().iter().any(|s| !s.intact),
        "the device corrupted nothing (the test needs noise)"
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn replies_two_periods_late_keep_every_force_invariant() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        reply_delay: Duration::from_millis(2),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "force flowing, then 500 host ticks",
        forces_after_trigger(FLOWING, 500),
    );
    assert_force_invariants(&device, 8.0);
    assert_slew_limited(&device);
}

#[test]
fn a_device_that_resets_is_handshaken_again_and_re_enabled() {
    let _turn = take_turn();
    let config = SpecDeviceConfig {
        reset: Some(FLOWING),
        ..tapping_until(INSIDE_X_M, FLOWING)
    };
    let device = run_until_ok(
        config,
        0.0,
        "a new Enable after the reset, and 50 host ticks after it",
        enabled_again_after_trigger(FLOWING, 50),
    );
    let messages = device.messages();
    let reset = device.fired(FLOWING).unwrap();
    let reset_at = reset.at;
    let hello_again = messages
        .iter()
        .find(|m| m.index > reset.index && matches!(m.message, HostMessage::Hello { .. }))
        .unwrap_or_else(|| panic!("no Hello after the device reset: {messages:?}"));
    assert!(
        hello_again.at < reset_at + Duration::from_secs(1),
        "Hello only {:?} after the reset",
        hello_again.at - reset_at
    );
    assert!(
        enable_after(&device, hello_again.index).is_some(),
        "never enabled again after the reset"
    );
    // The handle is still in the wall, so after the new Enable the engage rule may keep the force at zero; the
    // session works again when the device applies SetForce frames.
    let forces = device.forces();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < reset.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the device reset: {}",
        summary(&forces)
    );
    assert!(
        forces
            .iter()
            .any(|f| f.index > hello_again.index && f.enabled),
        "the device applied no SetForce after the reset: {}",
        summary(&forces)
    );
    assert_force_invariants_across_a_reset(&device, &reset, 8.0);
}

/// SIGSTOP freezes the whole host (servo, monitor and all): only the device's watchdog can act. After SIGCONT the
/// host must not resume with its stale force: zero until it has enabled the device again, then a ramp. The device
/// thread sends SIGSTOP itself, at the cycle it sees force flowing.
#[test]
fn a_frozen_host_is_caught_by_the_device_watchdog_and_resumes_from_zero() {
    let _turn = take_turn();
    let dir = tempfile::tempdir().unwrap();
    let scene = ball_scene(dir.path(), 0.0);
    let pid = Arc::new(AtomicI32::new(0));
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        call_at: Some((FLOWING, signaller(&pid, libc::SIGSTOP))),
        ..tapping_until(INSIDE_X_M, FLOWING)
    });
    let mut serve = Serve::start(&device, Some(&scene), None);
    serve.share_pid(&pid);
    serve.wait_for(&device, "force flowing (and SIGSTOP)", |device| {
        device.fired(FLOWING).is_some()
    });
    // Frozen for at least 200 ms (four times the device's watchdog); longer if this thread wakes late.
    let frozen = device.fired(FLOWING).unwrap();
    std::thread::sleep(
        (frozen.at + Duration::from_millis(200)).saturating_duration_since(Instant::now()),
    );
    serve.signal(libc::SIGCONT);
    serve.wait_for(
        &device,
        "a new Enable after the freeze, and 50 host ticks after it",
        |device| enabled_again_after(device, frozen.index, 50),
    );
    serve.signal(libc::SIGTERM);
    let (_status, output) = serve.finish(PATIENCE);
    std::thread::sleep(Duration::from_millis(50));
    device.stop();
    // A loaded machine may trip the device's watchdog before the freeze too (a late host): the one that counts
    // is the first after SIGSTOP.
    let watchdog = device
        .sent()
        .into_iter()
        .find(|s| {
            s.index > frozen.index
                && s.message_type == types::FAULT
                && s.detail == u16::from(fault::WATCHDOG_EXPIRED)
        })
        .unwrap_or_else(|| panic!("the device watchdog never fired; serve said {output}"));
    let forces = device.forces();
    assert!(
        forces
            .iter()
            .rfind(|f| f.index < frozen.index)
            .is_some_and(|f| f.magnitude_n() > 0.5),
        "no force was being rendered when the host froze: {}",
        summary(&forces)
    );
    let enable = enable_after(&device, watchdog.index)
        .expect("the host did not enable again after the device watchdog tripped");
    // One SetForce computed before the freeze may still go out after it; then zero until the new Enable.
    assert_force_invariants(&device, 8.0);
    let stale: Vec<_> = nonzero_while_not_enabled(&forces)
        .into_iter()
        .filter(|f| f.index > watchdog.index && f.index < enable.index)
        .collect();
    assert!(
        stale.len() <= 1,
        "{} non-zero SetForce to the Idle device after the freeze; {}",
        stale.len(),
        summary(&forces)
    );
    assert_slew_limited(&device);
}
