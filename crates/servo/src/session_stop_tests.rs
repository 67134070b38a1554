//! A servo thread that outlives [`SERVO_STOP_BOUND`]: a device double that hangs (in its close, or inside a
//! tick's force write, as a blocked port would) until the test lets it go. [`Session::stop`] must still return,
//! say that the servo thread was left behind, and bring the force to zero through the device's stop channel.
//! Nothing here depends on timing but the bound itself: the double hangs until released, which the test does
//! only after `stop` has returned (or after a minute, so that a broken stop fails instead of hanging forever).

use super::*;
use std::sync::Condvar;
use voxhap_device::{DeviceError, DeviceInfo, DeviceState, EmergencyStop, HapticDevice};

/// Where the double hangs.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Hang {
    /// In `close`, after the lifecycle's zero force and Disable.
    InClose,
    /// In the first `write_force` after the test arms it: the servo thread stalls mid-tick.
    InWrite,
}

/// What the device double saw, shared with the test.
#[derive(Debug, Default)]
struct Seen {
    /// Every force written to the device.
    forces: Vec<DVec3>,
    /// Stops through the stop channel (zero force and Disable, as a serial driver's pre-encoded bytes).
    stops: u32,
    /// The double is hanging now.
    hanging: bool,
    /// The hang ended (released by the test).
    released: bool,
    /// `InWrite`: the next write hangs.
    armed: bool,
}

#[derive(Default)]
struct Shared {
    seen: Mutex<Seen>,
    changed: Condvar,
}

impl Shared {
    fn update(&self, f: impl FnOnce(&mut Seen)) {
        f(&mut self.seen.lock().unwrap());
        self.changed.notify_all();
    }

    /// Waits until `done` holds or `limit` passes; the state then.
    fn wait_for(
        &self,
        limit: Duration,
        done: impl Fn(&Seen) -> bool,
    ) -> std::sync::MutexGuard<'_, Seen> {
        let guard = self.seen.lock().unwrap();
        self.changed
            .wait_timeout_while(guard, limit, |seen| !done(seen))
            .unwrap()
            .0
    }

    /// Hangs the calling thread until the test releases it (at most a minute).
    fn hang(&self) {
        self.update(|seen| seen.hanging = true);
        drop(self.wait_for(Duration::from_secs(60), |seen| seen.released));
        self.update(|seen| seen.hanging = false);
    }
}

struct HangingDevice {
    info: DeviceInfo,
    hang: Hang,
    shared: Arc<Shared>,
}

impl HapticDevice for HangingDevice {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn close(&mut self) -> Result<(), DeviceError> {
        if self.hang == Hang::InClose {
            self.shared.hang();
        }
        Ok(())
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        let mut hang = false;
        self.shared.update(|seen| {
            seen.forces.push(force_n);
            hang = self.hang == Hang::InWrite && seen.armed && !seen.released;
        });
        if hang {
            self.shared.hang();
        }
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        Ok(DeviceState::at_rest(DVec3::new(0.0, 0.0, 0.05)))
    }

    fn emergency_stop(&self) -> Option<Box<dyn EmergencyStop>> {
        Some(Box::new(CountingStop(self.shared.clone())))
    }
}

struct CountingStop(Arc<Shared>);

impl EmergencyStop for CountingStop {
    fn stop(&mut self) -> Result<(), DeviceError> {
        self.0.update(|seen| seen.stops += 1);
        Ok(())
    }
}

/// Runs a session on the double (through the same reconnecting supervisor serial devices use), makes it hang,
/// stops the session; the summary, and what the double saw by the time `stop` returned.
fn stop_a_hanging_session(hang: Hang) -> (SessionSummary, Seen) {
    let shared = Arc::new(Shared::default());
    let opener_shared = shared.clone();
    let opener = move || {
        Ok(HangingDevice {
            info: DeviceInfo::basic("hanging double", DVec3::splat(-0.1), DVec3::splat(0.1)),
            hang,
            shared: opener_shared.clone(),
        })
    };
    let session = start_on_double(opener);
    // Ticking: some forces have gone out.
    drop(shared.wait_for(Duration::from_secs(60), |seen| seen.forces.len() >= 10));
    if hang == Hang::InWrite {
        shared.update(|seen| seen.armed = true);
        let seen = shared.wait_for(Duration::from_secs(60), |seen| seen.hanging);
        assert!(
            seen.hanging,
            "the servo thread never reached the hanging write"
        );
    }
    let summary = session.stop();
    let mut seen = shared.seen.lock().unwrap();
    let at_return = Seen {
        forces: std::mem::take(&mut seen.forces),
        stops: seen.stops,
        hanging: seen.hanging,
        released: seen.released,
        armed: seen.armed,
    };
    seen.released = true;
    drop(seen);
    shared.changed.notify_all();
    (summary, at_return)
}

fn assert_left_behind_with_zero_force(summary: &SessionSummary, seen: &Seen) {
    assert!(
        seen.hanging && !seen.released,
        "stop returned only after the hang ended: {seen:?}"
    );
    let error = summary.recorder_error.as_deref().unwrap_or("");
    assert!(
        error.starts_with("the servo thread did not finish stopping the device within 3 s"),
        "{error:?}"
    );
    assert!(
        error.ends_with("zero force and Disable were sent through the device's stop channel"),
        "{error:?}"
    );
    assert!(
        seen.stops >= 1,
        "no stop through the stop channel: {seen:?}"
    );
    assert!(summary.trace.is_none());
}

#[test]
fn a_servo_thread_hanging_in_the_device_close_is_left_behind_with_the_force_at_zero() {
    let (summary, seen) = stop_a_hanging_session(Hang::InClose);
    assert_left_behind_with_zero_force(&summary, &seen);
    // The close hung after the lifecycle's explicit zero force.
    assert_eq!(
        seen.forces.last(),
        Some(&DVec3::ZERO),
        "{:?}",
        seen.forces.last()
    );
}

#[test]
fn a_servo_thread_hanging_in_a_force_write_is_left_behind_and_the_stop_channel_zeroes_the_force() {
    let (summary, seen) = stop_a_hanging_session(Hang::InWrite);
    // The servo thread never got to write its zero: only the stop channel stopped the device.
    assert_left_behind_with_zero_force(&summary, &seen);
}
