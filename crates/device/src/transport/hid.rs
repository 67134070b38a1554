//! USB HID devices through `hidapi` (Linux hidraw backend with the pure-Rust `basic-udev`, no system libraries).
//!
//! Where it sits: under the HID drivers (voxhap protocol over HID, WoodenHaptics 1.5). Opening needs read/write
//! access to `/dev/hidraw*` (contrib/udev/70-voxhap.rules; see docs/devices/README.md).
//!
//! Waits shorter than a millisecond: hidapi's `hid_read_timeout` takes whole milliseconds (hidapi.h; the Rust
//! crate's `HidDevice::read_timeout(buf, i32)`), so a 0.5 ms wait handed to it as `as_millis()` would be a
//! non-blocking read. [`HidTransport::read_report`] waits out a deadline instead: whole milliseconds through
//! hidapi while at least one is left, then non-blocking reads every [`POLL_STEP`] until the deadline, and one
//! last read at it. The device behind it is anything with hidapi's millisecond-only read ([`MillisecondHid`]), so
//! tests run this same code over a double that, like hidapi, cannot wait less than a millisecond.

use super::ReportTransport;
use crate::DeviceError;
use hidapi::{HidApi, HidDevice};
use std::time::{Duration, Instant};

/// How long [`HidTransport::read_report`] sleeps between non-blocking reads in the last millisecond of a wait.
pub const POLL_STEP: Duration = Duration::from_micros(50);

/// A HID device as hidapi presents it: whole reports out, and reads whose wait is in whole milliseconds
/// (0 = do not wait).
pub trait MillisecondHid {
    /// Writes one report (with its report id byte); returns the bytes written.
    fn write(&mut self, report: &[u8]) -> Result<usize, DeviceError>;
    /// Reads one report, waiting at most `timeout_ms` milliseconds (never negative here); `Ok(0)` if none came.
    fn read_timeout(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, DeviceError>;
}

impl MillisecondHid for HidDevice {
    fn write(&mut self, report: &[u8]) -> Result<usize, DeviceError> {
        HidDevice::write(self, report).map_err(|error| hid_io_error(error, "writing a HID report"))
    }

    fn read_timeout(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, DeviceError> {
        HidDevice::read_timeout(self, buf, timeout_ms)
            .map_err(|error| hid_io_error(error, "reading a HID report"))
    }
}

/// An open HID device as a [`ReportTransport`] (hidapi's device unless a test gives another).
pub struct HidTransport<D = HidDevice> {
    device: D,
}

impl<D> std::fmt::Debug for HidTransport<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HidTransport").finish_non_exhaustive()
    }
}

impl<D: MillisecondHid> HidTransport<D> {
    /// A transport on `device` (a test double with hidapi's millisecond-only reads).
    pub fn on(device: D) -> HidTransport<D> {
        HidTransport { device }
    }

    /// The device underneath.
    pub fn device(&self) -> &D {
        &self.device
    }
}

fn open_error(path: String, error: hidapi::HidError) -> DeviceError {
    let reason = error.to_string();
    let kind = match &error {
        hidapi::HidError::IoError { error } => error.kind(),
        // The hidraw backend reports some failures only as text.
        _ if reason.contains("Permission denied") => std::io::ErrorKind::PermissionDenied,
        _ if reason.contains("not found") || reason.contains("No such") => {
            std::io::ErrorKind::NotFound
        }
        _ => std::io::ErrorKind::Other,
    };
    DeviceError::Open {
        path,
        message: super::open_message(&reason, kind),
    }
}

impl HidTransport<HidDevice> {
    /// Opens the first device with this USB vendor and product id.
    pub fn open_vid_pid(vendor_id: u16, product_id: u16) -> Result<HidTransport, DeviceError> {
        let name = format!("HID {vendor_id:04x}:{product_id:04x}");
        let api = HidApi::new().map_err(|error| open_error(name.clone(), error))?;
        let device = api
            .open(vendor_id, product_id)
            .map_err(|error| open_error(name, error))?;
        Ok(HidTransport { device })
    }

    /// Opens the device with this USB vendor id, product id and serial number.
    pub fn open_serial(
        vendor_id: u16,
        product_id: u16,
        serial: &str,
    ) -> Result<HidTransport, DeviceError> {
        let name = format!("HID {vendor_id:04x}:{product_id:04x} serial {serial}");
        let api = HidApi::new().map_err(|error| open_error(name.clone(), error))?;
        let device = api
            .open_serial(vendor_id, product_id, serial)
            .map_err(|error| open_error(name, error))?;
        Ok(HidTransport { device })
    }

    /// Opens a device by its hidraw path (`/dev/hidraw3`).
    pub fn open_path(path: &str) -> Result<HidTransport, DeviceError> {
        let api = HidApi::new().map_err(|error| open_error(path.to_string(), error))?;
        let c_path = std::ffi::CString::new(path).map_err(|_| DeviceError::Config {
            what: format!("HID path {path:?} contains a NUL byte"),
        })?;
        let device = api
            .open_path(&c_path)
            .map_err(|error| open_error(path.to_string(), error))?;
        Ok(HidTransport { device })
    }
}

fn hid_io_error(error: hidapi::HidError, during: &'static str) -> DeviceError {
    match error {
        hidapi::HidError::IoError { error } => DeviceError::from_io(&error, during),
        // hidapi reports an unplugged device as a generic error on some backends; treat it as gone.
        _ => DeviceError::Disconnected {
            during,
            kind: std::io::ErrorKind::Other,
        },
    }
}

impl<D: MillisecondHid> ReportTransport for HidTransport<D> {
    fn write_report(&mut self, report: &[u8]) -> Result<(), DeviceError> {
        let written = self.device.write(report)?;
        if written == report.len() {
            Ok(())
        } else {
            Err(DeviceError::Io {
                during: "writing a HID report (short write)",
                kind: std::io::ErrorKind::WriteZero,
            })
        }
    }

    /// Waits until `timeout` has passed (module docs): whole milliseconds through the device while at least one
    /// is left, then non-blocking reads [`POLL_STEP`] apart, and a last one at the deadline. A zero timeout
    /// reads once without waiting.
    fn read_report(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        let deadline = Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let whole_ms = i32::try_from(remaining.as_millis()).unwrap_or(i32::MAX);
            let n = self.device.read_timeout(buf, whole_ms)?;
            if n > 0 || remaining.is_zero() {
                return Ok(n);
            }
            if whole_ms == 0 {
                std::thread::sleep(remaining.min(POLL_STEP));
            }
        }
    }
}

#[cfg(test)]
#[path = "hid_tests.rs"]
mod tests;
