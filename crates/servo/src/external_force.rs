//! The external force input (`serve --external-force`): a force a client sends (the control API's
//! `set_external_force`, ROS 2's `/voxhap/servo_cf`, the Python package) that the servo thread adds to the
//! rendered force before the safety pipeline, so the force limit, the slew limit, the engage ramp and the
//! passivity controller treat it as they treat any rendered force (docs/safety.md).
//!
//! Where it sits: the control side checks a force ([`check_external_force`]) and writes it with a sequence
//! number into a triple buffer ([`ExternalForceSender`]); the servo thread reads the newest one each tick
//! ([`ExternalForceReceiver::force_at`]: wait-free, no lock, no allocation) and notes the tick at which a new
//! sequence number first appeared. A force is applied for [`ExternalForceReceiver::timeout_ticks`] ticks from
//! then and is zero after that unless a newer one comes: a sender that stops (crashed, disconnected) leaves
//! no force behind. Ages count servo ticks (skipped ticks included), so the timeout holds on the servo's own
//! clock, and a mock clock runs it deterministically.

use glam::DVec3;
use std::time::Duration;

/// The largest external force accepted (N, magnitude). Above any force a haptic device renders (the safety
/// pipeline caps the sum at the device's own limit anyway), so a larger value is a mistake (a unit error, a
/// controller gone wrong) and is refused rather than clamped.
pub const MAX_EXTERNAL_FORCE_N: f64 = 1000.0;

/// The staleness timeout when `--external-force-timeout` is not given.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(100);

/// The shortest and longest staleness timeouts accepted (s).
pub const TIMEOUT_RANGE_S: (f64, f64) = (0.001, 5.0);

/// Why an external force was refused. Nothing of a refused force reaches the servo thread.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExternalForceError {
    /// A component is NaN or infinite.
    #[error("external force component {axis} = {value} is not a finite number (newtons)")]
    NotFinite { axis: char, value: f64 },
    /// The magnitude is above [`MAX_EXTERNAL_FORCE_N`].
    #[error(
        "external force {force_n:?} N has magnitude {magnitude_n} N, above the {max_n} N accepted \
         (a unit mistake? forces are in newtons)"
    )]
    TooLarge {
        force_n: [f64; 3],
        magnitude_n: f64,
        max_n: f64,
    },
}

/// Checks a force a client sent: three finite components with a magnitude of at most
/// [`MAX_EXTERNAL_FORCE_N`].
pub fn check_external_force(force_n: [f64; 3]) -> Result<DVec3, ExternalForceError> {
    for (axis, value) in ['x', 'y', 'z'].into_iter().zip(force_n) {
        if !value.is_finite() {
            return Err(ExternalForceError::NotFinite { axis, value });
        }
    }
    let force = DVec3::from_array(force_n);
    let magnitude_n = force.length();
    // Finite components: the magnitude is finite or (overflowing) +inf, never NaN.
    if magnitude_n > MAX_EXTERNAL_FORCE_N {
        return Err(ExternalForceError::TooLarge {
            force_n,
            magnitude_n,
            max_n: MAX_EXTERNAL_FORCE_N,
        });
    }
    Ok(force)
}

/// One force as it crosses to the servo thread. `sequence` 0 is "nothing sent yet".
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Message {
    force_n: DVec3,
    sequence: u64,
}

/// The control side's end: writes checked forces (never blocks the servo thread).
pub struct ExternalForceSender {
    input: triple_buffer::Input<Message>,
    sequence: u64,
}

impl ExternalForceSender {
    /// Checks `force_n` and hands it to the servo thread; a refused force changes nothing.
    pub fn send(&mut self, force_n: [f64; 3]) -> Result<DVec3, ExternalForceError> {
        let force = check_external_force(force_n)?;
        self.sequence += 1;
        self.input.write(Message {
            force_n: force,
            sequence: self.sequence,
        });
        Ok(force)
    }
}

/// The servo thread's end (see the module docs).
pub struct ExternalForceReceiver {
    output: triple_buffer::Output<Message>,
    timeout_ticks: u64,
    last_sequence: u64,
    /// The tick at which the newest force was first seen.
    seen_at_tick: Option<u64>,
}

impl ExternalForceReceiver {
    /// The force to add at tick `tick`: the newest one sent, while it is younger than the timeout; zero
    /// before any was sent and after the timeout. Wait-free; no lock, no allocation.
    pub fn force_at(&mut self, tick: u64) -> DVec3 {
        let message = *self.output.read();
        if message.sequence != self.last_sequence {
            self.last_sequence = message.sequence;
            self.seen_at_tick = Some(tick);
        }
        match self.seen_at_tick {
            // Checked by the sender; checked again so nothing else can ever reach the device.
            Some(seen) if tick.saturating_sub(seen) < self.timeout_ticks => {
                if message.force_n.is_finite() && message.force_n.length() <= MAX_EXTERNAL_FORCE_N {
                    message.force_n
                } else {
                    DVec3::ZERO
                }
            }
            _ => DVec3::ZERO,
        }
    }

    /// Ticks a force is applied for after the tick that first saw it.
    pub fn timeout_ticks(&self) -> u64 {
        self.timeout_ticks
    }
}

/// The ticks of `period_ns` in `timeout`, rounded up, at least 1.
pub fn timeout_ticks(timeout: Duration, period_ns: u64) -> u64 {
    let timeout_ns = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
    timeout_ns.div_ceil(period_ns.max(1)).max(1)
}

/// A connected sender and receiver for a loop of period `period_ns` with staleness timeout `timeout`.
pub fn channel(timeout: Duration, period_ns: u64) -> (ExternalForceSender, ExternalForceReceiver) {
    let (input, output) = triple_buffer::triple_buffer(&Message::default());
    (
        ExternalForceSender { input, sequence: 0 },
        ExternalForceReceiver {
            output,
            timeout_ticks: timeout_ticks(timeout, period_ns),
            last_sequence: 0,
            seen_at_tick: None,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_force_lasts_the_timeout_counted_from_the_tick_that_first_saw_it() {
        // 100 ms at 1 kHz is 100 ticks; 2.5 ms at 1 kHz rounds up to 3.
        assert_eq!(timeout_ticks(Duration::from_millis(100), 1_000_000), 100);
        assert_eq!(timeout_ticks(Duration::from_micros(2500), 1_000_000), 3);
        assert_eq!(timeout_ticks(Duration::from_nanos(1), 1_000_000), 1);
        let (mut sender, mut receiver) = channel(Duration::from_millis(3), 1_000_000);
        assert_eq!(receiver.force_at(0), DVec3::ZERO, "nothing sent yet");
        sender.send([1.0, -2.0, 0.5]).unwrap();
        let expected = DVec3::new(1.0, -2.0, 0.5);
        // Seen at tick 10: applied at 10, 11, 12 (3 ticks), zero from 13 on.
        assert_eq!(receiver.force_at(10), expected);
        assert_eq!(receiver.force_at(12), expected);
        assert_eq!(receiver.force_at(13), DVec3::ZERO);
        assert_eq!(receiver.force_at(500), DVec3::ZERO);
        // The same value sent again is a new message: applied again from the tick that sees it.
        sender.send([1.0, -2.0, 0.5]).unwrap();
        assert_eq!(receiver.force_at(501), expected);
        // Skipped ticks count: a tick 3 later (an overrun skipped two) is past the timeout.
        assert_eq!(receiver.force_at(504), DVec3::ZERO);
    }

    #[test]
    fn non_finite_and_absurd_forces_are_refused_and_change_nothing() {
        let (mut sender, mut receiver) = channel(Duration::from_secs(1), 1_000_000);
        sender.send([0.0, 0.0, 2.0]).unwrap();
        for bad in [
            [f64::NAN, 0.0, 0.0],
            [0.0, f64::INFINITY, 0.0],
            [0.0, 0.0, f64::NEG_INFINITY],
            [1e300, 1e300, 0.0],
            [800.0, 800.0, 0.0],
        ] {
            let error = sender.send(bad).unwrap_err().to_string();
            assert!(
                error.contains("not a finite number") || error.contains("above the 1000 N"),
                "{error}"
            );
        }
        assert!(matches!(
            sender.send([0.0, 0.0, f64::NAN]),
            Err(ExternalForceError::NotFinite { axis: 'z', .. })
        ));
        // Refused forces changed nothing: the servo still sees the first one.
        assert_eq!(receiver.force_at(0), DVec3::new(0.0, 0.0, 2.0));
        // 1000 N exactly is accepted (the device's own limit caps it later).
        assert!(sender.send([0.0, 0.0, 1000.0]).is_ok());
        assert_eq!(receiver.force_at(1), DVec3::new(0.0, 0.0, 1000.0));
    }
}
