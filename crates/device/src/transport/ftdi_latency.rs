//! The FTDI latency timer of a port Linux's `ftdi_sio` driver exposes: how long the chip holds a short packet
//! before sending it to the host (ms). `ftdi_sio` shows it as the sysfs attribute
//! `/sys/bus/usb-serial/devices/ttyUSBn/latency_timer` (read by anyone, written by root or a udev rule such as
//! contrib/udev/70-voxhap.rules). The Falcon's 16-byte frames are short packets, so at the chip's default of
//! 16 ms every frame reaches the host up to 16 ms late; libnifalcon sets 16 ms while loading firmware and 1 ms
//! after (libnifalcon src/comm/FalconCommLibUSB.cpp:407-413 and :560-564, include/falcon/core/FalconComm.h:48
//! and :72). A port without the attribute (a pseudo-terminal, a USB CDC-ACM device) has no such timer.

use crate::DeviceError;
use std::path::{Path, PathBuf};

/// The latency timer the Falcon needs in normal mode (ms).
pub const NORMAL_MS: u8 = 1;
/// The latency timer libnifalcon uses while loading firmware (ms).
pub const FIRMWARE_LOAD_MS: u8 = 16;

/// The `latency_timer` attribute of the tty at `tty_path` (symbolic links such as /dev/serial/by-id/... are
/// followed), whether or not it exists.
pub fn attribute_for(tty_path: &str) -> Option<PathBuf> {
    let resolved = std::fs::canonicalize(tty_path).unwrap_or_else(|_| PathBuf::from(tty_path));
    let name = resolved.file_name()?;
    Some(
        Path::new("/sys/bus/usb-serial/devices")
            .join(name)
            .join("latency_timer"),
    )
}

/// The timer's value (ms), or `None` when the attribute does not exist (no FTDI chip behind the port).
pub fn read_ms(attribute: &Path) -> Result<Option<u32>, DeviceError> {
    let text = match std::fs::read_to_string(attribute) {
        Ok(text) => text,
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(error) => {
            return Err(DeviceError::Open {
                path: attribute.display().to_string(),
                message: format!("cannot read the FTDI latency timer: {error}"),
            })
        }
    };
    text.trim()
        .parse()
        .map(Some)
        .map_err(|_| DeviceError::Open {
            path: attribute.display().to_string(),
            message: format!(
                "the FTDI latency timer reads {:?}, not a number of milliseconds",
                text.trim()
            ),
        })
}

/// Sets the timer to `ms`. Returns false when it could not (no attribute, or no permission: then
/// [`check_normal`] says what to do); other failures are errors.
pub fn try_set_ms(attribute: &Path, ms: u8) -> Result<bool, DeviceError> {
    match std::fs::write(attribute, format!("{ms}\n")) {
        Ok(()) => Ok(true),
        Err(error)
            if matches!(
                error.kind(),
                std::io::ErrorKind::NotFound | std::io::ErrorKind::PermissionDenied
            ) =>
        {
            Ok(false)
        }
        Err(error) => Err(DeviceError::Open {
            path: attribute.display().to_string(),
            message: format!("cannot set the FTDI latency timer to {ms} ms: {error}"),
        }),
    }
}

/// Checks that the timer is at most [`NORMAL_MS`]: otherwise an error naming the value, the attribute and
/// the fix. A port without the attribute passes (it has no such timer).
pub fn check_normal(attribute: &Path) -> Result<(), DeviceError> {
    match read_ms(attribute)? {
        Some(ms) if ms > u32::from(NORMAL_MS) => Err(DeviceError::Open {
            path: attribute.display().to_string(),
            message: format!(
                "the FTDI latency timer is {ms} ms; the Falcon needs {NORMAL_MS} ms, or each frame reaches the host \
                 up to {ms} ms late and every reply wait times out: install contrib/udev/70-voxhap.rules (it sets \
                 1 ms when the Falcon is plugged in), or run `echo 1 | sudo tee {}`",
                attribute.display()
            ),
        }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On real files: a missing attribute passes, 1 ms passes, ftdi_sio's default of 16 ms fails with a message
    /// naming the value, the file and the fix; setting writes the number as ftdi_sio's store function parses it.
    #[test]
    fn the_check_reads_the_attribute_and_names_the_fix() {
        let dir = tempfile::tempdir().unwrap();
        let attribute = dir.path().join("latency_timer");
        assert_eq!(read_ms(&attribute).unwrap(), None);
        check_normal(&attribute).unwrap();
        assert!(!try_set_ms(&dir.path().join("absent/latency_timer"), 1).unwrap());
        std::fs::write(&attribute, "16\n").unwrap();
        let message = check_normal(&attribute).unwrap_err().to_string();
        assert!(message.contains("latency timer is 16 ms"), "{message}");
        assert!(message.contains("70-voxhap.rules"), "{message}");
        assert!(
            message.contains(&attribute.display().to_string()),
            "{message}"
        );
        assert!(try_set_ms(&attribute, NORMAL_MS).unwrap());
        assert_eq!(std::fs::read_to_string(&attribute).unwrap(), "1\n");
        check_normal(&attribute).unwrap();
        std::fs::write(&attribute, "fast").unwrap();
        assert!(check_normal(&attribute)
            .unwrap_err()
            .to_string()
            .contains("\"fast\""));
    }

    #[test]
    fn the_attribute_is_found_by_the_tty_name() {
        assert_eq!(
            attribute_for("/dev/ttyUSB7").unwrap(),
            Path::new("/sys/bus/usb-serial/devices/ttyUSB7/latency_timer")
        );
    }
}
