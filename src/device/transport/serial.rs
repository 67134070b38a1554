//! Serial ports and pseudo-terminals through the `serialport` crate (default features off: no libudev needed).
//!
//! Where it sits: under the serial drivers (voxhap protocol, Haply 2DIY). A pseudo-terminal is opened like any
//! port by its path; [`SerialTransport::from_port`] wraps one end of `TTYPort::pair()` for tests and benches.

use super::ByteTransport;
use crate::device::DeviceError;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
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
            .map_err(|error| DeviceError::Open {
                path: path.to_string(),
                message: error.to_string(),
            })?;
        // Pseudo-terminals have no modem lines and refuse these; a real port that refuses still works.
        let _ = port.write_data_terminal_ready(true);
        let _ = port.write_request_to_send(true);
        Ok(Self::from_port(port))
    }

    /// Wraps an open port (for example one end of `TTYPort::pair()`).
    pub fn from_port(port: TTYPort) -> SerialTransport {
        SerialTransport {
            timeout: port.timeout(),
            port,
        }
    }

    /// The port's path, when it has one.
    pub fn name(&self) -> Option<String> {
        self.port.name()
    }
}

impl ByteTransport for SerialTransport {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), DeviceError> {
        self.port
            .write_all(bytes)
            .map_err(|error| DeviceError::from_io(&error, "writing to the serial port"))
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        if timeout != self.timeout {
            // Only stores the value; the wait happens in read's poll.
            self.port
                .set_timeout(timeout)
                .map_err(|_| DeviceError::Io {
                    during: "setting the serial timeout",
                    kind: std::io::ErrorKind::InvalidInput,
                })?;
            self.timeout = timeout;
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

    fn discard_input(&mut self) -> Result<(), DeviceError> {
        self.port
            .clear(serialport::ClearBuffer::Input)
            .map_err(|_| DeviceError::Io {
                during: "discarding the serial input buffer",
                kind: std::io::ErrorKind::Other,
            })
    }

    fn try_clone_writer(&self) -> Option<Box<dyn std::io::Write + Send>> {
        let port = self.port.try_clone_native().ok()?;
        Some(Box::new(port))
    }
}
