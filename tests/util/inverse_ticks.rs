//! The tests' side of the Inverse Service double's force log ([`super::inverse_service`]): force requests that
//! carry their tick ([`tick_stamped_force`]), so that a test can tell which tick's request each force the double
//! received came from, and read what the arm was sent after an event ([`received_after_tick`]). Written from the
//! safety pipeline's documented behaviour (it scales a force as a whole or zeroes it), not from its code.

use super::inverse_service::InverseService;
use glam::DVec3;
use std::time::{Duration, Instant};

/// x / z of a tick-stamped force request per tick ([`tick_stamped_force`]).
const FORCE_STAMP_PER_TICK: f64 = 1e-7;

/// A test's force request at `tick`: `magnitude` along z, with the tick written into x as
/// x = tick · 1e-7 · `magnitude` (0.0001 of the magnitude per 1000 ticks, well inside any limit). The safety
/// pipeline changes a force only by scaling it as a whole (ramp-in, clamp, slew limit) or zeroing it, so x / z
/// of any non-zero force the double received says which tick's request it came from ([`forced_tick`]).
pub fn tick_stamped_force(tick: u64, magnitude: f64) -> DVec3 {
    DVec3::new(
        tick as f64 * FORCE_STAMP_PER_TICK * magnitude,
        0.0,
        magnitude,
    )
}

/// The tick whose request ([`tick_stamped_force`]) a force the double received came from; `None` for a force
/// with no z (a zero).
pub fn forced_tick(force: &[f64; 3]) -> Option<u64> {
    (force[2] != 0.0).then(|| (force[0] / force[2] / FORCE_STAMP_PER_TICK).round() as u64)
}

/// The forces the double received after the last non-zero one requested at or before `tick`
/// ([`tick_stamped_force`]), in order: what the arm was sent once the host had acted on what it read at
/// `tick`. The link is one ordered stream and the host sends each tick's force at most once (the newest of
/// several queued), so the ticks of the non-zero forces must rise strictly (checked here): an earlier tick's
/// force sent again after the event cannot pass for one sent before it.
pub fn received_after_tick(forces: &[[f64; 3]], tick: u64) -> &[[f64; 3]] {
    let ticks: Vec<u64> = forces.iter().filter_map(forced_tick).collect();
    assert!(
        ticks.windows(2).all(|pair| pair[0] < pair[1]),
        "a tick's force reached the arm twice or out of order: ticks {ticks:?}"
    );
    let last = forces
        .iter()
        .rposition(|f| forced_tick(f).is_some_and(|t| t <= tick));
    &forces[last.map_or(0, |i| i + 1)..]
}

/// Waits (up to 20 s) until the forces the service has logged satisfy `done` (it reads the host's last
/// messages on its own thread, after the call that sent them has returned); returns them as they are then.
pub fn settle(service: &InverseService, done: impl Fn(&[[f64; 3]]) -> bool) -> Vec<[f64; 3]> {
    let start = Instant::now();
    loop {
        let forces = service.forces();
        if done(&forces) || start.elapsed() > Duration::from_secs(20) {
            return forces;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}
