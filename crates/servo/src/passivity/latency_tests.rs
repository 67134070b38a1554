use super::super::test_link::LinkDouble;
use super::*;
use crate::device::ServoDevice;
use glam::DVec3;
use std::time::Duration;
use voxhap_device::supervisor::{Supervisor, SupervisorConfig};
use voxhap_device::DeviceInfo;

/// What a supervisor over a [`LinkDouble`] driver hands `serve` once connected (`None` before).
fn through_the_supervisor(latency: Option<LinkLatency>) -> Option<LinkLatency> {
    let info = DeviceInfo::basic("declaring", DVec3::splat(-0.1), DVec3::splat(0.1));
    let mut supervisor = Supervisor::new(SupervisorConfig::default(), move || {
        Ok(LinkDouble {
            info: info.clone(),
            latency,
            worst_us: Default::default(),
            median_us: Default::default(),
        })
    })
    .unwrap();
    let device: &mut dyn ServoDevice = &mut supervisor;
    assert_eq!(device.link_latency(), None, "not connected yet");
    device.connect(0).unwrap();
    device.link_latency()
}

/// A measured figure as voxhap's protocol driver declares it: 1.2 ms at worst, median 1.05 ms, 65 round trips.
fn measured() -> LinkLatency {
    LinkLatency {
        typical: Duration::from_micros(1_050),
        worst: Duration::from_micros(1_200),
        source: "measured",
        round_trips: 65,
    }
}

/// `serve`'s observer pairs with what the connected driver declares, through the supervisor: the Falcon's
/// 2 ms (crates/device/src/latency.rs: FTDI latency timer 1 ms plus one 1 ms USB frame) is 2 ticks at 1 kHz
/// and 8 at 4 kHz; a measured 1.2 ms is 2 ticks at 1 kHz (rounded up) and 5 at 4 kHz (4.8, rounded up);
/// nothing declared is 0. The scene's `latency_s` comes first, then the simulated arm's.
#[test]
fn the_observer_takes_the_connected_drivers_declared_latency() {
    let settings = PassivitySettings::default();
    let falcon = through_the_supervisor(Some(voxhap_device::latency::FALCON));
    let at = |link, period_s| ObserverLatency::choose(&settings, None, link, period_s);
    assert_eq!(at(falcon, 1e-3).ticks, 2);
    assert_eq!(at(falcon, 2.5e-4).ticks, 8);
    assert_eq!(
        at(falcon, 1e-3).origin,
        LatencyOrigin::Driver(voxhap_device::latency::FALCON)
    );
    let link = through_the_supervisor(Some(measured()));
    assert_eq!(at(link, 1e-3).ticks, 2);
    assert_eq!(at(link, 2.5e-4).ticks, 5);
    assert!((at(link, 1e-3).latency_s - 0.0012).abs() < 1e-12);
    let none = through_the_supervisor(None);
    assert_eq!(at(none, 1e-3).ticks, 0);
    assert_eq!(at(none, 1e-3).origin, LatencyOrigin::Unknown);

    let arm = ObserverLatency::choose(&settings, Some(0.001), link, 1e-3);
    assert_eq!((arm.ticks, arm.origin), (1, LatencyOrigin::SimulatedArm));
    let written = PassivitySettings {
        latency_s: Some(0.0),
        ..PassivitySettings::default()
    };
    let scene = ObserverLatency::choose(&written, Some(0.001), link, 1e-3);
    assert_eq!((scene.ticks, scene.origin), (0, LatencyOrigin::Scene));
}

/// The notice names the ticks, the seconds and the origin; none when the observer is off.
#[test]
fn the_notice_names_where_the_latency_came_from() {
    let settings = PassivitySettings::default();
    let measured = ObserverLatency::choose(&settings, None, Some(measured()), 1e-3);
    assert_eq!(
        measured.notice(PassivityMode::Control, "mock:/dev/pts/9", 1000.0).unwrap(),
        "passivity control: the observer pairs each force with the motion 2 ticks later (1.200 ms at 1000 Hz), \
         from the link latency device mock:/dev/pts/9's driver measured at open: the 95th percentile of 65 \
         round trips from a zero force to the State echoing it, at most their median plus one servo period, \
         rounded up to 0.1 ms (median 1.050 ms); while serve runs it follows the median round trip the \
         driver times plus one period, below this figure only once it has timed as many round trips as this \
         figure came from (the run summary's link delay line and /api/stats say when)"
    );
    let falcon =
        ObserverLatency::choose(&settings, None, Some(voxhap_device::latency::FALCON), 1e-3);
    let notice = falcon
        .notice(PassivityMode::Observe, "falcon", 1000.0)
        .unwrap();
    assert!(
        notice.starts_with(
            "passivity observe: the observer pairs each force with the motion 2 ticks later (2.000 ms at \
             1000 Hz), from the link latency device falcon's driver declares (FTDI latency timer 1 ms"
        ),
        "{notice}"
    );
    let none = ObserverLatency::choose(&settings, None, None, 1e-3);
    let notice = none.notice(PassivityMode::Control, "x", 1000.0).unwrap();
    assert!(
        notice.contains("0 ticks later (0.000 ms") && notice.contains("declares no link latency"),
        "{notice}"
    );
    assert_eq!(measured.notice(PassivityMode::Off, "x", 1000.0), None);
    let arm = ObserverLatency::choose(&settings, Some(0.001), None, 1e-3);
    assert_eq!(arm.notice(PassivityMode::Control, "sim", 1000.0), None);
}

/// 255 ticks are paired; a link measured at 300 ms is 300 ticks at 1 kHz, beyond them, and the notice says so;
/// 255 ms exactly is not beyond.
#[test]
fn a_latency_beyond_what_the_observer_pairs_is_named() {
    let settings = PassivitySettings::default();
    let slow = |ms: u64| LinkLatency {
        worst: Duration::from_millis(ms),
        ..measured()
    };
    let beyond = ObserverLatency::choose(&settings, None, Some(slow(300)), 1e-3);
    assert_eq!((beyond.ticks, beyond.beyond_observer), (255, true));
    let notice = beyond.notice(PassivityMode::Control, "d", 1000.0).unwrap();
    assert!(
        notice.contains("255 ticks later (300.000 ms")
            && notice.contains("more than the 255 ticks the observer pairs"),
        "{notice}"
    );
    let edge = ObserverLatency::choose(&settings, None, Some(slow(255)), 1e-3);
    assert_eq!((edge.ticks, edge.beyond_observer), (255, false));
    assert!(!edge
        .notice(PassivityMode::Control, "d", 1000.0)
        .unwrap()
        .contains("more than"));
}
