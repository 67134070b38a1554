//! A pseudo-terminal for serial device doubles: the double owns the master end, the driver opens the slave by
//! its path (`/dev/pts/N`) exactly as it opens a USB serial port.

use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};
use std::time::Duration;

/// The device side of a pseudo-terminal.
pub struct PtyDevice {
    master: TTYPort,
    // Held open so the master does not see a hang-up while the driver has not opened the path yet.
    slave: TTYPort,
    path: String,
}

impl PtyDevice {
    /// A fresh pseudo-terminal pair.
    pub fn new() -> PtyDevice {
        let (mut master, slave) = TTYPort::pair().expect("create a pseudo-terminal pair");
        master
            .set_timeout(Duration::from_millis(2))
            .expect("set the master's read timeout");
        let path = slave.name().expect("the slave end has a path");
        PtyDevice {
            master,
            slave,
            path,
        }
    }

    /// The path the driver opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// How long [`PtyDevice::read`] waits for bytes (2 ms unless set).
    pub fn set_read_timeout(&mut self, timeout: Duration) {
        self.master
            .set_timeout(timeout)
            .expect("set the master's read timeout");
    }

    /// Reads what the host wrote (`Ok(0)` when nothing came within the read timeout, 2 ms unless set).
    pub fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self.master.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(e),
        }
    }

    /// Writes bytes on the host's side of the line, as the driver would: they reach [`PtyDevice::read`] after
    /// every byte the driver wrote before this call (one queue, in order), so a double can mark the end of what
    /// it has been sent.
    pub fn write_as_host(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.slave.write_all(bytes)?;
        self.slave.flush()
    }

    /// Sends bytes to the host.
    pub fn write(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.master.write_all(bytes)?;
        self.master.flush()
    }
}
