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

/// The driver's round trips since open: the median `median` and the longest `worst`, over 100 (more than
/// the 65 of [`at_open`]).
fn seen(median: Duration, worst: Duration) -> Option<LinkDelaySeen> {
    seen_over(median, worst, 100)
}

/// The driver's round trips since open: the median `median` and the longest `worst`, over `round_trips`.
fn seen_over(median: Duration, worst: Duration, round_trips: u64) -> Option<LinkDelaySeen> {
    Some(LinkDelaySeen {
        typical: median,
        worst,
        round_trips,
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

/// By hand at 1 kHz: the driver's 1.2 ms at open is 2 ticks. A median of 1.1 ms plus the 1 ms period is
/// 2.1 ms, 3 ticks: the pairing follows to 3, whatever the longest round trip: 30 ms (a stall) leaves it at
/// 3. A median of 4.3 ms (5.3 ms, 6 ticks) lengthens it to 6; 3 ms (4 ticks) shortens it to 4; none (1 ms,
/// 1 tick) over 64 round trips, fewer than the 65 open measured, takes it back to open's 2, not below; over
/// 100 round trips, to 1; 300 ms lengthens it to the 255 the observer pairs at most.
/// A reconnect measuring 1.2 ms again replaces the 255 with 2; the same figure again changes nothing.
#[test]
fn the_pairing_follows_the_median_round_trip_and_a_reconnect_replaces_it() {
    let (mut follower, mut c) = follower_of(&chosen(&PassivitySettings::default(), None));
    assert_eq!(c.latency_ticks_now(), 2);
    assert_eq!(follower.observe(None, &mut c), None);
    let typical = US * 1_100;
    assert_eq!(
        follower.observe(seen(typical, US * 1_800), &mut c),
        Some(PairingChange::Followed { from: 2, to: 3 })
    );
    assert_eq!(follower.observe(seen(typical, MS * 30), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 3);
    let follows = |follower: &LinkFollower, c: &mut PassivityController, median| {
        follower.observe(seen(median, MS * 300), c)
    };
    assert_eq!(
        follows(&follower, &mut c, US * 4_300),
        Some(PairingChange::Followed { from: 3, to: 6 })
    );
    assert_eq!(
        follows(&follower, &mut c, MS * 3),
        Some(PairingChange::Followed { from: 6, to: 4 })
    );
    assert_eq!(
        follower.observe(seen_over(Duration::ZERO, MS * 300, 64), &mut c),
        Some(PairingChange::Followed { from: 4, to: 2 })
    );
    assert_eq!(
        follows(&follower, &mut c, Duration::ZERO),
        Some(PairingChange::Followed { from: 2, to: 1 })
    );
    assert_eq!(
        follows(&follower, &mut c, MS * 300),
        Some(PairingChange::Followed { from: 1, to: 255 })
    );
    assert_eq!(
        follower.connected(Some(at_open(US * 1_200)), &mut c),
        Some(PairingChange::Reconnected { from: 255, to: 2 })
    );
    assert_eq!(follower.connected(Some(at_open(US * 1_200)), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 2);
}

/// The contact of `tests/device_passivity_pty.rs` as a sampled loop at 1 kHz: a 0.1 kg handle with 1.5 N s/m
/// of damping (the arm's and the grip's), a 200 N/m grip pulling it towards z = -3 mm from rest at z = 0 on
/// a one-sided 2 000 N/m plane at z = 0, each force acting over the step from 2 ticks after it was sent (the
/// link's median round trip, 1.1 ms, in whole ticks), the controller in control, paired from the driver's
/// figure at open `open` (over 65 round trips) and followed each tick as the driver reports `live(n)` at
/// tick `n`. Returns the most energy the force gave the handle, `max_t W(t)` with `W = sum F_acting . dx`
/// (exact: the handle is integrated under the force held over each step), and the positive work of its worst
/// window of `2 (d + 1)` steps, `d` = 2 (J). With `pinned = Some((n, ticks))`, the controller pairs `ticks`
/// from tick `n` on instead of following.
fn delayed_contact(
    open: Duration,
    live: impl Fn(usize) -> Option<LinkDelaySeen>,
    pinned: Option<(usize, usize)>,
) -> (f64, f64) {
    let (mass, damping, grip, hand_z, k, dt) = (0.1, 1.5, 200.0, -0.003, 2000.0, 1e-3);
    let settings = PassivitySettings::default();
    let latency = ObserverLatency::choose(&settings, None, Some(at_open(open)), dt);
    let mut c = PassivityController::new(PassivityMode::Control, &settings, latency.ticks);
    let follower = LinkFollower::new(&latency, MS);
    let (mut z, mut v) = (0.0f64, 0.0f64);
    let mut sent = [0.0f64; 3];
    let (mut given, mut most) = (0.0f64, 0.0f64);
    let mut work = Vec::new();
    for n in 0..3_000usize {
        match pinned {
            Some((from, ticks)) if n >= from => c.set_latency_ticks(ticks),
            _ => {
                follower.observe(live(n), &mut c);
            }
        }
        let probe = DVec3::new(0.0, 0.0, z);
        let depth = (-z).max(0.0);
        let control =
            c.observe_and_control(probe, DVec3::new(0.0, 0.0, v), 0.5 * k * depth * depth, dt);
        let force = DVec3::new(0.0, 0.0, k * depth) + control;
        c.sent(force, force);
        sent[n % 3] = force.z;
        // The force sent 2 ticks ago acts over this step (the next of the 3 slots holds it).
        let acting = sent[(n + 1) % 3];
        let start = z;
        let substeps = 100;
        let h = dt / f64::from(substeps);
        for _ in 0..substeps {
            v += h * (acting + grip * (hand_z - z) - damping * v) / mass;
            z += h * v;
        }
        work.push(acting * (z - start));
        given += acting * (z - start);
        most = most.max(given);
    }
    let window = work
        .windows(2 * (2 + 1))
        .map(|w| w.iter().map(|w| w.max(0.0)).sum::<f64>())
        .fold(0.0, f64::max);
    (most, window)
}

/// [`delayed_contact`] from the driver's 1.2 ms at open (2 ticks), and the
/// driver timing round trips of 1.1 ms (median), and one of 30 ms at 30 ms, while the press still rings (a
/// stall: the loop ran on as before); followed, the pairing is the median plus a period, 3 ticks (a tick
/// long). With `pairing`, the controller pairs that many ticks from the stall on instead of following (what
/// following the longest round trip did).
fn stalled_contact(pairing: Option<usize>) -> (f64, f64) {
    let live = |n| seen(US * 1_100, if n < 30 { US * 1_200 } else { MS * 30 });
    delayed_contact(US * 1_200, live, pairing.map(|ticks| (30, ticks)))
}

/// A stall does not unpair the controller (module docs, "Why the median plus a period"): through a
/// 30 ms round trip the contact of [`stalled_contact`] gives the handle at most the controller's threshold
/// plus its worst window of `2 (d + 1)` steps (the bound `tests/device_passivity_pty.rs` derives). Paired
/// with the stall's 31 ticks from then on, as following the longest round trip did, the observer books the
/// 24 Hz contact's generation as absorbed and the same contact gives the handle more than that bound.
#[test]
fn a_stall_does_not_unpair_a_stiff_delayed_contact() {
    let threshold = PassivitySettings::default().threshold_j;
    let (followed, window) = stalled_contact(None);
    assert!(
        followed <= threshold + window,
        "followed: given {followed} J, bound {threshold} + {window} J"
    );
    let (longest, window) = stalled_contact(Some(31));
    assert!(
        longest > threshold + window,
        "paired 31 ticks: given {longest} J, within {threshold} + {window} J"
    );
}

/// The loaded open of docs/stability.md ("While the servo runs"): the driver measured 555 ms at open over 65
/// round trips, 555 ticks at 1 kHz, so the observer pairs the 255 it pairs at most. The link then answers
/// as it does unloaded, a median of 1.1 ms and the longest 1.2 ms: by hand 2.1 ms with the period, 3 ticks.
/// Over 64 live round trips, fewer than open's 65, the figure at open still holds (255); over 65 the live
/// figure has as many behind it and the pairing comes down to 3, and stays there as they grow to 10 000. A
/// reconnect that measures 555 ms again is the floor again, until the new connection's own round trips
/// number 65 (10 do not lower it).
#[test]
fn a_loaded_open_holds_the_pairing_only_until_as_many_live_round_trips_are_timed() {
    let loaded = Some(at_open(MS * 555));
    let latency = ObserverLatency::choose(&PassivitySettings::default(), None, loaded, 1e-3);
    let (mut follower, mut c) = follower_of(&latency);
    assert_eq!(c.latency_ticks_now(), 255);
    let live = |round_trips| seen_over(US * 1_100, US * 1_200, round_trips);
    assert_eq!(follower.observe(live(1), &mut c), None);
    assert_eq!(follower.observe(live(64), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 255);
    assert_eq!(
        follower.observe(live(65), &mut c),
        Some(PairingChange::Followed { from: 255, to: 3 })
    );
    assert_eq!(follower.observe(live(10_000), &mut c), None);
    assert_eq!(c.latency_ticks_now(), 3);
    assert_eq!(
        follower.connected(loaded, &mut c),
        Some(PairingChange::Reconnected { from: 3, to: 255 })
    );
    assert_eq!(follower.observe(live(10), &mut c), None);
    assert_eq!(
        follower.observe(live(65), &mut c),
        Some(PairingChange::Followed { from: 255, to: 3 })
    );
}

/// After the same loaded open, a link that stays slow keeps the pairing as wide as its live round trips say,
/// by hand at 1 kHz: a median of 554 ms (555 ms with the period) is still beyond the 255 ticks the observer
/// pairs, over 65 round trips and over 10 000: 255. A median of 199.2 ms over 1 000 round trips is 200.2 ms
/// with the period, 201 ticks: the pairing narrows to 201, not below (and open's 255 no longer holds it).
#[test]
fn a_link_that_stays_slow_keeps_the_pairing_wide() {
    let loaded = Some(at_open(MS * 555));
    let latency = ObserverLatency::choose(&PassivitySettings::default(), None, loaded, 1e-3);
    let (follower, mut c) = follower_of(&latency);
    for round_trips in [65, 10_000] {
        assert_eq!(
            follower.observe(seen_over(MS * 554, MS * 600, round_trips), &mut c),
            None
        );
        assert_eq!(c.latency_ticks_now(), 255);
    }
    assert_eq!(
        follower.observe(seen_over(US * 199_200, MS * 600, 1_000), &mut c),
        Some(PairingChange::Followed { from: 255, to: 201 })
    );
    assert_eq!(c.latency_ticks_now(), 201);
}

/// The loaded open does not unpair the contact of [`delayed_contact`] for good: the driver measured 555 ms at
/// open (255 ticks), the link then answers in 1.1 ms (median; 1.2 ms at most), one round trip a tick, while
/// the grip presses the handle in from the first tick. Followed, the pairing is 3 ticks from tick 65 (the
/// median plus a period, once the live round trips are as many as open's), and the contact gives the handle at
/// most the controller's threshold plus its worst window of `2 (d + 1)` steps, as through a stall (what the
/// first 65 ticks left unanswered included). Paired 255 ticks throughout, as when the figure at open
/// was the floor for the whole connection, the observer pairs each step with a force sent a quarter of a
/// second before, not the one that acted: the 24 Hz contact's generation goes unanswered and it gives the
/// handle more than that bound.
#[test]
fn a_loaded_open_does_not_unpair_a_stiff_delayed_contact_for_good() {
    let threshold = PassivitySettings::default().threshold_j;
    let live = |n: usize| seen_over(US * 1_100, US * 1_200, n as u64);
    let (followed, window) = delayed_contact(MS * 555, live, None);
    assert!(
        followed <= threshold + window,
        "followed: given {followed} J, bound {threshold} + {window} J"
    );
    let (floored, window) = delayed_contact(MS * 555, live, Some((0, 255)));
    assert!(
        floored > threshold + window,
        "paired 255 ticks: given {floored} J, within {threshold} + {window} J"
    );
}

/// The scene's `latency_s` and the simulated arm's are what the user said: neither follows nor is replaced.
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
        let (mut follower, mut c) = follower_of(&latency);
        let before = c.latency_ticks_now();
        assert_eq!(follower.observe(seen(MS * 9, MS * 9), &mut c), None);
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
/// each tick: connected at tick 0 with the driver's 1.2 ms at open, then from tick 7 on the driver reports
/// round trips of median `median_us` and longest `worst_us`. The controller's pairing at the end, and what
/// the statistics report.
fn followed_through_the_supervisor(
    period: Duration,
    median_us: u64,
    worst_us: u64,
) -> (usize, LinkDelayReport) {
    let (worst, median) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let (worst_shared, median_shared) = (worst.clone(), median.clone());
    let info = DeviceInfo::basic("timed", DVec3::splat(-0.1), DVec3::splat(0.1));
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), move || {
        Ok(LinkDouble {
            info: info.clone(),
            latency: Some(at_open(US * 1_200)),
            worst_us: worst_shared.clone(),
            median_us: median_shared.clone(),
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
    let mut follower = LinkFollower::new(&latency, period);
    for tick in 0..10u64 {
        if tick == 7 {
            median.store(median_us, Ordering::Relaxed);
            worst.store(worst_us, Ordering::Relaxed);
        }
        follower.follow(&*device, tick == 0, &mut controller, &stats, tick);
    }
    (controller.latency_ticks_now(), stats.report())
}

/// Through the supervisor (`followed_through_the_supervisor`) at 1 kHz: connected at tick 0 with the driver's
/// 1.2 ms (2 ticks, no change from the start); round trips of median 4.3 ms and longest 30 ms seen at tick 7
/// set the controller's pairing to the median plus a period, 5.3 ms, 6 ticks, and the statistics say so: one change, at 7 ms
/// (tick 7 at 1 kHz), the worst round trip 30 ms and 30 ticks, the median 4.3 ms, 1.2 ms declared at open.
#[test]
fn each_tick_hands_the_followed_pairing_to_the_controller_and_the_statistics() {
    let (pairing, report) = followed_through_the_supervisor(MS, 4_300, 30_000);
    assert_eq!(pairing, 6);
    assert_eq!(
        (
            report.observer_ticks,
            report.observer_changes,
            report.worst_ticks,
            report.round_trips
        ),
        (6, 1, 30, 100)
    );
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(
        close(report.last_change_t_s, 0.007)
            && close(report.worst_ms, 30.0)
            && close(report.typical_ms, 4.3)
            && close(report.declared_ms, 1.2),
        "{report:?}"
    );
    assert!(
        report.summary().starts_with(
            "link delay: worst round trip seen 30.000 ms (30 ticks), median 4.300 ms over 100 round trips, \
             declared at open 1.200 ms; the passivity observer pairs 6 ticks (changed 1 time, last at 0.007 s)"
        ),
        "{}",
        report.summary()
    );
}

/// The run summary's round trips in ticks and the observer's pairing count on one period: the servo's.
/// At 3 kHz that is 333 333 ns (1e9 / 3000 rounded to whole nanoseconds, as `Session` sets it), by hand:
/// the driver's 1.2 ms at open is 1 200 000 / 333 333 = 3.6 periods, 4 ticks; round trips of 1.999 ms
/// (median and longest) are 5.997 periods (5 x 333 333 = 1 666 665 < 1 999 000 <= 6 x 333 333 = 1 999 998
/// ns), 6 ticks in the summary; the median plus a period, 2 332 333 ns, is 6.997 periods, 7 ticks. So at
/// tick 7 (7 x 333 333 ns = 2.333331 ms) the pairing follows from 4 to 7. Counted on another period, say
/// whole microseconds (333 µs), the longest round trip would be 7 ticks (6 x 333 000 = 1 998 000 < 1 999 000
/// ns), not the summary's 6: both figures count on the servo's period.
#[test]
fn at_3_khz_the_summary_and_the_pairing_count_the_same_ticks() {
    let (pairing, report) =
        followed_through_the_supervisor(Duration::from_nanos(333_333), 1_999, 1_999);
    assert_eq!(pairing, 7);
    assert_eq!(
        (
            report.observer_ticks,
            report.observer_changes,
            report.worst_ticks
        ),
        (7, 1, 6),
        "{report:?}"
    );
    assert!(
        (report.last_change_t_s - 2.333331e-3).abs() < 1e-12,
        "{report:?}"
    );
}
