//! voxhap's device wire protocol: `no_std`, no allocation, sans-IO. Firmware and host share this one codec.
//!
//! Data flow: the host (voxhap's servo loop, through its protocol driver) sends [`HostToDevice`] messages
//! (hello, enable, disable, set-force, heartbeat, clear-fault, set-state-rate); the device answers with
//! [`DeviceToHost`] messages (device info, state, heartbeat reply, fault, rejected). The same payloads travel in two
//! framings:
//!
//! - serial ([`serial`]): `COBS(type ‖ payload ‖ CRC-16/CCITT-FALSE) ‖ 0x00`, decoded by a streaming
//!   [`FrameDecoder`] that resynchronises at the next delimiter after garbage and counts every dropped frame;
//! - USB HID ([`hid`]): one 64-byte report per message, `[report id][type][payload][zero padding]`.
//!
//! [`DeviceSession`] is the device's state machine (session, enable, the set-force watchdog, state streaming),
//! [`HostSession`] the host's bookkeeping (handshake, sequence numbers, lost and stale state frames). Nothing reads a
//! clock: every time is a `u64` of microseconds passed in. The byte-level specification, with CRC parameters, state
//! machine and a firmware guide, is `protocol/SPEC.md`; `protocol/vectors/` holds test vectors.
#![no_std]
#![deny(missing_docs)]

pub mod cobs;
pub mod crc;
mod cursor;
pub mod device;
pub mod error;
pub mod fields;
pub mod hid;
pub mod host;
pub mod local;
pub mod local_build;
pub mod message;
mod num;
pub mod serial;
pub mod wire;

pub use device::{
    DeviceSample, DeviceSession, DeviceStats, DriveState, LocalTick, DEFAULT_WATCHDOG_TIMEOUT_US,
    MAX_WATCHDOG_TIMEOUT_US, MIN_WATCHDOG_TIMEOUT_US,
};
pub use error::{EncodeError, FrameError, PayloadError, ReportError};
pub use fields::{
    local_model_negotiated, FaultCode, FaultFlags, ForceFlags, Label, LabelError, RateSet,
    RejectReason, StatusFlags, Version, LOCAL_MODEL_VERSION, PROTOCOL_VERSION,
};
pub use hid::{decode_report, encode_report};
pub use host::{HostEvent, HostPhase, HostSession, HostStats};
pub use local::{
    LocalKind, LocalModel, LocalPassivity, LocalPassivityMode, LocalPrimitive, LocalState,
    LocalStatus, ModelFlags, SiPrimitive, MAX_LOCAL_PRIMITIVES,
};
pub use local_build::{build_local_model, LocalBuildError, LocalModelParams};
pub use message::{
    message_type, DeviceInfo, DeviceToHost, Enable, Fault, Heartbeat, HeartbeatReply, Hello,
    HostToDevice, Message, Rejected, SetForce, SetStateRate, State, MAX_PAYLOAD_LEN,
};
pub use serial::{
    decode_frame, encode_frame, DecoderStats, FrameDecoder, SliceError, MAX_WIRE_FRAME_LEN,
};
