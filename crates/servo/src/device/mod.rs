//! The device end of the servo loop: the one object ([`ServoDevice`]) the servo thread talks to, whatever
//! the device is, and where the rest of the device path lives.
//!
//! Every device runs inside a [`Supervisor`] (lifecycle, safety pipeline, reconnection; see
//! `device::supervisor`), so the safety pipeline is applied to every force of every device, the simulated
//! arm included. [`ServoDevice`] erases the driver type so the servo thread holds one `Box<dyn
//! ServoDevice>`.
//!
//! - [`ServoDevice`] (servo_device.rs): the trait; error.rs: [`OpenError`], [`ConnectError`].
//! - [`spec`]: which device `--device` names ([`DeviceSpec`]).
//! - [`factory`]: building the supervised device for a spec ([`open_device`]).
//! - [`reconnect`]: the reconnecting wrapper whose connector thread reopens a lost device ([`Reconnecting`]).
//! - [`sim`]: the in-process simulated arm as a device ([`SimDevice`]), the default.
//! - [`local`]: the in-process device with the local-model capability ([`LocalDevice`]) that the simulated
//!   arm, `voxhap sim` and `voxhap stability` run.
//! - [`replay`]: plays back the probe positions of a recorded force trace ([`ReplayDevice`], `replay:TRACE`).

mod error;
mod factory;
pub mod local;
mod reconnect;
pub mod replay;
mod servo_device;
mod sim;
mod spec;

pub use error::{ConnectError, OpenError};
pub use factory::{open_device, open_device_with_profile, spec_family, OpenedDevice};
pub use local::{LocalDevice, LocalRateError};
pub use reconnect::Reconnecting;
pub use replay::{parse_replay_spec, ReplayDevice, ReplayOptions, ReplaySpecError};
pub(crate) use servo_device::forward_to_wrapped;
pub use servo_device::ServoDevice;
pub use sim::{HandTargetInput, SimDevice};
pub use spec::{DeviceSpec, DeviceSpecError, DeviceSpecProblem};
