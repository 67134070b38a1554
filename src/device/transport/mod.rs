//! Transports: how bytes reach a device. A driver sits on a transport, so the same driver code runs against a
//! serial port, a pseudo-terminal, a USB HID device, an in-memory pipe to a simulated device, or a scripted test
//! double (STYLE.md 7).
//!
//! Two shapes: [`ByteTransport`] is a byte stream (UART, USB CDC-ACM, pseudo-terminal) whose framing the driver
//! does; [`ReportTransport`] moves whole HID reports. Reads take a timeout and return `Ok(0)` when nothing came,
//! so a timeout is the driver's decision, not the transport's; a hang-up is `DeviceError::Disconnected`.

pub mod hid;
pub mod memory;
pub mod serial;

pub use hid::HidTransport;
pub use memory::{MemoryPipe, ScriptedReports, ScriptedStream};
pub use serial::SerialTransport;

use super::DeviceError;
use std::time::Duration;

/// A byte stream to a device.
pub trait ByteTransport {
    /// Writes all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError>;

    /// Reads what is available into `buf`, waiting at most `timeout` for the first byte. `Ok(0)` means nothing
    /// arrived in time.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError>;

    /// Throws away whatever the device sent before now (stale replies of an earlier session), as a driver
    /// does when it opens the link.
    fn discard_input(&mut self) -> Result<(), DeviceError> {
        Ok(())
    }

    /// A second, write-only handle to the same link, for the stall monitor's emergency stop
    /// ([`crate::device::EmergencyStop`]); `None` where the transport cannot be shared.
    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        None
    }
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
