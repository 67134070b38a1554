//! The protocol's messages: what each carries, its type byte, and its little-endian payload layout.
//!
//! Where it sits: the serial codec ([`crate::serial`]) and the HID codec ([`crate::hid`]) frame the same payloads;
//! [`HostToDevice`] flows from voxhap to the arm, [`DeviceToHost`] back. Every payload has a fixed size per type, and
//! SPEC.md tables every byte. Decoding validates values as well as sizes (no NaN or infinity in any float, labels
//! printable, ranges documented per field), and encoding runs the same checks, so an encoder never emits a message
//! its decoder would refuse.

use crate::cursor::{check_length, finite, in_range, Reader, Writer};
use crate::error::PayloadError;
use crate::fields::{
    FaultCode, FaultFlags, ForceFlags, Label, RateSet, RejectReason, StatusFlags, Version,
    LABEL_LEN,
};
use crate::local::{LocalModel, LocalState};

pub use crate::wire::MAX_PAYLOAD_LEN;

/// The type byte of every message. Host-to-device types are 0x01..=0x7F, device-to-host types 0x81..=0xFF.
pub mod message_type {
    /// [`crate::HostToDevice::Hello`]
    pub const HELLO: u8 = 0x01;
    /// [`crate::HostToDevice::Enable`]
    pub const ENABLE: u8 = 0x02;
    /// [`crate::HostToDevice::Disable`]
    pub const DISABLE: u8 = 0x03;
    /// [`crate::HostToDevice::SetForce`]
    pub const SET_FORCE: u8 = 0x04;
    /// [`crate::HostToDevice::Heartbeat`]
    pub const HEARTBEAT: u8 = 0x05;
    /// [`crate::HostToDevice::ClearFault`]
    pub const CLEAR_FAULT: u8 = 0x06;
    /// [`crate::HostToDevice::SetStateRate`]
    pub const SET_STATE_RATE: u8 = 0x07;
    /// [`crate::HostToDevice::LocalModel`] (the local-model capability, SPEC section 10)
    pub const LOCAL_MODEL: u8 = crate::local::LOCAL_MODEL_TYPE;
    /// [`crate::DeviceToHost::DeviceInfo`]
    pub const DEVICE_INFO: u8 = 0x81;
    /// [`crate::DeviceToHost::State`]
    pub const STATE: u8 = 0x82;
    /// [`crate::DeviceToHost::Heartbeat`]
    pub const HEARTBEAT_REPLY: u8 = 0x83;
    /// [`crate::DeviceToHost::Fault`]
    pub const FAULT: u8 = 0x84;
    /// [`crate::DeviceToHost::Rejected`]
    pub const REJECTED: u8 = 0x85;
    /// [`crate::DeviceToHost::LocalState`] (the local-model capability, SPEC section 10)
    pub const LOCAL_STATE: u8 = crate::local::LOCAL_STATE_TYPE;
}
use message_type as ty;

/// One direction's message set: how to turn it into a type byte and a payload and back.
pub trait Message: Sized + Copy + core::fmt::Debug + PartialEq {
    /// Byte 0 of a HID report in this direction.
    const HID_REPORT_ID: u8;

    /// The type byte.
    fn message_type(&self) -> u8;

    /// Payload size of a type byte, or `None` if this direction has no such type.
    fn payload_len(message_type: u8) -> Option<usize>;

    /// Checks every field (finite floats, ranges) as the decoder does.
    fn validate(&self) -> Result<(), PayloadError>;

    /// Writes the payload into `out` and returns its length. Does not validate.
    fn write_payload(&self, out: &mut [u8; MAX_PAYLOAD_LEN]) -> usize;

    /// Parses and validates a payload of exactly [`Self::payload_len`] bytes.
    fn read_payload(message_type: u8, payload: &[u8]) -> Result<Self, PayloadError>;
}

// ---------------------------------------------------------------- host to device

/// Opens a session. The device answers with [`DeviceInfo`] (always) and opens the session if the majors agree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hello {
    /// The host's protocol version.
    pub version: Version,
}

/// Lets the device apply forces, with the watchdog armed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Enable {
    /// Longest gap between set-force messages before the device drops to zero force, in microseconds.
    /// 0 asks for the default ([`crate::DEFAULT_WATCHDOG_TIMEOUT_US`], 50 ms); otherwise 1_000..=1_000_000.
    pub watchdog_timeout_us: u32,
}

/// The force the device should render now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetForce {
    /// Host counter, +1 per set-force (wrapping). The device echoes the last one it received in [`State`].
    pub sequence: u32,
    /// Force on the handle in the device frame, newtons. Always finite (checked both ways).
    pub force_n: [f32; 3],
    /// Options; see [`ForceFlags`].
    pub flags: ForceFlags,
}

/// A liveness probe. The device answers with a [`HeartbeatReply`] carrying the same counter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heartbeat {
    /// Any value; echoed back (lets the host match replies and measure the round trip).
    pub counter: u32,
}

/// Chooses how the device sends state frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetStateRate {
    /// 0: lockstep, one state frame per set-force (the default after hello). Otherwise a rate in the device's
    /// [`DeviceInfo::supported_rates`], and the device streams state frames at that rate.
    pub state_rate_hz: u16,
}

/// Messages from the host (voxhap) to the device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HostToDevice {
    /// Type 0x01, 2-byte payload.
    Hello(Hello),
    /// Type 0x02, 4-byte payload.
    Enable(Enable),
    /// Type 0x03, no payload: zero force, stop applying forces.
    Disable,
    /// Type 0x04, 18-byte payload.
    SetForce(SetForce),
    /// Type 0x05, 4-byte payload.
    Heartbeat(Heartbeat),
    /// Type 0x06, no payload: leave the faulted state (to idle).
    ClearFault,
    /// Type 0x07, 2-byte payload.
    SetStateRate(SetStateRate),
    /// Type 0x08, 62-byte payload: one tick's local model, for a device with the capability.
    LocalModel(LocalModel),
}

// ---------------------------------------------------------------- device to host

/// What the device is; sent in answer to every hello.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceInfo {
    /// The device's protocol version.
    pub version: Version,
    /// Model name.
    pub model: Label,
    /// Serial number.
    pub serial_number: Label,
    /// Sensed degrees of freedom (3 for a position-only arm), 0..=6.
    pub position_dof: u8,
    /// Actuated degrees of freedom (3 for a force-only arm), 0..=6.
    pub force_dof: u8,
    /// Number of buttons reported in [`State::buttons`], 0..=16.
    pub button_count: u8,
    /// State rates the device can stream at (it always supports lockstep).
    pub supported_rates: RateSet,
    /// Lower corner of the reachable box in the device frame, metres. Each component <= the upper corner's.
    pub workspace_min_m: [f32; 3],
    /// Upper corner of the reachable box in the device frame, metres.
    pub workspace_max_m: [f32; 3],
    /// Largest force the device renders (it clamps above this), newtons, >= 0.
    pub max_force_n: f32,
    /// Largest virtual-coupling stiffness the device renders stably at 1 kHz, N/m, >= 0.
    pub max_stiffness_n_per_m: f32,
}

/// One sample of the device: where the handle is and what the device is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    /// Device counter, +1 per state frame (wrapping); gaps show lost frames.
    pub sequence: u32,
    /// Device clock when the position was sampled, microseconds since the device started.
    pub device_time_us: u64,
    /// Handle position in the device frame, metres.
    pub position_m: [f32; 3],
    /// Handle velocity in the device frame, metres per second.
    pub velocity_m_per_s: [f32; 3],
    /// Sequence of the last set-force the device received (0 before the first).
    pub last_force_sequence: u32,
    /// Button `n` pressed = bit `n`.
    pub buttons: u16,
    /// Device status.
    pub status: StatusFlags,
    /// Latched faults.
    pub faults: FaultFlags,
}

/// Answer to a [`Heartbeat`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeartbeatReply {
    /// The heartbeat's counter.
    pub counter: u32,
    /// Device clock when answering, microseconds.
    pub device_time_us: u64,
    /// Device status.
    pub status: StatusFlags,
}

/// The device dropped to zero force; sent once per event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    /// What happened, 0..=15.
    pub code: FaultCode,
    /// All latched faults after this event.
    pub active_faults: FaultFlags,
    /// Device clock at the event, microseconds.
    pub device_time_us: u64,
}

/// The device refused a host message and did nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rejected {
    /// Type byte of the refused message.
    pub message_type: u8,
    /// Why.
    pub reason: RejectReason,
}

/// Messages from the device to the host.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeviceToHost {
    /// Type 0x81, 62-byte payload.
    DeviceInfo(DeviceInfo),
    /// Type 0x82, 46-byte payload.
    State(State),
    /// Type 0x83, 14-byte payload.
    Heartbeat(HeartbeatReply),
    /// Type 0x84, 11-byte payload.
    Fault(Fault),
    /// Type 0x85, 2-byte payload.
    Rejected(Rejected),
    /// Type 0x86, 52-byte payload: the device's local loop, after a State (local-model capability).
    LocalState(LocalState),
}

// ---------------------------------------------------------------- host to device codec

impl Message for HostToDevice {
    const HID_REPORT_ID: u8 = crate::wire::HOST_TO_DEVICE_REPORT_ID;

    fn message_type(&self) -> u8 {
        match self {
            HostToDevice::Hello(_) => ty::HELLO,
            HostToDevice::Enable(_) => ty::ENABLE,
            HostToDevice::Disable => ty::DISABLE,
            HostToDevice::SetForce(_) => ty::SET_FORCE,
            HostToDevice::Heartbeat(_) => ty::HEARTBEAT,
            HostToDevice::ClearFault => ty::CLEAR_FAULT,
            HostToDevice::SetStateRate(_) => ty::SET_STATE_RATE,
            HostToDevice::LocalModel(_) => ty::LOCAL_MODEL,
        }
    }

    fn payload_len(message_type: u8) -> Option<usize> {
        Some(match message_type {
            ty::HELLO => 2,
            ty::ENABLE => 4,
            ty::DISABLE => 0,
            ty::SET_FORCE => 18,
            ty::HEARTBEAT => 4,
            ty::CLEAR_FAULT => 0,
            ty::SET_STATE_RATE => 2,
            ty::LOCAL_MODEL => crate::local::LOCAL_MODEL_LEN,
            _ => return None,
        })
    }

    fn validate(&self) -> Result<(), PayloadError> {
        match self {
            HostToDevice::SetForce(m) => finite(ty::SET_FORCE, "force_n", &m.force_n),
            HostToDevice::LocalModel(m) => m.validate(),
            _ => Ok(()),
        }
    }

    fn write_payload(&self, out: &mut [u8; MAX_PAYLOAD_LEN]) -> usize {
        let mut w = Writer::new(out);
        match self {
            HostToDevice::Hello(m) => {
                w.u8(m.version.major);
                w.u8(m.version.minor);
            }
            HostToDevice::Enable(m) => w.u32(m.watchdog_timeout_us),
            HostToDevice::Disable | HostToDevice::ClearFault => {}
            HostToDevice::SetForce(m) => {
                w.u32(m.sequence);
                w.vec3(m.force_n);
                w.u16(m.flags.0);
            }
            HostToDevice::Heartbeat(m) => w.u32(m.counter),
            HostToDevice::SetStateRate(m) => w.u16(m.state_rate_hz),
            HostToDevice::LocalModel(m) => m.write(&mut w),
        }
        w.pos
    }

    fn read_payload(message_type: u8, payload: &[u8]) -> Result<Self, PayloadError> {
        check_length(message_type, Self::payload_len(message_type), payload.len())?;
        let mut r = Reader::new(payload);
        let message = match message_type {
            ty::HELLO => HostToDevice::Hello(Hello {
                version: Version {
                    major: r.u8(),
                    minor: r.u8(),
                },
            }),
            ty::ENABLE => HostToDevice::Enable(Enable {
                watchdog_timeout_us: r.u32(),
            }),
            ty::DISABLE => HostToDevice::Disable,
            ty::SET_FORCE => HostToDevice::SetForce(SetForce {
                sequence: r.u32(),
                force_n: r.vec3(),
                flags: ForceFlags(r.u16()),
            }),
            ty::HEARTBEAT => HostToDevice::Heartbeat(Heartbeat { counter: r.u32() }),
            ty::CLEAR_FAULT => HostToDevice::ClearFault,
            ty::SET_STATE_RATE => HostToDevice::SetStateRate(SetStateRate {
                state_rate_hz: r.u16(),
            }),
            ty::LOCAL_MODEL => HostToDevice::LocalModel(LocalModel::read(&mut r)?),
            _ => return Err(PayloadError::UnknownType(message_type)),
        };
        message.validate()?;
        Ok(message)
    }
}

// ---------------------------------------------------------------- device to host codec

impl DeviceInfo {
    fn validate(&self) -> Result<(), PayloadError> {
        let t = ty::DEVICE_INFO;
        in_range(t, "position_dof", self.position_dof <= 6)?;
        in_range(t, "force_dof", self.force_dof <= 6)?;
        in_range(t, "button_count", self.button_count <= 16)?;
        finite(t, "workspace_min_m", &self.workspace_min_m)?;
        finite(t, "workspace_max_m", &self.workspace_max_m)?;
        let ordered = self
            .workspace_min_m
            .iter()
            .zip(&self.workspace_max_m)
            .all(|(lo, hi)| lo <= hi);
        in_range(t, "workspace_max_m", ordered)?;
        finite(t, "max_force_n", &[self.max_force_n])?;
        in_range(t, "max_force_n", self.max_force_n >= 0.0)?;
        finite(t, "max_stiffness_n_per_m", &[self.max_stiffness_n_per_m])?;
        in_range(
            t,
            "max_stiffness_n_per_m",
            self.max_stiffness_n_per_m >= 0.0,
        )
    }
}

impl Message for DeviceToHost {
    const HID_REPORT_ID: u8 = crate::wire::DEVICE_TO_HOST_REPORT_ID;

    fn message_type(&self) -> u8 {
        match self {
            DeviceToHost::DeviceInfo(_) => ty::DEVICE_INFO,
            DeviceToHost::State(_) => ty::STATE,
            DeviceToHost::Heartbeat(_) => ty::HEARTBEAT_REPLY,
            DeviceToHost::Fault(_) => ty::FAULT,
            DeviceToHost::Rejected(_) => ty::REJECTED,
            DeviceToHost::LocalState(_) => ty::LOCAL_STATE,
        }
    }

    fn payload_len(message_type: u8) -> Option<usize> {
        Some(match message_type {
            ty::DEVICE_INFO => 62,
            ty::STATE => 46,
            ty::HEARTBEAT_REPLY => 14,
            ty::FAULT => 11,
            ty::REJECTED => 2,
            ty::LOCAL_STATE => crate::local::LOCAL_STATE_LEN,
            _ => return None,
        })
    }

    fn validate(&self) -> Result<(), PayloadError> {
        match self {
            DeviceToHost::DeviceInfo(m) => m.validate(),
            DeviceToHost::State(m) => {
                finite(ty::STATE, "position_m", &m.position_m)?;
                finite(ty::STATE, "velocity_m_per_s", &m.velocity_m_per_s)
            }
            DeviceToHost::Fault(m) => in_range(ty::FAULT, "code", m.code.0 <= FaultCode::MAX),
            DeviceToHost::LocalState(m) => m.validate(),
            DeviceToHost::Heartbeat(_) | DeviceToHost::Rejected(_) => Ok(()),
        }
    }

    fn write_payload(&self, out: &mut [u8; MAX_PAYLOAD_LEN]) -> usize {
        let mut w = Writer::new(out);
        match self {
            DeviceToHost::DeviceInfo(m) => {
                w.u8(m.version.major);
                w.u8(m.version.minor);
                w.bytes(m.model.to_bytes());
                w.bytes(m.serial_number.to_bytes());
                w.u8(m.position_dof);
                w.u8(m.force_dof);
                w.u8(m.button_count);
                w.u8(m.supported_rates.0);
                w.vec3(m.workspace_min_m);
                w.vec3(m.workspace_max_m);
                w.f32(m.max_force_n);
                w.f32(m.max_stiffness_n_per_m);
            }
            DeviceToHost::State(m) => {
                w.u32(m.sequence);
                w.u64(m.device_time_us);
                w.vec3(m.position_m);
                w.vec3(m.velocity_m_per_s);
                w.u32(m.last_force_sequence);
                w.u16(m.buttons);
                w.u16(m.status.0);
                w.u16(m.faults.0);
            }
            DeviceToHost::Heartbeat(m) => {
                w.u32(m.counter);
                w.u64(m.device_time_us);
                w.u16(m.status.0);
            }
            DeviceToHost::Fault(m) => {
                w.u8(m.code.0);
                w.u16(m.active_faults.0);
                w.u64(m.device_time_us);
            }
            DeviceToHost::Rejected(m) => {
                w.u8(m.message_type);
                w.u8(m.reason.0);
            }
            DeviceToHost::LocalState(m) => m.write(&mut w),
        }
        w.pos
    }

    fn read_payload(message_type: u8, payload: &[u8]) -> Result<Self, PayloadError> {
        check_length(message_type, Self::payload_len(message_type), payload.len())?;
        let mut r = Reader::new(payload);
        let message = match message_type {
            ty::DEVICE_INFO => {
                let version = Version {
                    major: r.u8(),
                    minor: r.u8(),
                };
                let label = |bytes: [u8; LABEL_LEN], field| {
                    Label::from_bytes(bytes).ok_or(PayloadError::InvalidValue {
                        message_type,
                        field,
                    })
                };
                let model = label(r.bytes(), "model")?;
                let serial_number = label(r.bytes(), "serial_number")?;
                DeviceToHost::DeviceInfo(DeviceInfo {
                    version,
                    model,
                    serial_number,
                    position_dof: r.u8(),
                    force_dof: r.u8(),
                    button_count: r.u8(),
                    supported_rates: RateSet(r.u8()),
                    workspace_min_m: r.vec3(),
                    workspace_max_m: r.vec3(),
                    max_force_n: r.f32(),
                    max_stiffness_n_per_m: r.f32(),
                })
            }
            ty::STATE => DeviceToHost::State(State {
                sequence: r.u32(),
                device_time_us: r.u64(),
                position_m: r.vec3(),
                velocity_m_per_s: r.vec3(),
                last_force_sequence: r.u32(),
                buttons: r.u16(),
                status: StatusFlags(r.u16()),
                faults: FaultFlags(r.u16()),
            }),
            ty::HEARTBEAT_REPLY => DeviceToHost::Heartbeat(HeartbeatReply {
                counter: r.u32(),
                device_time_us: r.u64(),
                status: StatusFlags(r.u16()),
            }),
            ty::FAULT => DeviceToHost::Fault(Fault {
                code: FaultCode(r.u8()),
                active_faults: FaultFlags(r.u16()),
                device_time_us: r.u64(),
            }),
            ty::REJECTED => DeviceToHost::Rejected(Rejected {
                message_type: r.u8(),
                reason: RejectReason(r.u8()),
            }),
            ty::LOCAL_STATE => DeviceToHost::LocalState(LocalState::read(&mut r)),
            _ => return Err(PayloadError::UnknownType(message_type)),
        };
        message.validate()?;
        Ok(message)
    }
}
