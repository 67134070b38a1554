//! A voxhap-protocol device written from protocol/SPEC.md alone, run in a thread on the device side of a
//! pseudo-terminal, that logs everything the host sends and can misbehave on request.
//!
//! Where it sits: a test spawns it ([`SpecDevice::spawn`]), starts the real host (`voxhap serve --device
//! serial:PATH`) on [`SpecDeviceHandle::path`], and asserts on the device-side logs ([`SpecDeviceHandle::forces`],
//! [`SpecDeviceHandle::messages`], [`SpecDeviceHandle::sent`]) and the helpers built on them
//! ([`SpecDeviceHandle::max_force_while_not_enabled`], [`SpecDeviceHandle::max_slew_n_per_ms`],
//! [`SpecDeviceHandle::nonzero_forces_after_index`], ...). It is an independent second reading of the SPEC: COBS,
//! CRC-16/CCITT-FALSE and the payload layouts are implemented here from the SPEC text, not with the
//! `voxhap-protocol` crate, and nothing here was written from the host's driver code. Two tests in
//! tests/device_spec/vectors.rs check the double itself: its codec against `protocol/vectors/*.hex`, and its state machine
//! against a host written with the reference crate.
//!
//! ```ignore
//! let config = SpecDeviceConfig { refuse_enable: Some(reject::FAULTED), ..Default::default() };
//! let mut device = SpecDevice::spawn(config);
//! // run `voxhap serve --device serial:{device.path()}` ...
//! device.stop();
//! assert_eq!(device.max_force_while_not_enabled(), 0.0);
//! ```
//!
//! Behaviour, by SPEC section:
//! - §4.1 / §4.3: the pty's slave side is put in raw mode at creation; the device sends a lone 0x00 at start-up
//!   (and after a reset) and before every DeviceInfo.
//! - §4.2 / §4.4: frames are `COBS(type ‖ payload ‖ CRC-16 LE) ‖ 0x00`; a frame that fails COBS, length, CRC, type
//!   or payload-size checks is dropped and counted ([`SpecDeviceHandle::dropped_frames`]), never answered. A
//!   SetForce with a non-finite component is **logged** (so a test can see the host sent it) and then dropped as the
//!   SPEC says (`invalid_value`).
//! - §6 table: session closed / open, drive Idle / Enabled / Faulted, Hello (DeviceInfo, Rejected on a version
//!   mismatch), Heartbeat → HeartbeatReply always, Rejected(NO_SESSION) for anything but SetForce while closed,
//!   Enable / Disable / ClearFault / SetStateRate with their Rejected replies.
//! - §6.1: the status bits; §6.2: the force clamp at `max_force_n` (in f64); §6.3: Fault frames (WATCHDOG_EXPIRED
//!   drops to Idle, codes ≥ 1 latch until ClearFault); §6.4: State sequence +1 per State from power-up.
//! - §6.5: the watchdog (default 50 ms, set per Enable) is checked by the device's own 1 kHz control loop, whether
//!   or not bytes arrive.
//! - §6.6: lockstep: one State per SetForce (a control cycle runs as soon as a SetForce is received, so the State
//!   is sampled and sent at once); streaming at SetStateRate(r) from the device clock.
//! - §6.7: the double's outbox is unbounded: it never drops a reply of its own accord (only on purpose, below).
//! - §6.8: a device with `position_dof` 1 or 2 reports the components it does not sense as 0 (unless told to
//!   report garbage there, `unused_components`), and one with `force_dof` 1 or 2 applies only the components it
//!   renders (the log keeps all three as received).
//! - Not modelled: buttons (always 0) and non-finite samples (the scripted handle is always finite, so no ENCODER
//!   fault arises by itself; a test can inject one with `fault`).
//!
//! The logs: every SetForce received ([`ForceRecord`]: arrival [`Instant`], host sequence, force, whether the drive
//! was Enabled at that moment), every other message received ([`MessageRecord`], including a `PortClosed` event
//! when the host closes the pty), every frame written ([`SentRecord`]) and every trigger as it fired
//! ([`TriggerRecord`]). All four share one event counter (`index`) so that their order is exact.
//!
//! Misbehaviour ([`SpecDeviceConfig`] fields, each off by default): refuse every Enable; start Faulted; raise a
//! Fault at a [`Trigger`] (a time after the first Enable, or the first moment an applied force is above a
//! threshold); corrupt the first N DeviceInfo replies (bad CRC); speak another major version; stop replying for a
//! while; delay every reply; delay DeviceInfo (and so everything after it) by a configurable time; corrupt a
//! fraction of the bytes it writes (seeded); send every Nth frame cut in half; add a position jump; report a fixed
//! (absurd or inconsistent) velocity; report garbage in the components a 1- or 2-DOF device does not use; reset (a
//! brown-out). The handle follows a
//! scripted function of time ([`HandleFn`]), and can be held still from a trigger on; `max_force_n`,
//! `max_stiffness_n_per_m` and the workspace are what DeviceInfo declares. A test can also have the device thread
//! run an action of its own at a trigger (`call_at`), so that it acts on the host while force is flowing, not some
//! scheduling delay later.
//!
//! The parts: [`wire`] the wire format; [`config`] what a test asks of the device; [`log`] what it records;
//! `device` the state machine and its misbehaviours; [`handle`] spawning and asserting.

mod config;
mod device;
mod handle;
mod log;
mod wire;

pub use config::{Callback, HandleFn, HandleTime, SpecDeviceConfig, Trigger};
pub use handle::{SpecDevice, SpecDeviceHandle};
pub use log::{ForceRecord, HostMessage, MessageRecord, TriggerRecord};
pub use wire::{crc16, decode_frame, encode_frame, fault, payload_len, reject, types};
