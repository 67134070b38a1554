//! The host side of the protocol as a sans-IO helper: the handshake, set-force sequence numbers, and tracking of
//! the device's state frames (lost, stale, and how many set-forces the device has not yet acknowledged).
//!
//! Where it sits: voxhap's protocol driver (crates/device/src/) builds outgoing [`HostToDevice`] messages here, encodes
//! them with [`crate::serial`] or [`crate::hid`], and passes every decoded [`DeviceToHost`] to
//! [`HostSession::on_message`], which classifies it. Safety (clamping, ramps, the host watchdog) stays in the host's
//! safety pipeline; this only keeps protocol bookkeeping.
//!
//! Sequence arithmetic is modulo 2^32: a state whose sequence is 1..2^31 ahead of the last accepted one is new (the
//! gap minus one frames were lost); 0 or more than 2^31 ahead means behind (a duplicate or reordered frame), which is
//! counted and reported as stale so that the caller never steps time backwards.

use crate::fields::{ForceFlags, PROTOCOL_VERSION};
use crate::local::LocalState;
use crate::local::SiPrimitive;
use crate::local_build::{build_local_model, LocalBuildError, LocalModelParams};
use crate::message::{
    DeviceInfo, DeviceToHost, Enable, Fault, Heartbeat, HeartbeatReply, Hello, HostToDevice,
    Rejected, SetForce, SetStateRate, State,
};

/// Where the handshake stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostPhase {
    /// Hello not sent yet, or sent and no device info back.
    AwaitingInfo,
    /// The device answered with a compatible version.
    Ready,
    /// The device answered with another major version; do not enable.
    Incompatible,
}

/// Counters of a host session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct HostStats {
    /// State frames accepted (in order).
    pub states_received: u64,
    /// State frames missing from the sequence (gaps).
    pub states_lost: u64,
    /// State frames that arrived after a newer one, or twice.
    pub states_stale: u64,
    /// Fault reports received.
    pub faults: u64,
    /// Rejected messages received.
    pub rejections: u64,
}

/// What a message from the device means for the host.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HostEvent {
    /// Device info with a compatible version: the session is ready to enable.
    Connected(DeviceInfo),
    /// Device info with another major version.
    Incompatible(DeviceInfo),
    /// A new state frame, in sequence order; `lost` frames were skipped since the previous one.
    State {
        /// The state.
        state: State,
        /// Frames missing between the previous accepted state and this one.
        lost: u32,
    },
    /// A state frame older than one already accepted (or a duplicate): ignore it.
    StaleState(State),
    /// Answer to a heartbeat.
    Heartbeat(HeartbeatReply),
    /// The device dropped to zero force.
    Fault(Fault),
    /// The device refused a message.
    Rejected(Rejected),
    /// The device's local loop (local-model capability), reported right after a State.
    LocalState(LocalState),
}

/// Host-side protocol bookkeeping for one device.
#[derive(Debug, Clone)]
pub struct HostSession {
    phase: HostPhase,
    info: Option<DeviceInfo>,
    last_force_sequence: u32,
    last_heartbeat: u32,
    last_state_sequence: Option<u32>,
    acknowledged_force_sequence: u32,
    stats: HostStats,
}

impl Default for HostSession {
    fn default() -> Self {
        Self::new()
    }
}

impl HostSession {
    /// A session before the handshake.
    pub const fn new() -> Self {
        Self {
            phase: HostPhase::AwaitingInfo,
            info: None,
            last_force_sequence: 0,
            last_heartbeat: 0,
            last_state_sequence: None,
            acknowledged_force_sequence: 0,
            stats: HostStats {
                states_received: 0,
                states_lost: 0,
                states_stale: 0,
                faults: 0,
                rejections: 0,
            },
        }
    }

    /// Handshake progress.
    pub fn phase(&self) -> HostPhase {
        self.phase
    }

    /// The device info from the last handshake.
    pub fn device_info(&self) -> Option<&DeviceInfo> {
        self.info.as_ref()
    }

    /// Counters.
    pub fn stats(&self) -> &HostStats {
        &self.stats
    }

    /// Starts (or restarts) the handshake.
    pub fn hello(&mut self) -> HostToDevice {
        self.phase = HostPhase::AwaitingInfo;
        self.last_state_sequence = None;
        HostToDevice::Hello(Hello {
            version: PROTOCOL_VERSION,
        })
    }

    /// Enable with a watchdog timeout in microseconds (0 = the device default, 50 ms).
    pub fn enable(&self, watchdog_timeout_us: u32) -> HostToDevice {
        HostToDevice::Enable(Enable {
            watchdog_timeout_us,
        })
    }

    /// Choose the state rate (0 = lockstep).
    pub fn set_state_rate(&self, state_rate_hz: u16) -> HostToDevice {
        HostToDevice::SetStateRate(SetStateRate { state_rate_hz })
    }

    /// The next set-force, with a fresh sequence number (1, 2, ...). The force must be finite (the encoder refuses
    /// NaN); the host's safety pipeline has already clamped it.
    pub fn set_force(&mut self, force_n: [f32; 3], flags: ForceFlags) -> HostToDevice {
        self.last_force_sequence = self.last_force_sequence.wrapping_add(1);
        HostToDevice::SetForce(SetForce {
            sequence: self.last_force_sequence,
            force_n,
            flags,
        })
    }

    /// A local model for a capable device (SPEC section 10), numbered in the set-force sequence (the
    /// `sequence` in `params` is replaced). A model that cannot be built takes no sequence number.
    pub fn local_model(
        &mut self,
        params: &LocalModelParams,
        primitives: &[SiPrimitive],
    ) -> Result<HostToDevice, LocalBuildError> {
        let sequence = self.last_force_sequence.wrapping_add(1);
        let params = LocalModelParams {
            sequence,
            ..*params
        };
        let model = build_local_model(&params, primitives)?;
        self.last_force_sequence = sequence;
        Ok(HostToDevice::LocalModel(model))
    }

    /// The next heartbeat, with a fresh counter.
    pub fn heartbeat(&mut self) -> HostToDevice {
        self.last_heartbeat = self.last_heartbeat.wrapping_add(1);
        HostToDevice::Heartbeat(Heartbeat {
            counter: self.last_heartbeat,
        })
    }

    /// Set-forces sent that no state frame has acknowledged yet (the link's depth in frames).
    pub fn forces_in_flight(&self) -> u32 {
        self.last_force_sequence
            .wrapping_sub(self.acknowledged_force_sequence)
    }

    /// Classifies one message from the device and updates the bookkeeping.
    pub fn on_message(&mut self, message: &DeviceToHost) -> HostEvent {
        match *message {
            DeviceToHost::DeviceInfo(info) => {
                self.info = Some(info);
                if PROTOCOL_VERSION.is_compatible_with(info.version) {
                    self.phase = HostPhase::Ready;
                    HostEvent::Connected(info)
                } else {
                    self.phase = HostPhase::Incompatible;
                    HostEvent::Incompatible(info)
                }
            }
            DeviceToHost::State(state) => self.on_state(state),
            DeviceToHost::Heartbeat(reply) => HostEvent::Heartbeat(reply),
            DeviceToHost::Fault(fault) => {
                self.stats.faults = self.stats.faults.wrapping_add(1);
                HostEvent::Fault(fault)
            }
            DeviceToHost::Rejected(rejected) => {
                self.stats.rejections = self.stats.rejections.wrapping_add(1);
                HostEvent::Rejected(rejected)
            }
            DeviceToHost::LocalState(local) => HostEvent::LocalState(local),
        }
    }

    fn on_state(&mut self, state: State) -> HostEvent {
        let lost = match self.last_state_sequence {
            None => 0,
            Some(last) => {
                let ahead = state.sequence.wrapping_sub(last);
                if ahead == 0 || ahead > u32::MAX / 2 {
                    self.stats.states_stale = self.stats.states_stale.wrapping_add(1);
                    return HostEvent::StaleState(state);
                }
                ahead - 1
            }
        };
        self.last_state_sequence = Some(state.sequence);
        // Only move the acknowledgement forward (modulo 2^32), and never past what was sent.
        let echoed_ahead = state
            .last_force_sequence
            .wrapping_sub(self.acknowledged_force_sequence);
        if echoed_ahead <= self.forces_in_flight() {
            self.acknowledged_force_sequence = state.last_force_sequence;
        }
        self.stats.states_received = self.stats.states_received.wrapping_add(1);
        self.stats.states_lost = self.stats.states_lost.wrapping_add(u64::from(lost));
        HostEvent::State { state, lost }
    }
}
