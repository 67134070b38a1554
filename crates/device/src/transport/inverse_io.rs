//! The Inverse Service simulation channel's socket once the session is set up: non-blocking, read one message
//! at a time without waiting, waited on with poll(2), written with a bounded wait. The I/O thread that drives
//! it (and the protocol core it feeds) is the driver's: `drivers/haply_inverse_io.rs`. Allocates as it needs
//! (it is not the servo thread).

use super::{Socket, WRITE_TIMEOUT};
use crate::DeviceError;
use std::os::fd::AsRawFd;
use std::time::{Duration, Instant};
use tungstenite::Message;

fn is_would_block(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e) if e.kind() == std::io::ErrorKind::WouldBlock)
}

/// A socket error as the driver reports it: the link is gone.
fn gone(during: &'static str, error: &tungstenite::Error) -> DeviceError {
    let kind = match error {
        tungstenite::Error::Io(e) => e.kind(),
        _ => std::io::ErrorKind::ConnectionReset,
    };
    DeviceError::Disconnected { during, kind }
}

/// The set-up simulation channel (module docs).
#[derive(Debug)]
pub struct ServicePort {
    socket: Socket,
}

impl ServicePort {
    pub(super) fn new(socket: Socket) -> Self {
        ServicePort { socket }
    }

    /// The next text or binary message already received; `Ok(None)` when none is waiting. A close from the
    /// service is a disconnect; pings are answered by tungstenite.
    pub fn try_read(&mut self) -> Result<Option<Message>, DeviceError> {
        loop {
            match self.socket.read() {
                Ok(message @ (Message::Text(_) | Message::Binary(_))) => return Ok(Some(message)),
                Ok(Message::Close(_)) => {
                    return Err(DeviceError::Disconnected {
                        during: "reading the Inverse Service's messages (it closed the connection)",
                        kind: std::io::ErrorKind::ConnectionReset,
                    })
                }
                Ok(_) => {}
                Err(error) if is_would_block(&error) => return Ok(None),
                Err(error) => return Err(gone("reading the Inverse Service's messages", &error)),
            }
        }
    }

    /// Waits until the socket is readable or `timeout` passes (to the microsecond: ppoll, so a wait below a
    /// millisecond is not rounded up to one).
    pub fn wait_readable(&self, timeout: Duration) {
        self.poll(libc::POLLIN, timeout);
    }

    fn poll(&self, events: libc::c_short, timeout: Duration) {
        let mut fd = libc::pollfd {
            fd: self.socket.get_ref().stream.as_raw_fd(),
            events,
            revents: 0,
        };
        let limit = libc::timespec {
            tv_sec: libc::time_t::try_from(timeout.as_secs()).unwrap_or(libc::time_t::MAX),
            tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
        };
        // SAFETY: one valid pollfd and timespec for the duration of the call, no signal mask; the descriptor
        // stays open (we own the socket).
        unsafe {
            libc::ppoll(&mut fd, 1, &limit, std::ptr::null());
        }
    }

    /// Sends one text message, waiting at most [`WRITE_TIMEOUT`] for room in the socket's send buffer.
    pub fn send_text(&mut self, text: String) -> Result<(), DeviceError> {
        match self.socket.send(Message::text(text)) {
            Ok(()) => Ok(()),
            Err(error) if is_would_block(&error) => {
                self.flush_within(Instant::now() + WRITE_TIMEOUT)
            }
            Err(error) => Err(gone("sending to the Inverse Service", &error)),
        }
    }

    /// Starts the WebSocket close and flushes it within [`WRITE_TIMEOUT`] (errors ignored: the link ends).
    pub fn close(&mut self) {
        let _ = self.socket.close(None);
        let _ = self.flush_within(Instant::now() + WRITE_TIMEOUT);
    }

    fn flush_within(&mut self, deadline: Instant) -> Result<(), DeviceError> {
        loop {
            match self.socket.flush() {
                Ok(()) => return Ok(()),
                Err(error) if is_would_block(&error) => {
                    let now = Instant::now();
                    if now >= deadline {
                        // The service reads nothing.
                        return Err(DeviceError::Disconnected {
                            during: "sending to the Inverse Service (it reads nothing)",
                            kind: std::io::ErrorKind::TimedOut,
                        });
                    }
                    self.poll(libc::POLLOUT, deadline - now);
                }
                Err(error) => return Err(gone("sending to the Inverse Service", &error)),
            }
        }
    }
}
