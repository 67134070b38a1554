//! The session's start: it connects and reads the first state before the servo loop starts its clock, and the
//! set-up in between is time that clock does not see. A device double whose first answer comes 60 ms after it
//! was taken (a slow first reply) while the handle moves at 0.1 m/s: by the loop's first tick the handle is
//! 6 mm on, far past the 0.5 mm the input checks allow for no time at all. The session must not refuse the
//! readings of a handle that moved while it set up.

use super::*;
use std::sync::atomic::AtomicUsize;
use std::time::Instant;
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, HapticDevice};

/// The handle's speed along x (m/s), from `START_X_M`, stopping at `END_X_M` (inside the ±0.1 m workspace).
const SPEED_M_PER_S: f64 = 0.1;
const START_X_M: f64 = -0.09;
const END_X_M: f64 = 0.09;
/// How long the first answer takes after the state it carries was taken.
const FIRST_REPLY: Duration = Duration::from_millis(60);

struct MovingHandle {
    info: DeviceInfo,
    started: Option<Instant>,
    /// Forces written so far, shared with the test.
    forces: Arc<AtomicUsize>,
}

impl HapticDevice for MovingHandle {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn write_force(&mut self, _force_n: DVec3) -> Result<(), DeviceError> {
        self.forces.fetch_add(1, Ordering::AcqRel);
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let first = self.started.is_none();
        let started = *self.started.get_or_insert_with(Instant::now);
        let x_m = (START_X_M + SPEED_M_PER_S * started.elapsed().as_secs_f64()).min(END_X_M);
        if first {
            std::thread::sleep(FIRST_REPLY);
        }
        Ok(DeviceState::at_rest(DVec3::new(x_m, 0.0, 0.0)))
    }
}

#[test]
fn a_handle_moved_while_the_session_set_up_is_not_refused() {
    let forces = Arc::new(AtomicUsize::new(0));
    let written = forces.clone();
    let mut opened = false;
    let opener = move || {
        // One device: a reconnect (after a link dropped for refused readings) would start the handle over.
        if std::mem::replace(&mut opened, true) {
            return Err(DeviceError::Protocol { what: "reopened" });
        }
        Ok(MovingHandle {
            info: DeviceInfo::basic("moving handle", DVec3::splat(-0.1), DVec3::splat(0.1)),
            started: None,
            forces: written.clone(),
        })
    };
    let session = start_on_double(opener);
    let limit = Instant::now() + Duration::from_secs(60);
    while forces.load(Ordering::Acquire) < 200 && Instant::now() < limit {
        std::thread::sleep(Duration::from_millis(5));
    }
    let summary = session.stop();
    let written = forces.load(Ordering::Acquire);
    assert!(
        written >= 200,
        "the loop wrote only {written} forces in a minute"
    );
    let safety = &summary.stats.safety;
    assert_eq!(
        safety.positions_rejected, 0,
        "readings of the moving handle were refused: {safety:?}"
    );
}
