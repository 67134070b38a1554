//! Device errors: one `Copy`-free but allocation-free-on-the-hot-path enum for every driver and transport, and the
//! embedded-hal style [`Error`] trait whose [`ErrorKind`] lets generic code (the lifecycle wrapper, the supervisor)
//! decide what to do without knowing the driver: a `Disconnected` error closes the device and schedules a reopen,
//! a `Timeout` is counted and tolerated for a while, anything else is reported.
//!
//! Where it sits: transports (crates/device/src/transport) and drivers (crates/device/src/drivers) return [`DeviceError`]; the
//! supervisor (crates/device/src/supervisor.rs) reads `kind()`. Errors raised per tick carry only `&'static str` and
//! numbers, so building one does not allocate; only opening a device (paths, OS messages) allocates.

use std::io;

/// What kind of failure an error is, independent of the driver that raised it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The device went away (unplugged cable, closed pseudo-terminal, hang-up). Reopen when it comes back.
    Disconnected,
    /// The device did not answer in time.
    Timeout,
    /// The device sent something that breaks its protocol, or refused a command.
    Protocol,
    /// An operating-system I/O error other than a disconnect.
    Io,
    /// The device reported a hardware fault and holds zero force.
    Faulted,
    /// An operation was called in the wrong lifecycle state (for example a force before enable).
    InvalidState,
    /// The device or its configuration cannot be used (bad parameters, unsupported, incompatible version).
    Unsupported,
    /// Anything else (embedded-hal's `Other`): reported, never acted on by kind.
    Other,
}

/// The error trait of voxhap devices, in the embedded-hal manner: any driver error can say what kind it is.
pub trait Error: std::error::Error + Send + Sync + 'static {
    /// The kind of failure.
    fn kind(&self) -> ErrorKind;
}

/// Errors of the transports and drivers in this crate.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// The link to the device is gone.
    #[error("device disconnected while {during} ({kind:?})")]
    Disconnected {
        /// What the host was doing.
        during: &'static str,
        /// The OS error kind that showed it.
        kind: io::ErrorKind,
    },
    /// No answer within the allowed time.
    #[error("device did not answer within {waited_us} µs while waiting for {waiting_for}")]
    Timeout {
        /// How long the host waited (µs).
        waited_us: u64,
        /// What the host waited for.
        waiting_for: &'static str,
    },
    /// The device broke its protocol.
    #[error("protocol error: {what}")]
    Protocol {
        /// What was wrong.
        what: &'static str,
    },
    /// The device refused a command (voxhap protocol `Rejected`).
    #[error("device rejected message type 0x{message_type:02x} (reason {reason})")]
    Rejected {
        /// Type byte of the refused message.
        message_type: u8,
        /// Reject reason code (1 no session, 2 version mismatch, 3 faulted, 4 invalid argument).
        reason: u8,
    },
    /// The device never answered a request that was retried (a handshake), so there is nobody there speaking
    /// the protocol: wrong port, no power, other firmware, or a reply delay beyond the deadline.
    #[error("the device did not answer: no {waiting_for} within {} s ({attempts} {sent} sent); check that it is powered, on this port, running firmware that speaks voxhap protocol {}.x at the port's baud rate, and that no other program holds the port", seconds(*waited_us), voxhap_protocol::PROTOCOL_VERSION.major)]
    NoAnswer {
        /// What the host waited for.
        waiting_for: &'static str,
        /// Requests sent.
        attempts: u32,
        /// What the requests were ("Hellos").
        sent: &'static str,
        /// How long the host waited in all (µs).
        waited_us: u64,
    },
    /// The device reported a latched hardware fault.
    #[error("device fault code {code} (active fault bits 0x{active:04x})")]
    Faulted {
        /// Fault code (voxhap protocol numbering).
        code: u8,
        /// All latched fault bits.
        active: u16,
    },
    /// The device speaks another major protocol version.
    #[error("device speaks protocol {device_major}.{device_minor}, this host speaks {host_major}.{host_minor}")]
    Incompatible {
        /// Device major version.
        device_major: u8,
        /// Device minor version.
        device_minor: u8,
        /// Host major version.
        host_major: u8,
        /// Host minor version.
        host_minor: u8,
    },
    /// An OS I/O error that is not a disconnect.
    #[error("I/O error while {during}: {kind:?}")]
    Io {
        /// What the host was doing.
        during: &'static str,
        /// The OS error kind.
        kind: io::ErrorKind,
    },
    /// A value read from the device is unusable (NaN, out of range).
    #[error("invalid data from device: {what}")]
    InvalidData {
        /// What was wrong.
        what: &'static str,
    },
    /// Opening the device failed.
    #[error("cannot open {path}: {message}")]
    Open {
        /// The device path or name.
        path: String,
        /// Why, as the OS or library said.
        message: String,
    },
    /// A configuration value is out of range.
    #[error("invalid device configuration: {what}")]
    Config {
        /// What was wrong.
        what: String,
    },
}

/// Microseconds as seconds with one decimal, for messages.
fn seconds(us: u64) -> String {
    format!("{:.1}", us as f64 * 1e-6)
}

impl DeviceError {
    /// Every driver's last check before a force goes out: a non-finite component is refused (the safety
    /// pipeline zeroes such forces before any driver, so this only fires on a bug upstream).
    pub(crate) fn check_finite_force(components: [f64; 3]) -> Result<(), DeviceError> {
        if components.iter().all(|c| c.is_finite()) {
            Ok(())
        } else {
            Err(DeviceError::InvalidData {
                what: "force is not finite (the safety pipeline should have zeroed it)",
            })
        }
    }

    /// Classifies an OS I/O error: hang-ups and broken pipes are disconnects, the rest are I/O errors.
    pub fn from_io(error: &io::Error, during: &'static str) -> DeviceError {
        let kind = error.kind();
        let disconnected = matches!(
            kind,
            io::ErrorKind::BrokenPipe
                | io::ErrorKind::NotConnected
                | io::ErrorKind::UnexpectedEof
                | io::ErrorKind::ConnectionReset
                | io::ErrorKind::ConnectionAborted
                | io::ErrorKind::NotFound
        ) || error.raw_os_error() == Some(5) // EIO: a pseudo-terminal whose other end closed
            || error.raw_os_error() == Some(19); // ENODEV: a USB device unplugged
        if disconnected {
            DeviceError::Disconnected { during, kind }
        } else {
            DeviceError::Io { during, kind }
        }
    }
}

impl Error for DeviceError {
    fn kind(&self) -> ErrorKind {
        match self {
            DeviceError::Disconnected { .. } => ErrorKind::Disconnected,
            DeviceError::Timeout { .. } | DeviceError::NoAnswer { .. } => ErrorKind::Timeout,
            DeviceError::Protocol { .. } | DeviceError::Rejected { .. } => ErrorKind::Protocol,
            DeviceError::Faulted { .. } => ErrorKind::Faulted,
            DeviceError::Io { .. } | DeviceError::Open { .. } => ErrorKind::Io,
            DeviceError::InvalidData { .. } => ErrorKind::Protocol,
            DeviceError::Incompatible { .. } | DeviceError::Config { .. } => ErrorKind::Unsupported,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hang_ups_are_disconnects_and_other_io_errors_are_not() {
        let hup = io::Error::new(io::ErrorKind::BrokenPipe, "hup");
        assert_eq!(
            DeviceError::from_io(&hup, "reading").kind(),
            ErrorKind::Disconnected
        );
        let eio = io::Error::from_raw_os_error(5);
        assert_eq!(
            DeviceError::from_io(&eio, "reading").kind(),
            ErrorKind::Disconnected
        );
        let denied = io::Error::new(io::ErrorKind::PermissionDenied, "no");
        assert_eq!(
            DeviceError::from_io(&denied, "opening").kind(),
            ErrorKind::Io
        );
    }
}
