//! Transports: how bytes reach a device. A driver sits on a transport, so the same driver code runs against a
//! serial port, a pseudo-terminal, a USB HID device, an in-memory pipe to a simulated device, or a scripted test
//! double (CONTRIBUTING.md item 7). The in-memory ones (`memory`) are test doubles: they exist only with the
//! `test-support` feature (off by default; the root package's tests and benches switch it on).
//!
//! [`inverse_service`] is a third kind: the Haply Inverse Service's JSON-over-WebSocket channel on its own I/O
//! thread, handed to the servo thread through lock-free buffers; [`inverse_wire`] holds its JSON messages.
//!
//! Two shapes: [`ByteTransport`] is a byte stream (UART, USB CDC-ACM, pseudo-terminal) whose framing the driver
//! does; [`ReportTransport`] moves whole HID reports. Reads take a timeout and return `Ok(0)` when nothing came,
//! so a timeout is the driver's decision, not the transport's; a hang-up is `DeviceError::Disconnected`.

pub mod ftdi_latency;
pub mod hid;
pub mod inverse_service;
pub mod inverse_wire;
#[cfg(any(test, feature = "test-support"))]
pub mod memory;
pub mod serial;
mod traits;

pub use hid::{HidTransport, MillisecondHid};
#[cfg(any(test, feature = "test-support"))]
pub use memory::{MemoryPipe, ReportTiming, ScriptedReports, ScriptedStream};
pub use serial::SerialTransport;
pub use traits::{open_advice, open_message, ByteTransport, ReportTransport};
