//! Serial ports and pseudo-terminals through the `serialport` crate (default features off: no libudev needed).
//!
//! Where it sits: under the serial drivers (voxhap protocol, Haply 2DIY). A pseudo-terminal is opened like any
//! port by its path; [`SerialTransport::from_port`] wraps one end of `TTYPort::pair()` for tests and benches.

use super::ByteTransport;
use crate::DeviceError;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::os::unix::io::AsRawFd;
use std::time::Duration;

/// A serial port as a [`ByteTransport`].
#[derive(Debug)]
pub struct SerialTransport {
    port: TTYPort,
    timeout: Duration,
}

impl SerialTransport {
    /// Opens `path` at `baud_rate`, 8N1, no flow control, with DTR and RTS asserted (protocol/SPEC.md section
    /// 4: many USB CDC-ACM firmwares treat DTR as "host present"). USB CDC-ACM devices and pseudo-terminals
    /// ignore the rate.
    pub fn open(path: &str, baud_rate: u32) -> Result<SerialTransport, DeviceError> {
        let mut port = serialport::new(path, baud_rate)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(Duration::from_millis(10))
            .open_native()
            .map_err(|error| open_error(path, &error))?;
        // Pseudo-terminals have no modem lines and refuse these; a real port that refuses still works.
        let _ = port.write_data_terminal_ready(true);
        let _ = port.write_request_to_send(true);
        Ok(Self::from_port(port))
    }

    /// Sets the DTR and RTS modem lines (the FTDI-based devices use them as signals; USB CDC-ACM ignores them).
    pub fn set_modem_lines(&mut self, dtr: bool, rts: bool) -> Result<(), DeviceError> {
        let failed = |_| DeviceError::Io {
            during: "setting the DTR/RTS modem lines",
            kind: std::io::ErrorKind::Other,
        };
        self.port.write_data_terminal_ready(dtr).map_err(failed)?;
        self.port.write_request_to_send(rts).map_err(failed)
    }

    /// Changes the baud rate (any rate: Linux's termios2 passes custom rates to drivers such as ftdi_sio).
    pub fn set_baud_rate(&mut self, baud_rate: u32) -> Result<(), DeviceError> {
        self.port
            .set_baud_rate(baud_rate)
            .map_err(|_| DeviceError::Io {
                during: "setting the baud rate",
                kind: std::io::ErrorKind::InvalidInput,
            })
    }

    /// Wraps an open port (for example one end of `TTYPort::pair()`).
    pub fn from_port(port: TTYPort) -> SerialTransport {
        SerialTransport {
            timeout: port.timeout(),
            port,
        }
    }

    /// Throws away both kernel queues (bytes not yet sent and bytes received), then drains what arrives
    /// meanwhile.
    pub fn purge_both(&mut self) -> Result<(), DeviceError> {
        self.clear(serialport::ClearBuffer::All, "purging the serial queues")?;
        self.discard_input()
    }

    /// Throws away the kernel's `queues`; `during` names the step in the error.
    fn clear(
        &mut self,
        queues: serialport::ClearBuffer,
        during: &'static str,
    ) -> Result<(), DeviceError> {
        self.port.clear(queues).map_err(|_| DeviceError::Io {
            during,
            kind: std::io::ErrorKind::Other,
        })
    }

    /// The port's path, when it has one.
    pub fn name(&self) -> Option<String> {
        self.port.name()
    }
}

/// The open error for `path`: the OS reason and the next step (permissions, a missing device, a busy port).
pub fn open_error(path: &str, error: &serialport::Error) -> DeviceError {
    let kind = match error.kind() {
        serialport::ErrorKind::Io(kind) => kind,
        // serialport reports EBUSY (another process holds the port exclusively) as NoDevice.
        serialport::ErrorKind::NoDevice => std::io::ErrorKind::ResourceBusy,
        _ => std::io::ErrorKind::Other,
    };
    // serialport's description is the OS's text ("Permission denied", "No such file or directory").
    DeviceError::Open {
        path: path.to_string(),
        message: super::open_message(&error.description, kind),
    }
}

impl ByteTransport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        self.port
            .write_all(bytes)
            .map_err(|error| DeviceError::from_io(&error, "writing to the serial port"))
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        // Wait here, with ppoll and nanosecond resolution, rather than in serialport's read: on a timeout that
        // read builds an `io::Error` with a message (a heap allocation), and the servo thread reads with
        // short timeouts every tick. serialport's own wait then finds the bytes already there.
        match wait_readable(self.port.as_raw_fd(), timeout) {
            Readiness::Timeout => return Ok(0),
            Readiness::HungUp => {
                return Err(DeviceError::Disconnected {
                    during: "reading from the serial port",
                    kind: std::io::ErrorKind::BrokenPipe,
                })
            }
            Readiness::Readable => {}
        }
        let wait = timeout.max(Duration::from_millis(1));
        if wait != self.timeout {
            // Only stores the value; the wait happens in read's poll.
            self.port.set_timeout(wait).map_err(|_| DeviceError::Io {
                during: "setting the serial timeout",
                kind: std::io::ErrorKind::InvalidInput,
            })?;
            self.timeout = wait;
        }
        match self.port.read(buf) {
            Ok(0) => Err(DeviceError::Disconnected {
                during: "reading from the serial port",
                kind: std::io::ErrorKind::UnexpectedEof,
            }),
            Ok(n) => Ok(n),
            Err(error) if error.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(error) if error.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(error) => Err(DeviceError::from_io(&error, "reading from the serial port")),
        }
    }

    /// Clears the kernel's input queue, then drains what arrives meanwhile.
    fn discard_input(&mut self) -> Result<(), DeviceError> {
        self.clear(
            serialport::ClearBuffer::Input,
            "discarding the serial input",
        )?;
        let mut scratch = [0u8; 256];
        for _ in 0..256 {
            if self.read(&mut scratch, Duration::ZERO)? == 0 {
                break;
            }
        }
        Ok(())
    }

    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        let port = self.port.try_clone_native().ok()?;
        Some(Box::new(port))
    }
}

enum Readiness {
    Readable,
    Timeout,
    HungUp,
}

/// Waits at most `timeout` for `fd` to have bytes to read (or to hang up), without allocating.
fn wait_readable(fd: std::os::unix::io::RawFd, timeout: Duration) -> Readiness {
    let mut poll = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let limit = libc::timespec {
        tv_sec: libc::time_t::try_from(timeout.as_secs()).unwrap_or(libc::time_t::MAX),
        tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
    };
    // SAFETY: `poll` and `limit` are valid for the call; one descriptor is passed, and no signal mask.
    let ready = unsafe { libc::ppoll(&mut poll, 1, &limit, std::ptr::null()) };
    if ready <= 0 {
        // 0: nothing in time; -1: EINTR and the like, treated as nothing yet (the caller asks again next tick).
        return Readiness::Timeout;
    }
    if poll.revents & libc::POLLIN != 0 {
        Readiness::Readable
    } else if poll.revents & (libc::POLLHUP | libc::POLLERR | libc::POLLNVAL) != 0 {
        Readiness::HungUp
    } else {
        Readiness::Timeout
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_errors_keep_the_os_reason_and_name_the_next_step() {
        let denied = serialport::Error::new(
            serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied),
            "Permission denied",
        );
        let message = open_error("/dev/ttyACM0", &denied).to_string();
        assert_eq!(
            message,
            "cannot open /dev/ttyACM0: Permission denied: add your user to the dialout group (then log out and \
             in), or install contrib/udev/70-voxhap.rules (see docs/devices/README.md)"
        );
        let missing = serialport::Error::new(
            serialport::ErrorKind::Io(std::io::ErrorKind::NotFound),
            "No such file or directory",
        );
        let message = open_error("/dev/ttyACM0", &missing).to_string();
        assert!(message.ends_with(
            "No such file or directory: is it plugged in and switched on? `voxhap devices` lists what is connected"
        ));
        let busy =
            serialport::Error::new(serialport::ErrorKind::NoDevice, "Device or resource busy");
        assert!(open_error("/dev/ttyUSB0", &busy)
            .to_string()
            .contains("another program has the device open"));
    }
}
