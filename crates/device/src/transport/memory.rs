//! In-memory transports for tests: scripted transactions in the embedded-hal-mock manner ([`ScriptedStream`],
//! [`ScriptedReports`]), each checked by `done()`, and [`MemoryPipe`], a duplex byte pipe between a driver and a
//! simulated device in the same process.
//!
//! The scripted doubles panic on an unexpected call, with a message naming the step: that is their purpose (a
//! test double that tolerated a wrong byte would hide a driver bug). They are not used outside tests and benches:
//! they exist only in this crate's own tests and with the `test-support` feature.

use super::{ByteTransport, ReportTransport};
use crate::DeviceError;
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

/// One expected transaction of a scripted transport.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transaction {
    /// The driver writes exactly these bytes (one `write_all` or `write_report` call).
    Write(Vec<u8>),
    /// The driver reads, and gets these bytes (a byte stream may take them over several reads).
    Read(Vec<u8>),
    /// The driver reads, and nothing arrives in time (a timed [`ScriptedReports`]: a report the device never
    /// sent).
    ReadTimeout,
    /// A timed [`ScriptedReports`] only: a report that arrives this much later than its slot (jitter, a late
    /// reply). An untimed double treats it as a read that times out.
    Late(Duration, Vec<u8>),
    /// The next call (read or write) fails with a disconnect.
    Disconnect,
}

impl Transaction {
    /// A write of these bytes.
    pub fn write(bytes: &[u8]) -> Transaction {
        Transaction::Write(bytes.to_vec())
    }

    /// A read returning these bytes.
    pub fn read(bytes: &[u8]) -> Transaction {
        Transaction::Read(bytes.to_vec())
    }
}

#[derive(Debug)]
struct Script {
    expected: VecDeque<Transaction>,
    step: usize,
}

impl Script {
    fn new(transactions: &[Transaction]) -> Script {
        Script {
            expected: transactions.iter().cloned().collect(),
            step: 0,
        }
    }

    fn next(&mut self, call: &str) -> Transaction {
        self.step += 1;
        match self.expected.pop_front() {
            Some(transaction) => transaction,
            None => panic!(
                "scripted transport: unexpected {call} at step {} (script finished)",
                self.step
            ),
        }
    }

    fn write(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        match self.next("write") {
            Transaction::Write(expected) => {
                assert_eq!(
                    bytes,
                    expected.as_slice(),
                    "scripted transport: step {} wrote {:02x?}, expected {:02x?}",
                    self.step,
                    bytes,
                    expected
                );
                Ok(())
            }
            Transaction::Disconnect => Err(disconnected("writing")),
            other => panic!(
                "scripted transport: step {} is {other:?}, but the driver wrote {bytes:02x?}",
                self.step
            ),
        }
    }

    /// True when a poll (a read with a zero timeout) finds nothing queued: the script's next step is a write or
    /// the script is finished. Scripts model a queue, so draining it ("read until nothing is left") needs no
    /// extra script steps; an explicit `ReadTimeout` or `Disconnect` step is still consumed by a poll.
    fn poll_finds_nothing(&self, timeout: Duration) -> bool {
        timeout.is_zero() && matches!(self.expected.front(), None | Some(Transaction::Write(_)))
    }

    fn done(&self) {
        assert!(
            self.expected.is_empty(),
            "scripted transport: {} transactions never happened: {:?}",
            self.expected.len(),
            self.expected
        );
    }
}

fn disconnected(during: &'static str) -> DeviceError {
    DeviceError::Disconnected {
        during,
        kind: std::io::ErrorKind::BrokenPipe,
    }
}

/// A scripted byte stream.
#[derive(Debug)]
pub struct ScriptedStream {
    script: Script,
}

impl ScriptedStream {
    /// A stream that expects exactly `transactions`, in order.
    pub fn new(transactions: &[Transaction]) -> ScriptedStream {
        ScriptedStream {
            script: Script::new(transactions),
        }
    }

    /// Panics unless every expected transaction happened.
    pub fn done(&self) {
        self.script.done();
    }
}

impl ByteTransport for ScriptedStream {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        self.script.write(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        if self.script.poll_finds_nothing(timeout) {
            return Ok(0);
        }
        match self.script.next("read") {
            Transaction::Read(mut bytes) => {
                let n = bytes.len().min(buf.len());
                buf[..n].copy_from_slice(&bytes[..n]);
                if n < bytes.len() {
                    // The rest stays for the next read.
                    bytes.drain(..n);
                    self.script.expected.push_front(Transaction::Read(bytes));
                    self.script.step -= 1;
                }
                Ok(n)
            }
            Transaction::ReadTimeout | Transaction::Late(..) => Ok(0),
            Transaction::Disconnect => Err(disconnected("reading")),
            Transaction::Write(expected) => panic!(
                "scripted transport: step {} expects a write of {expected:02x?}, but the driver read",
                self.script.step
            ),
        }
    }
}

/// Copies a scripted report into the driver's buffer (a report that does not fit is a test bug: panic).
fn copy_report(bytes: &[u8], buf: &mut [u8]) -> usize {
    assert!(
        bytes.len() <= buf.len(),
        "scripted transport: report of {} bytes does not fit the driver's {}-byte buffer",
        bytes.len(),
        buf.len()
    );
    buf[..bytes.len()].copy_from_slice(bytes);
    bytes.len()
}

/// The time model of a timed [`ScriptedReports`]: a virtual clock, so a test can show what a driver does with a
/// report that comes late or not at all, without sleeping and whatever the machine's load.
///
/// The device sends its `i`-th report (the `i`-th `Read` of the script; a `ReadTimeout` step is a report the
/// device never sent) `latency + i * report_period` after the script starts, plus that report's own extra delay
/// ([`Transaction::Late`], jitter). The driver's `k`-th write starts servo tick `k`, at `k * servo_period` (or
/// later, if its reads already waited past that). A read at virtual time `now` with timeout `w` returns the
/// oldest report not read yet if it has arrived by `now + w` (the clock moves on to its arrival), and otherwise
/// nothing (the clock moves on by `w`): a report arriving after the read gave up is seen late, by a later read.
/// Writes are checked in order against the script's `Write` steps, as in the untimed double.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReportTiming {
    /// The driver's servo period: write `k` is at `k * servo_period`.
    pub servo_period: Duration,
    /// The device's report interval (its input rate).
    pub report_period: Duration,
    /// From the script's start (the device's report slot) to the report being readable by the host: the
    /// device's documented latency.
    pub latency: Duration,
}

#[derive(Debug)]
struct Timed {
    timing: ReportTiming,
    now: Duration,
    writes: u32,
    /// Reports not read yet: arrival time, bytes.
    in_flight: VecDeque<(Duration, Vec<u8>)>,
    disconnect_after: Option<usize>,
}

/// A scripted HID report transport, untimed ([`ScriptedReports::new`]: a read gets the next scripted report at
/// once) or timed ([`ScriptedReports::timed`], [`ReportTiming`]).
#[derive(Debug)]
pub struct ScriptedReports {
    script: Script,
    timed: Option<Timed>,
}

impl ScriptedReports {
    /// A transport that expects exactly `transactions`, in order.
    pub fn new(transactions: &[Transaction]) -> ScriptedReports {
        ScriptedReports {
            script: Script::new(transactions),
            timed: None,
        }
    }

    /// A transport with a time model ([`ReportTiming`]): the `Write` steps are the writes expected, in order;
    /// the `Read`, `Late` and `ReadTimeout` steps are the device's report slots, in order; a `Disconnect` step
    /// makes every call fail once the reports before it were read.
    pub fn timed(transactions: &[Transaction], timing: ReportTiming) -> ScriptedReports {
        let mut writes = Vec::new();
        let mut in_flight = VecDeque::new();
        let mut slot = 0u32;
        let mut disconnect_after = None;
        for transaction in transactions {
            let arrival = timing.latency + timing.report_period * slot;
            match transaction {
                Transaction::Write(_) => writes.push(transaction.clone()),
                Transaction::Read(bytes) => {
                    in_flight.push_back((arrival, bytes.clone()));
                    slot += 1;
                }
                Transaction::Late(extra, bytes) => {
                    in_flight.push_back((arrival + *extra, bytes.clone()));
                    slot += 1;
                }
                Transaction::ReadTimeout => slot += 1,
                Transaction::Disconnect => {
                    disconnect_after.get_or_insert(in_flight.len());
                }
            }
        }
        ScriptedReports {
            script: Script::new(&writes),
            timed: Some(Timed {
                timing,
                now: Duration::ZERO,
                writes: 0,
                in_flight,
                disconnect_after,
            }),
        }
    }

    /// The virtual time of a timed double (zero for an untimed one).
    pub fn now(&self) -> Duration {
        self.timed.as_ref().map_or(Duration::ZERO, |t| t.now)
    }

    /// Panics unless every expected transaction happened (for a timed double: every write, and every report
    /// read).
    pub fn done(&self) {
        self.script.done();
        if let Some(timed) = &self.timed {
            assert!(
                timed.in_flight.is_empty(),
                "scripted reports: {} reports never read",
                timed.in_flight.len()
            );
        }
    }
}

impl Timed {
    fn disconnected(&self) -> bool {
        self.disconnect_after == Some(0)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        if self.disconnected() {
            return Err(disconnected("reading"));
        }
        match self.in_flight.front() {
            Some((arrival, _)) if *arrival <= self.now + timeout => {
                let (arrival, bytes) = self.in_flight.pop_front().unwrap_or_default();
                self.now = self.now.max(arrival);
                if let Some(after) = self.disconnect_after.as_mut() {
                    *after = after.saturating_sub(1);
                }
                Ok(copy_report(&bytes, buf))
            }
            _ => {
                self.now += timeout;
                Ok(0)
            }
        }
    }
}

impl ReportTransport for ScriptedReports {
    fn write_report(&mut self, report: &[u8]) -> Result<(), DeviceError> {
        if let Some(timed) = self.timed.as_mut() {
            if timed.disconnected() {
                return Err(disconnected("writing"));
            }
            timed.now = timed.now.max(timed.timing.servo_period * timed.writes);
            timed.writes += 1;
        }
        self.script.write(report)
    }

    fn read_report(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        if let Some(timed) = self.timed.as_mut() {
            return timed.read(buf, timeout);
        }
        if self.script.poll_finds_nothing(timeout) {
            return Ok(0);
        }
        match self.script.next("read_report") {
            Transaction::Read(bytes) => {
                Ok(copy_report(&bytes, buf))
            }
            Transaction::ReadTimeout | Transaction::Late(..) => Ok(0),
            Transaction::Disconnect => Err(disconnected("reading")),
            Transaction::Write(expected) => panic!(
                "scripted transport: step {} expects a write of {expected:02x?}, but the driver read",
                self.script.step
            ),
        }
    }
}

/// Bytes one direction of a [`MemoryPipe`] holds before a write waits for the reader, like the buffer of a tty.
/// Reserved when the pipe is made, so passing bytes never allocates (the allocation-free servo tests run
/// drivers over this pipe: a growing buffer allocated on the driver's thread whenever the device double's
/// thread fell behind, seen once in a CI run).
pub const MEMORY_PIPE_CAPACITY: usize = 64 * 1024;

/// How long a write into a full [`MemoryPipe`] waits for the reader before it fails with a timeout.
pub const MEMORY_PIPE_WRITE_TIMEOUT: Duration = Duration::from_millis(200);

#[derive(Debug)]
struct Channel {
    bytes: Mutex<(VecDeque<u8>, bool)>,
    ready: Condvar,
}

impl Channel {
    fn new() -> Channel {
        Channel {
            bytes: Mutex::new((VecDeque::with_capacity(MEMORY_PIPE_CAPACITY), false)),
            ready: Condvar::new(),
        }
    }
}

/// One end of an in-memory duplex byte pipe (tests and in-process simulations; it locks, so it is not for the
/// servo thread of a real run). Each direction holds at most [`MEMORY_PIPE_CAPACITY`] bytes, reserved up
/// front; a writer facing a full pipe waits for the reader up to [`MEMORY_PIPE_WRITE_TIMEOUT`].
#[derive(Debug, Clone)]
pub struct MemoryPipe {
    incoming: Arc<Channel>,
    outgoing: Arc<Channel>,
}

impl MemoryPipe {
    /// Two connected ends.
    pub fn pair() -> (MemoryPipe, MemoryPipe) {
        let a = Arc::new(Channel::new());
        let b = Arc::new(Channel::new());
        (
            MemoryPipe {
                incoming: a.clone(),
                outgoing: b.clone(),
            },
            MemoryPipe {
                incoming: b,
                outgoing: a,
            },
        )
    }

    /// Hangs up: both ends see a disconnect from now on.
    pub fn close(&self) {
        for channel in [&self.incoming, &self.outgoing] {
            if let Ok(mut guard) = channel.bytes.lock() {
                guard.1 = true;
            }
            channel.ready.notify_all();
        }
    }
}

impl ByteTransport for MemoryPipe {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        let mut guard = self
            .outgoing
            .bytes
            .lock()
            .map_err(|_| disconnected("writing"))?;
        let mut rest = bytes;
        loop {
            if guard.1 {
                return Err(disconnected("writing"));
            }
            let room = MEMORY_PIPE_CAPACITY - guard.0.len();
            let n = room.min(rest.len());
            guard.0.extend(&rest[..n]);
            rest = &rest[n..];
            self.outgoing.ready.notify_all();
            if rest.is_empty() {
                return Ok(());
            }
            let (next, wait) = self
                .outgoing
                .ready
                .wait_timeout_while(guard, MEMORY_PIPE_WRITE_TIMEOUT, |(bytes, closed)| {
                    bytes.len() == MEMORY_PIPE_CAPACITY && !*closed
                })
                .map_err(|_| disconnected("writing"))?;
            guard = next;
            if wait.timed_out() && guard.0.len() == MEMORY_PIPE_CAPACITY {
                return Err(DeviceError::Timeout {
                    waited_us: MEMORY_PIPE_WRITE_TIMEOUT.as_micros() as u64,
                    waiting_for: "room in the in-memory pipe (its reader stopped reading)",
                });
            }
        }
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        let guard = self
            .incoming
            .bytes
            .lock()
            .map_err(|_| disconnected("reading"))?;
        let (mut guard, _) = self
            .incoming
            .ready
            .wait_timeout_while(guard, timeout, |(bytes, closed)| {
                bytes.is_empty() && !*closed
            })
            .map_err(|_| disconnected("reading"))?;
        if guard.0.is_empty() {
            return if guard.1 {
                Err(disconnected("reading"))
            } else {
                Ok(0)
            };
        }
        let n = guard.0.len().min(buf.len());
        for (slot, byte) in buf.iter_mut().zip(guard.0.drain(..n)) {
            *slot = byte;
        }
        // A writer may be waiting for room.
        self.incoming.ready.notify_all();
        Ok(n)
    }

    fn discard_input(&mut self) -> Result<(), DeviceError> {
        if let Ok(mut guard) = self.incoming.bytes.lock() {
            guard.0.clear();
        }
        self.incoming.ready.notify_all();
        Ok(())
    }

    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        Some(Box::new(self.clone()))
    }
}

impl std::io::Write for MemoryPipe {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        ByteTransport::write_all(self, bytes)
            .map(|()| bytes.len())
            .map_err(|_| std::io::Error::from(std::io::ErrorKind::BrokenPipe))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_pipe_makes_the_writer_wait_for_the_reader_and_then_time_out() {
        let (mut host, mut device) = MemoryPipe::pair();
        host.write_all(&vec![7u8; MEMORY_PIPE_CAPACITY]).unwrap();
        let error = host.write_all(&[1]).unwrap_err();
        assert!(
            matches!(error, DeviceError::Timeout { waiting_for, .. } if waiting_for.contains("room")),
            "{error}"
        );
        // The reader frees room: the next write goes through, and nothing was lost or reordered.
        let mut buf = [0u8; 16];
        assert_eq!(device.read(&mut buf, Duration::ZERO).unwrap(), 16);
        host.write_all(&[1, 2, 3]).unwrap();
        let mut all = vec![0u8; MEMORY_PIPE_CAPACITY];
        let mut got = 0;
        while got < MEMORY_PIPE_CAPACITY - 16 + 3 {
            got += device.read(&mut all[got..], Duration::ZERO).unwrap();
        }
        assert!(all[..MEMORY_PIPE_CAPACITY - 16].iter().all(|&b| b == 7));
        assert_eq!(&all[MEMORY_PIPE_CAPACITY - 16..got], &[1, 2, 3]);
    }

    #[test]
    fn a_write_larger_than_the_pipe_completes_while_the_reader_reads() {
        let (mut host, mut device) = MemoryPipe::pair();
        let sent: Vec<u8> = (0..3 * MEMORY_PIPE_CAPACITY)
            .map(|i| (i % 251) as u8)
            .collect();
        let expected = sent.clone();
        let writer = std::thread::spawn(move || host.write_all(&sent));
        let mut received = Vec::new();
        let mut buf = [0u8; 4096];
        while received.len() < expected.len() {
            let n = device.read(&mut buf, Duration::from_secs(5)).unwrap();
            assert!(n > 0, "the writer stalled after {} bytes", received.len());
            received.extend_from_slice(&buf[..n]);
        }
        writer.join().unwrap().unwrap();
        assert_eq!(received, expected);
    }

    #[test]
    fn scripted_stream_splits_a_long_read_and_reports_completion() {
        let mut stream = ScriptedStream::new(&[
            Transaction::write(&[1, 2]),
            Transaction::read(&[3, 4, 5]),
            Transaction::ReadTimeout,
        ]);
        stream.write_all(&[1, 2]).unwrap();
        let mut buf = [0u8; 2];
        assert_eq!(stream.read(&mut buf, Duration::ZERO).unwrap(), 2);
        assert_eq!(buf, [3, 4]);
        assert_eq!(stream.read(&mut buf, Duration::ZERO).unwrap(), 1);
        assert_eq!(buf[0], 5);
        assert_eq!(stream.read(&mut buf, Duration::ZERO).unwrap(), 0);
        stream.done();
    }

    #[test]
    #[should_panic(expected = "wrote")]
    fn scripted_stream_rejects_a_wrong_write() {
        let mut stream = ScriptedStream::new(&[Transaction::write(&[1, 2])]);
        let _ = stream.write_all(&[1, 3]);
    }

    #[test]
    #[should_panic(expected = "never happened")]
    fn done_notices_missing_transactions() {
        ScriptedStream::new(&[Transaction::ReadTimeout]).done();
    }

    #[test]
    fn memory_pipe_carries_bytes_both_ways_and_reports_hang_up() {
        let (mut a, mut b) = MemoryPipe::pair();
        a.write_all(b"ping").unwrap();
        let mut buf = [0u8; 8];
        assert_eq!(b.read(&mut buf, Duration::from_millis(100)).unwrap(), 4);
        assert_eq!(&buf[..4], b"ping");
        assert_eq!(a.read(&mut buf, Duration::from_millis(1)).unwrap(), 0);
        b.close();
        let error = a.read(&mut buf, Duration::from_millis(1)).unwrap_err();
        assert!(matches!(error, DeviceError::Disconnected { .. }));
    }
}
