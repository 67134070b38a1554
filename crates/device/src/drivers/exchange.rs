//! The shared runner of the request/reply drivers (Falcon, Haply 2DIY, WoodenHaptics serial) and of the
//! report-streaming WoodenHaptics 1.5 HID driver ([`newest_report_within`]): the one place that reads a port
//! with a deadline. Each driver's protocol logic sits in a receive core with no I/O and no
//! clock ([`super::assemble`], [`super::falcon_frames::FrameAssembler`]); the runner moves bytes from the
//! transport into the core until the core yields a whole reply or the wait is over.
//!
//! The wait is the caller's, and on the servo thread it derives from the servo period
//! ([`super::reply_age::reply_wait`]: three quarters of it), so a reply that never comes costs at most one tick.
//! Once the wait has passed the runner still takes what is already waiting (reads that do not wait), but at
//! most [`LATE_POLLS`] of them, so a device that never stops sending cannot hold the tick.

use super::assemble::Receive;
use super::report_stream::{NewestReport, REPORT_CAPACITY};
use crate::transport::{ByteTransport, ReportTransport};
use crate::DeviceError;
use std::time::{Duration, Instant};

/// Reads that do not wait, after the wait has passed, while they still bring bytes.
pub const LATE_POLLS: u32 = 64;

/// Reads from `transport` into `core` until `take` yields a reply (returned), or the wait is over (`None`).
/// The port is read at least once, even with a zero wait. `take` is the core's own `next_*` method; its error
/// (a malformed reply the core cannot skip) ends the read.
pub fn receive_within<T, C, O>(
    transport: &mut T,
    core: &mut C,
    wait: Duration,
    mut take: impl FnMut(&mut C) -> Result<Option<O>, DeviceError>,
) -> Result<Option<O>, DeviceError>
where
    T: ByteTransport + ?Sized,
    C: Receive + ?Sized,
{
    let deadline = Instant::now() + wait;
    let mut late_polls = 0u32;
    loop {
        if let Some(reply) = take(core)? {
            return Ok(Some(reply));
        }
        let remaining = deadline.saturating_duration_since(Instant::now());
        if remaining.is_zero() {
            if late_polls == LATE_POLLS {
                return Ok(None);
            }
            late_polls += 1;
        }
        let space = core.space();
        if space.is_empty() {
            // A core that holds a whole reply yields it; an empty space with nothing to take would loop.
            return Ok(None);
        }
        let n = transport.read(space, remaining)?;
        if n == 0 {
            return Ok(None);
        }
        core.filled(n);
    }
}

/// Reports read after the first one of a tick, while the queue still holds some (bounded, so a device flooding
/// reports cannot hold the tick).
pub const DRAIN_REPORTS: u32 = 128;

/// Reads a tick's reports from `transport` into `core` ([`NewestReport`]): the first within `wait`, then what is
/// already queued (at most [`DRAIN_REPORTS`] more, without waiting). True when a report came.
pub fn newest_report_within<T: ReportTransport + ?Sized>(
    transport: &mut T,
    core: &mut NewestReport,
    wait: Duration,
) -> Result<bool, DeviceError> {
    core.begin();
    let mut scratch = [0u8; REPORT_CAPACITY];
    let n = transport.read_report(&mut scratch, wait)?;
    if n == 0 {
        return Ok(false);
    }
    core.report(&scratch[..n]);
    for _ in 0..DRAIN_REPORTS {
        let m = transport.read_report(&mut scratch, Duration::ZERO)?;
        if m == 0 {
            break;
        }
        core.report(&scratch[..m]);
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drivers::assemble::FixedAssembler;
    use crate::transport::memory::{ScriptedStream, Transaction};

    /// A port that always has one more byte: a device that never stops sending.
    struct Flood(u64);

    impl ByteTransport for Flood {
        fn write_all(&mut self, _: &[u8]) -> Result<(), DeviceError> {
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], _: Duration) -> Result<usize, DeviceError> {
            self.0 += 1;
            buf[0] = 0xff;
            Ok(1)
        }
    }

    /// A flood that never makes a whole reply ends the read after the bounded late polls, whatever the wait.
    #[test]
    fn a_flood_cannot_hold_the_read_past_its_bound() {
        let mut port = Flood(0);
        let mut core = crate::drivers::assemble::LineAssembler::<1024>::new();
        let got = receive_within(&mut port, &mut core, Duration::ZERO, |c| {
            Ok(c.next_line().map(|_| ()))
        })
        .unwrap();
        assert_eq!(got, None);
        assert_eq!(port.0, u64::from(LATE_POLLS));
    }

    /// A zero wait still reads once; a reply split over reads is put together; nothing waits past the script.
    #[test]
    fn a_zero_wait_reads_what_is_already_there() {
        let mut port = ScriptedStream::new(&[
            Transaction::read(&[1, 2, 3, 4]),
            Transaction::read(&[5, 6, 7, 8, 9]),
        ]);
        let mut core = FixedAssembler::<9>::new();
        let got = receive_within(&mut port, &mut core, Duration::ZERO, |c| Ok(c.next_reply()));
        assert_eq!(got.unwrap(), Some([1, 2, 3, 4, 5, 6, 7, 8, 9]));
        port.done();
        let mut empty = ScriptedStream::new(&[Transaction::ReadTimeout]);
        let got = receive_within(&mut empty, &mut core, Duration::from_millis(1), |c| {
            Ok(c.next_reply())
        });
        assert_eq!(got.unwrap(), None);
        empty.done();
    }
}
