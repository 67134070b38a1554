//! The HID transport's waits over a double with hidapi's millisecond-only reads (hidapi.h,
//! `hid_read_timeout(dev, data, length, milliseconds)`).

use super::{HidTransport, MillisecondHid};
use crate::transport::ReportTransport;
use crate::DeviceError;
use std::time::{Duration, Instant};

/// One report that becomes readable at `ready_at`; reads wait in whole milliseconds only, as hidapi's.
struct OneLateReport {
    ready_at: Instant,
    taken: bool,
    /// The waits asked of the device (ms).
    asked_ms: Vec<i32>,
}

impl MillisecondHid for OneLateReport {
    fn write(&mut self, report: &[u8]) -> Result<usize, DeviceError> {
        Ok(report.len())
    }

    fn read_timeout(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, DeviceError> {
        assert!(timeout_ms >= 0, "hidapi blocks forever on a negative wait");
        self.asked_ms.push(timeout_ms);
        let until = Instant::now() + Duration::from_millis(timeout_ms as u64);
        let wake = until.min(self.ready_at);
        std::thread::sleep(wake.saturating_duration_since(Instant::now()));
        if self.taken || Instant::now() < self.ready_at {
            return Ok(0);
        }
        self.taken = true;
        buf[..4].copy_from_slice(&[1, 2, 3, 4]);
        Ok(4)
    }
}

fn late_report(after: Duration) -> HidTransport<OneLateReport> {
    HidTransport::on(OneLateReport {
        ready_at: Instant::now() + after,
        taken: false,
        asked_ms: Vec::new(),
    })
}

/// A report that comes 0.3 ms into a 0.8 ms wait is read. Rounding the wait down to whole milliseconds (what
/// `timeout.as_millis()` handed to hidapi did) reads once without waiting and misses it: checked by putting
/// that back, which fails this test. Whatever the load, the last read happens at or after the deadline, by
/// which time the report is ready.
#[test]
fn a_sub_millisecond_wait_is_waited_out() {
    let mut transport = late_report(Duration::from_micros(300));
    let mut buf = [0u8; 8];
    let n = transport
        .read_report(&mut buf, Duration::from_micros(800))
        .unwrap();
    assert_eq!(&buf[..n], &[1, 2, 3, 4]);
    assert!(transport.device().asked_ms.iter().all(|&ms| ms == 0));
}

/// A wait of several milliseconds goes to the device in whole milliseconds first, never longer than what is
/// left, and ends with nothing when nothing came.
#[test]
fn a_long_wait_never_asks_for_more_than_is_left() {
    let mut transport = late_report(Duration::from_secs(3600));
    let mut buf = [0u8; 8];
    let wait = Duration::from_micros(2_500);
    let started = Instant::now();
    assert_eq!(transport.read_report(&mut buf, wait).unwrap(), 0);
    assert!(started.elapsed() >= wait);
    let asked = &transport.device().asked_ms;
    assert!(asked[0] == 2 || asked[0] == 1, "{asked:?}");
    assert!(asked.iter().all(|&ms| ms <= 2), "{asked:?}");
    assert_eq!(*asked.last().unwrap(), 0);
}

/// A zero wait reads exactly once, without waiting.
#[test]
fn a_zero_wait_reads_once() {
    let mut transport = late_report(Duration::from_secs(3600));
    let mut buf = [0u8; 8];
    assert_eq!(transport.read_report(&mut buf, Duration::ZERO).unwrap(), 0);
    assert_eq!(transport.device().asked_ms, vec![0]);
}
