use super::super::settings::{PassivityMode, PassivitySettings, MAX_LATENCY_TICKS};
use super::super::test_link::LinkDouble;
use super::*;
use glam::DVec3;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use voxhap_api::LinkDelayReport;
use voxhap_device::supervisor::{Supervisor, SupervisorConfig};
use voxhap_device::DeviceInfo;

const US: Duration = Duration::from_micros(1);
const MS: Duration = Duration::from_millis(1);

/// The protocol driver's figure at open: 1.2 ms at worst (2 ticks at 1 kHz, rounded up).
fn at_open(worst: Duration) -> LinkLatency {
    LinkLatency {
        typical: US * 1_050,
        worst,
        source: "measured",
        round_trips: 65,
    }
}

fn seen(worst: Duration) -> Option<LinkDelaySeen> {
    Some(LinkDelaySeen {
        typical: US * 1_100,
        worst,
        round_trips: 100,
    })
}

fn chosen(settings: &PassivitySettings, arm_s: Option<f64>) -> ObserverLatency {
    ObserverLatency::choose(settings, arm_s, Some(at_open(US * 1_200)), 1e-3)
}

/// An observing controller paired as `latency` says, and its follower at 1 kHz.
fn follower_of(latency: &ObserverLatency) -> (LinkFollower, PassivityController) {
    let controller = PassivityController::new(
        PassivityMode::Observe,
        &PassivitySettings::default(),
        latency.ticks,
    );
    (LinkFollower::new(latency, MS), controller)
}

/// By hand at 1 kHz: the driver's 1.2 ms at open is 2 ticks. Round trips of at most 1.8 ms (2 ticks) change
/// nothing; 4.3 ms (ceil 4.3 = 5 ticks) widens to 5; 3 ms afterwards does not narrow; 300 ms widens to the
/// 255 the observer pairs at most. A reconnect measuring 1.2 ms again replaces the 255 with 2; the same
/// figure again changes nothing.
#[test]
fn the_pairing_widens_to_the_longest_round_trip_and_a_reconnect_replaces_it() {
    let (follower, mut c) = follower_of(&chosen(&PassivitySettings::default(), None));
    assert_eq!(c.latency_ticks_now(), 2);
    assert_eq!(follower.observe(None, &mut c), None);
    assert_eq!(follower.observe(seen(US * 1_800), &mut c), None);
    assert_eq!(
        follower.observe(seen(US * 4_300), &mut c),
        Some(PairingChange::Widened { from: 2, to: 5 })
    );
    assert_eq!(follower.observe(seen(MS * 3), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 5);
    assert_eq!(
        follower.observe(seen(MS * 300), &mut c),
        Some(PairingChange::Widened { from: 5, to: 255 })
    );
    assert_eq!(
        follower.connected(Some(at_open(US * 1_200)), &mut c),
        Some(PairingChange::Reconnected { from: 255, to: 2 })
    );
    assert_eq!(follower.connected(Some(at_open(US * 1_200)), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 2);
}

/// The scene's `latency_s` and the simulated arm's are what the user said: neither widens nor is replaced.
#[test]
fn a_latency_the_scene_or_the_arm_gives_is_kept() {
    let written = PassivitySettings {
        latency_s: Some(0.0),
        ..PassivitySettings::default()
    };
    for latency in [
        chosen(&written, None),
        chosen(&PassivitySettings::default(), Some(0.001)),
    ] {
        let (follower, mut c) = follower_of(&latency);
        let before = c.latency_ticks_now();
        assert_eq!(follower.observe(seen(MS * 9), &mut c), None);
        assert_eq!(follower.connected(Some(at_open(MS * 7)), &mut c), None);
        assert_eq!(c.latency_ticks_now(), before);
    }
}

/// A hand-worked run: forces of 1, 2, 3, ... N along x sent at ticks 0, 1, 2, ..., the probe moving 1 mm a
/// tick, no reference energy. Paired with no latency, ticks 1 to 4 book the forces of ticks 0 to 3: 1 + 2 +
/// 3 + 4 = 10 mJ. Widened to 2 ticks from tick 5, ticks 5, 6 and 7 book the forces of ticks 2, 3 and 4:
/// 3 + 4 + 5 = 12 mJ, 22 mJ in all (unwidened they would book 5 + 6 + 7, 28 mJ in all).
#[test]
fn a_widened_controller_pairs_each_step_with_the_force_sent_that_much_earlier() {
    let settings = PassivitySettings::default();
    let mut controller = PassivityController::new(PassivityMode::Observe, &settings, 0);
    for n in 0..8u32 {
        if n == 5 {
            controller.set_latency_ticks(2);
        }
        let x = DVec3::new(f64::from(n) * 1e-3, 0.0, 0.0);
        controller.observe_and_control(x, DVec3::ZERO, 0.0, 1e-3);
        let force = DVec3::new(f64::from(n + 1), 0.0, 0.0);
        controller.sent(force, force);
    }
    assert_eq!(controller.latency_ticks_now(), 2);
    let generated = controller.totals().generated_j;
    assert!((generated - 22e-3).abs() < 1e-12, "{generated}");
    controller.set_latency_ticks(1_000);
    assert_eq!(controller.latency_ticks_now(), MAX_LATENCY_TICKS);
}

/// Ten ticks of a servo of period `period` through the supervisor, as the servo loop calls the follower
/// each tick: connected at tick 0 with the driver's 1.2 ms at open, then from tick 7 on the driver reports a
/// longest round trip of `worst_us`. The controller's pairing at the end, and what the statistics report.
fn followed_through_the_supervisor(period: Duration, worst_us: u64) -> (usize, LinkDelayReport) {
    let worst = Arc::new(AtomicU64::new(0));
    let shared = worst.clone();
    let info = DeviceInfo::basic("timed", DVec3::splat(-0.1), DVec3::splat(0.1));
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), move || {
        Ok(LinkDouble {
            info: info.clone(),
            latency: Some(at_open(US * 1_200)),
            worst_us: shared.clone(),
        })
    })
    .unwrap();
    let device: &mut dyn ServoDevice = &mut supervisor;
    device.connect(0).unwrap();
    let settings = PassivitySettings::default();
    let latency =
        ObserverLatency::choose(&settings, None, device.link_latency(), period.as_secs_f64());
    let mut controller = PassivityController::new(PassivityMode::Control, &settings, latency.ticks);
    let stats = LinkDelayStats::default();
    stats.start(latency.ticks, device.link_latency());
    let follower = LinkFollower::new(&latency, period);
    for tick in 0..10u64 {
        if tick == 7 {
            worst.store(worst_us, Ordering::Relaxed);
        }
        follower.follow(&*device, tick == 0, &mut controller, &stats, tick);
    }
    (controller.latency_ticks_now(), stats.report())
}

/// Through the supervisor (`followed_through_the_supervisor`) at 1 kHz: connected at tick 0 with the driver's
/// 1.2 ms (2 ticks, no change from the start); a 4.3 ms round trip seen at tick 7 widens the controller's
/// pairing to 5 ticks, and the statistics say so: one change, at 7 ms (tick 7 at 1 kHz), the worst round
/// trip 4.3 ms and 5 ticks, the median 1.1 ms, 1.2 ms declared at open.
#[test]
fn each_tick_hands_the_widened_pairing_to_the_controller_and_the_statistics() {
    let (pairing, report) = followed_through_the_supervisor(MS, 4_300);
    assert_eq!(pairing, 5);
    assert_eq!(
        (
            report.observer_ticks,
            report.observer_changes,
            report.worst_ticks,
            report.round_trips
        ),
        (5, 1, 5, 100)
    );
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(
        close(report.last_change_t_s, 0.007)
            && close(report.worst_ms, 4.3)
            && close(report.typical_ms, 1.1)
            && close(report.declared_ms, 1.2),
        "{report:?}"
    );
    assert!(
        report.summary().starts_with(
            "link delay: worst round trip seen 4.300 ms (5 ticks), median 1.100 ms over 100 round trips, \
             declared at open 1.200 ms; the passivity observer pairs 5 ticks (changed 1 time, last at 0.007 s)"
        ),
        "{}",
        report.summary()
    );
}

/// The run summary's longest round trip in ticks and the observer's pairing count on one period: the servo's.
/// At 3 kHz that is 333 333 ns (1e9 / 3000 rounded to whole nanoseconds, as `Session` sets it), by hand:
/// the driver's 1.2 ms at open is 1 200 000 / 333 333 = 3.6 periods, 4 ticks; a longest round trip of
/// 1.999 ms is 5.997 periods (5 x 333 333 = 1 666 665 < 1 999 000 <= 6 x 333 333 = 1 999 998 ns), 6 ticks.
/// So at tick 7 (7 x 333 333 ns = 2.333331 ms) the pairing widens from 4 to 6, and the summary says 6 ticks
/// too. Counted on another period, say whole microseconds (333 µs), that round trip would be 7 ticks
/// (6 x 333 000 = 1 998 000 < 1 999 000 ns): the two figures agree because both count on the servo's period.
#[test]
fn at_3_khz_the_summary_and_the_pairing_count_the_same_ticks() {
    let (pairing, report) = followed_through_the_supervisor(Duration::from_nanos(333_333), 1_999);
    assert_eq!(pairing, 6);
    assert_eq!(
        (
            report.observer_ticks,
            report.observer_changes,
            report.worst_ticks
        ),
        (6, 1, 6),
        "{report:?}"
    );
    assert!(
        (report.last_change_t_s - 2.333331e-3).abs() < 1e-12,
        "{report:?}"
    );
}
