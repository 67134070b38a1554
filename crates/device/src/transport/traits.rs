//! The transport traits ([`ByteTransport`], [`ReportTransport`]) and the advice an open failure carries.

use crate::DeviceError;
use std::time::Duration;

/// A byte stream to a device.
pub trait ByteTransport {
    /// Writes all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError>;

    /// Reads what is available into `buf`, waiting at most `timeout` for the first byte. `Ok(0)` means nothing
    /// arrived in time.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError>;

    /// Throws away whatever the device sent before now (stale replies from an earlier session), so the next read
    /// starts at a fresh reply. The default reads with a zero timeout until nothing is left (at most 64 KiB, so a
    /// device that never stops talking cannot hold the caller).
    fn discard_input(&mut self) -> Result<(), DeviceError> {
        let mut scratch = [0u8; 256];
        let mut discarded = 0usize;
        while discarded < 65_536 {
            let n = self.read(&mut scratch, Duration::ZERO)?;
            if n == 0 {
                break;
            }
            discarded += n;
        }
        Ok(())
    }

    /// A second, write-only handle to the same link, for the stall monitor's emergency stop
    /// ([`crate::EmergencyStop`]); `None` where the transport cannot be shared.
    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        None
    }
}

/// The next step to suggest when opening a device failed with this OS error kind: what a lab user should check
/// or change. Used by every transport's open error, so the advice is the same for every device.
pub fn open_advice(kind: std::io::ErrorKind) -> &'static str {
    match kind {
        std::io::ErrorKind::PermissionDenied => {
            "add your user to the dialout group (then log out and in), or install contrib/udev/70-voxhap.rules \
             (see docs/devices/README.md)"
        }
        std::io::ErrorKind::NotFound => {
            "is it plugged in and switched on? `voxhap devices` lists what is connected"
        }
        std::io::ErrorKind::ResourceBusy | std::io::ErrorKind::AddrInUse => {
            "another program has the device open (a vendor tool, a second voxhap, ModemManager); close it and retry"
        }
        std::io::ErrorKind::ConnectionRefused => {
            "nothing listens there: is the vendor service running, and on that port?"
        }
        std::io::ErrorKind::TimedOut => "the device did not answer: unplug it, plug it in again and retry",
        _ => "check the cable and the path; `voxhap devices` lists what is connected",
    }
}

/// Builds the message of a [`DeviceError::Open`]: the OS reason, then the next step.
pub fn open_message(reason: &str, kind: std::io::ErrorKind) -> String {
    format!("{reason}: {}", open_advice(kind))
}

/// A transport of whole reports (USB HID). Output reports start with their report id (0 when the device uses
/// none), as hidapi expects.
pub trait ReportTransport {
    /// Sends one output report.
    fn write_report(&mut self, report: &[u8]) -> Result<(), DeviceError>;

    /// Receives one input report into `buf`, waiting at most `timeout`. `Ok(0)` means none arrived in time.
    fn read_report(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError>;
}

impl<T: ByteTransport + ?Sized> ByteTransport for Box<T> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        (**self).write_all(bytes)
    }
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        (**self).read(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), DeviceError> {
        (**self).discard_input()
    }
    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        (**self).try_clone_writer()
    }
}

impl<T: ReportTransport + ?Sized> ReportTransport for Box<T> {
    fn write_report(&mut self, report: &[u8]) -> Result<(), DeviceError> {
        (**self).write_report(report)
    }
    fn read_report(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        (**self).read_report(buf, timeout)
    }
}
