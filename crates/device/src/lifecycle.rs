//! The device lifecycle, enforced once for every driver (HAPI's UNINITIALIZED / INITIALIZED / ENABLED;
//! CONTRIBUTING.md item 6):
//! `Closed --open--> Open --enable--> Enabled --disable--> Open --close--> Closed`.
//!
//! Where it sits: between the supervisor (crates/device/src/supervisor.rs) and a driver. Forces are accepted only while
//! enabled; while open the only force that may be written is zero (lockstep devices answer each write with a
//! state, so the host watches the handle before enabling); states can be read while open or enabled. On every
//! stop (disable, close, drop while open or enabled) the wrapper writes an explicit zero force first, because some
//! devices keep their last force (docs/design.md, "Devices"), and close disables the device whether or not the host
//! believed it enabled (the device may know better).

use super::error::{Error, ErrorKind};
use super::{DeviceInfo, DeviceState, HapticDevice};
use glam::DVec3;

/// Where a device is in its lifecycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LifecycleState {
    /// Not connected.
    Closed,
    /// Connected, forces off.
    Open,
    /// Connected, forces on.
    Enabled,
}

/// An error of the lifecycle wrapper: a call in the wrong state, or the driver's own error.
#[derive(Debug, thiserror::Error)]
pub enum LifecycleError<E: Error> {
    /// The operation is not allowed in this state.
    #[error("cannot {operation} a device that is {state:?}")]
    InvalidState {
        /// What was attempted.
        operation: &'static str,
        /// The state the device was in.
        state: LifecycleState,
    },
    /// The driver failed.
    #[error(transparent)]
    Device(E),
}

impl<E: Error> Error for LifecycleError<E> {
    fn kind(&self) -> ErrorKind {
        match self {
            LifecycleError::InvalidState { .. } => ErrorKind::InvalidState,
            LifecycleError::Device(error) => error.kind(),
        }
    }
}

/// A driver wrapped in the lifecycle state machine.
#[derive(Debug)]
pub struct Lifecycle<D: HapticDevice> {
    device: D,
    state: LifecycleState,
}

impl<D: HapticDevice> Lifecycle<D> {
    /// Wraps a driver that is not yet open.
    pub fn new(device: D) -> Self {
        Lifecycle {
            device,
            state: LifecycleState::Closed,
        }
    }

    /// The current state.
    pub fn state(&self) -> LifecycleState {
        self.state
    }

    /// The driver's capabilities.
    pub fn info(&self) -> &DeviceInfo {
        self.device.info()
    }

    /// The wrapped driver (read-only: calling its lifecycle hooks directly would bypass the wrapper).
    pub fn device(&self) -> &D {
        &self.device
    }

    fn check(
        &self,
        operation: &'static str,
        allowed: &[LifecycleState],
    ) -> Result<(), LifecycleError<D::Error>> {
        if allowed.contains(&self.state) {
            Ok(())
        } else {
            Err(LifecycleError::InvalidState {
                operation,
                state: self.state,
            })
        }
    }

    /// Closed → Open.
    pub fn open(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("open", &[LifecycleState::Closed])?;
        self.device.open().map_err(LifecycleError::Device)?;
        self.state = LifecycleState::Open;
        Ok(())
    }

    /// Open → Enabled.
    pub fn enable(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("enable", &[LifecycleState::Open])?;
        self.device.enable().map_err(LifecycleError::Device)?;
        self.state = LifecycleState::Enabled;
        Ok(())
    }

    /// Enabled → Open, after an explicit zero force. The state changes even if the driver fails, so that no more
    /// forces are sent.
    pub fn disable(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("disable", &[LifecycleState::Enabled])?;
        self.state = LifecycleState::Open;
        let zero = self.device.write_force(DVec3::ZERO);
        let disabled = self.device.disable();
        zero.and(disabled).map_err(LifecycleError::Device)
    }

    /// Open or Enabled → Closed, after an explicit zero force and a disable. The state becomes Closed even if
    /// the driver fails.
    pub fn close(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("close", &[LifecycleState::Open, LifecycleState::Enabled])?;
        self.state = LifecycleState::Closed;
        let zero = self.device.write_force(DVec3::ZERO);
        let disabled = self.device.disable();
        let closed = self.device.close();
        zero.and(disabled)
            .and(closed)
            .map_err(LifecycleError::Device)
    }

    /// Sends a force; only while enabled.
    pub fn write_force(&mut self, force_n: DVec3) -> Result<(), LifecycleError<D::Error>> {
        self.check("write a force to", &[LifecycleState::Enabled])?;
        self.device
            .write_force(force_n)
            .map_err(LifecycleError::Device)
    }

    /// Sends a local model instead of a force ([`HapticDevice::write_local_model`]); only while enabled.
    pub fn write_local_model(
        &mut self,
        model: &crate::local_offer::LocalOffer,
        force_limit_n: f64,
        fallback_force_n: DVec3,
    ) -> Result<(), LifecycleError<D::Error>> {
        self.check("write a local model to", &[LifecycleState::Enabled])?;
        self.device
            .write_local_model(model, force_limit_n, fallback_force_n)
            .map_err(LifecycleError::Device)
    }

    /// Sends a zero force; while open or enabled (lockstep devices answer it with a state).
    pub fn write_zero(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check(
            "write a zero force to",
            &[LifecycleState::Open, LifecycleState::Enabled],
        )?;
        self.device
            .write_force(DVec3::ZERO)
            .map_err(LifecycleError::Device)
    }

    /// Passes the host's input-check verdict on the last state read to the driver
    /// ([`HapticDevice::input_checked`]).
    pub fn input_checked(&mut self, accepted: bool) {
        self.device.input_checked(accepted);
    }

    /// The next event the device reported (a fault, a refusal).
    pub fn take_event(&mut self) -> Option<super::DeviceEvent> {
        self.device.take_event()
    }

    /// Clears the device's latched faults (an operator's request); while open.
    pub fn clear_fault(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("clear the faults of", &[LifecycleState::Open])?;
        self.device.clear_fault().map_err(LifecycleError::Device)
    }

    /// Keeps an idle link alive (a heartbeat); while open.
    pub fn keep_alive(&mut self) -> Result<(), LifecycleError<D::Error>> {
        self.check("keep alive", &[LifecycleState::Open])?;
        self.device.keep_alive().map_err(LifecycleError::Device)
    }

    /// The device's stop channel for the stall monitor, if its driver has one.
    pub fn emergency_stop(&self) -> Option<Box<dyn super::EmergencyStop>> {
        self.device.emergency_stop()
    }

    /// Reads the handle; while open or enabled.
    pub fn read_state(&mut self) -> Result<DeviceState, LifecycleError<D::Error>> {
        self.check(
            "read the state of",
            &[LifecycleState::Open, LifecycleState::Enabled],
        )?;
        self.device.read_state().map_err(LifecycleError::Device)
    }

    /// Marks the device closed without talking to it (after a disconnect, when there is nobody to talk to).
    pub fn mark_lost(&mut self) {
        self.state = LifecycleState::Closed;
    }
}

impl<D: HapticDevice> Drop for Lifecycle<D> {
    fn drop(&mut self) {
        if self.state != LifecycleState::Closed {
            // Best effort: a zero force and a clean close; errors have nowhere to go here.
            let _ = self.close();
        }
    }
}
