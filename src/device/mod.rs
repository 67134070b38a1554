//! Haptic devices: the arms whose probe position feeds the servo loop and which render its force.
//!
//! Sits at both ends of the data flow in DESIGN.md section 5: a device reports the probe position to the
//! servo thread and receives the rendered force. The layers, bottom up:
//!
//! - [`transport`]: bytes or reports to and from somewhere (serial port or pseudo-terminal, USB HID, in-memory
//!   pipes and scripted test doubles);
//! - [`drivers`]: one per device family, each on a transport (voxhap's own protocol over serial or HID,
//!   WoodenHaptics 1.5, Haply 2DIY, a replay of a recorded trace); all implement [`HapticDevice`];
//! - [`Lifecycle`]: open → enabled → open → closed, enforced once for every driver;
//! - [`safety`]: the host's safety pipeline, applied to every force before any driver;
//! - [`supervisor`]: lifecycle plus safety plus reconnection, the one object the servo loop talks to;
//! - [`mock`]: the simulated arm behind the real protocol, with fault injection (`voxhap mock-device`);
//! - [`discovery`]: which serial ports and HID devices are present, and which ones voxhap recognises.
//!
//! [`sim`] is the in-process simulated arm used by scenarios, tests and demos.

pub mod discovery;
pub mod drivers;
pub mod error;
pub mod info;
pub mod lifecycle;
pub mod mock;
pub mod safety;
pub mod sim;
pub mod supervisor;
pub mod transport;

pub use error::{DeviceError, Error, ErrorKind};
pub use info::{DeviceInfo, DeviceState};
pub use lifecycle::{Lifecycle, LifecycleError, LifecycleState};

use glam::DVec3;

/// A haptic device driver: what it is, where its handle is, and which force to render.
///
/// Drivers implement the lifecycle hooks; the order (open, enable, forces, disable, close) is enforced by
/// [`Lifecycle`], so a driver may assume it. `write_force` receives a force that the safety pipeline has already
/// made finite and clamped; drivers still refuse a non-finite one.
pub trait HapticDevice {
    /// The driver's error type.
    type Error: Error;

    /// Capabilities. Valid after a successful [`HapticDevice::open`]; drivers that know them up front return them
    /// at any time.
    fn info(&self) -> &DeviceInfo;

    /// Connects: handshake, setup commands. Forces stay zero.
    fn open(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Lets the device apply forces.
    fn enable(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Stops applying forces (the wrapper has already sent an explicit zero force).
    fn disable(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Releases the device.
    fn close(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Sends the force to render now (N, device frame).
    fn write_force(&mut self, force_n: DVec3) -> Result<(), Self::Error>;

    /// Reads the newest state of the handle.
    fn read_state(&mut self) -> Result<DeviceState, Self::Error>;
}
