//! The shared runner of the request/reply drivers (Falcon, Haply 2DIY, WoodenHaptics serial) and of the
//! report-streaming WoodenHaptics 1.5 HID driver ([`newest_report_within`]), and of the Haply Inverse3's message
//! link ([`messages_within`], run on its I/O thread): the one place that reads a port with a deadline. Each
//! driver's protocol logic sits in a receive core with no I/O and no clock ([`super::assemble`],
//! [`super::falcon_frames::FrameAssembler`], [`super::haply_inverse::link`]); the runner moves bytes from the
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

/// A transport of whole messages (the Haply Inverse Service's WebSocket), read by [`messages_within`].
pub trait MessageTransport {
    /// One message as the transport delivers it.
    type Message;

    /// The next whole message already received, without waiting; `Ok(None)`: none is waiting.
    fn try_read_message(&mut self) -> Result<Option<Self::Message>, DeviceError>;

    /// Waits until a message may have come, or `wait` has passed.
    fn wait_readable(&mut self, wait: Duration) -> Result<(), DeviceError>;
}

/// The receive core of a message link, fed by [`messages_within`].
pub trait MessageCore<M> {
    /// One message; an error (a flood the core bounds) ends the read.
    fn message(&mut self, message: M) -> Result<(), DeviceError>;

    /// The transport was found with nothing more waiting.
    fn emptied(&mut self);

    /// A reply is still awaited: the runner waits for more until the wait is over.
    fn awaiting(&self) -> bool;
}

/// The longest single wait of [`messages_within`], so a core that stops awaiting (a stop) is looked at again
/// soon.
pub const MESSAGE_WAIT_SLICE: Duration = Duration::from_millis(1);

/// Reads every message already waiting into `core` until the transport is found empty; then, while the core
/// awaits a reply and `wait` has not passed, waits (in slices of at most [`MESSAGE_WAIT_SLICE`]) and reads
/// again. Returns once the transport was found empty and the core awaits nothing or the wait is over, so the
/// core always holds the newest message and the transport never holds one unread. The core bounds a flood.
pub fn messages_within<T, C>(
    transport: &mut T,
    core: &mut C,
    wait: Duration,
) -> Result<(), DeviceError>
where
    T: MessageTransport + ?Sized,
    C: MessageCore<T::Message> + ?Sized,
{
    let deadline = Instant::now() + wait;
    loop {
        match transport.try_read_message()? {
            Some(message) => core.message(message)?,
            None => {
                core.emptied();
                let remaining = deadline.saturating_duration_since(Instant::now());
                if !core.awaiting() || remaining.is_zero() {
                    return Ok(());
                }
                transport.wait_readable(remaining.min(MESSAGE_WAIT_SLICE))?;
            }
        }
    }
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

    /// A message link scripted step by step: `Some(m)` a message waiting, `None` nothing waiting at that read.
    struct Script {
        steps: std::collections::VecDeque<Option<u32>>,
        waits: u32,
    }

    impl MessageTransport for Script {
        type Message = u32;
        fn try_read_message(&mut self) -> Result<Option<u32>, DeviceError> {
            Ok(self.steps.pop_front().flatten())
        }
        fn wait_readable(&mut self, _: Duration) -> Result<(), DeviceError> {
            self.waits += 1;
            Ok(())
        }
    }

    /// A core that awaits the message `until`.
    struct Await {
        got: Vec<u32>,
        empties: u32,
        until: u32,
    }

    impl MessageCore<u32> for Await {
        fn message(&mut self, message: u32) -> Result<(), DeviceError> {
            self.got.push(message);
            Ok(())
        }
        fn emptied(&mut self) {
            self.empties += 1;
        }
        fn awaiting(&self) -> bool {
            !self.got.contains(&self.until)
        }
    }

    /// Worked by hand: everything waiting is read, each time the link is found empty the core is told, and the
    /// runner waits on only while the core awaits its reply; with a zero wait it reads what is there and no
    /// more.
    #[test]
    fn messages_are_read_until_empty_and_awaited_only_while_a_reply_is_due() {
        let script = |steps: &[Option<u32>]| Script {
            steps: steps.iter().copied().collect(),
            waits: 0,
        };
        let mut link = script(&[Some(1), Some(2), None, None, Some(3), None, Some(4)]);
        let mut core = Await {
            got: Vec::new(),
            empties: 0,
            until: 3,
        };
        messages_within(&mut link, &mut core, Duration::from_secs(10)).unwrap();
        assert_eq!(
            (core.got.as_slice(), core.empties, link.waits),
            (&[1, 2, 3][..], 3, 2)
        );
        assert_eq!(
            link.steps.len(),
            1,
            "message 4 came after the link was found empty"
        );
        let mut link = script(&[Some(1), None, Some(2)]);
        let mut core = Await {
            got: Vec::new(),
            empties: 0,
            until: 2,
        };
        messages_within(&mut link, &mut core, Duration::ZERO).unwrap();
        assert_eq!(
            (core.got.as_slice(), core.empties, link.waits),
            (&[1][..], 1, 0)
        );
    }
}
