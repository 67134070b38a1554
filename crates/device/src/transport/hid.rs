//! USB HID devices through `hidapi` (Linux hidraw backend with the pure-Rust `basic-udev`, no system libraries).
//!
//! Where it sits: under the HID drivers (voxhap protocol over HID, WoodenHaptics 1.5). Opening needs read/write
//! access to `/dev/hidraw*` (contrib/udev/70-voxhap.rules; see docs/devices/README.md).

use super::ReportTransport;
use crate::DeviceError;
use hidapi::{HidApi, HidDevice};
use std::time::Duration;

/// An open HID device as a [`ReportTransport`].
pub struct HidTransport {
    device: HidDevice,
}

impl std::fmt::Debug for HidTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HidTransport").finish_non_exhaustive()
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

impl HidTransport {
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

impl ReportTransport for HidTransport {
    fn write_report(&mut self, report: &[u8]) -> Result<(), DeviceError> {
        let written = self
            .device
            .write(report)
            .map_err(|error| hid_io_error(error, "writing a HID report"))?;
        if written == report.len() {
            Ok(())
        } else {
            Err(DeviceError::Io {
                during: "writing a HID report (short write)",
                kind: std::io::ErrorKind::WriteZero,
            })
        }
    }

    fn read_report(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        let timeout_ms = i32::try_from(timeout.as_millis()).unwrap_or(i32::MAX);
        self.device
            .read_timeout(buf, timeout_ms)
            .map_err(|error| hid_io_error(error, "reading a HID report"))
    }
}
