//! Why the force is off this tick: one [`ForceOffCause`] per tick, derived from what the safety pipeline did
//! (the supervisor's output state, its safety flags and events) and what the tick itself refused.
//!
//! Where it sits: on the servo thread, after the device exchange (`super::runner`); allocation-free. The
//! supervisor reports *why* it dropped a link or went to `Recovering` once, as an event; [`ForceOffTracker`]
//! remembers that reason for as long as the state lasts, so every tick of a recovery or a reconnect names
//! it. Precedence (the first that applies): disconnected (or, when the link was dropped for it, stale link
//! or implausible input), device fault, enable refused, recovering (device watchdog, monitor stop or device
//! dropped out), not enabled, host watchdog, stale link, implausible input, invalid force, not engaged,
//! none.

use voxhap_api::ForceOffCause;
use voxhap_core::haptics::tick::TickStatus;
use voxhap_device::safety::SafetyFlags;
use voxhap_device::supervisor::{LossReason, OutputState, SupervisorEvent, SupervisorOutput};
use voxhap_device::DeviceEvent;

/// Remembers the reasons the supervisor reports once (module docs).
#[derive(Debug, Clone, Copy, Default)]
pub struct ForceOffTracker {
    /// Why the link was last dropped.
    loss: ForceOffCause,
    /// Why the device last went to `Recovering`.
    recovery: ForceOffCause,
}

impl ForceOffTracker {
    /// The cause for a tick whose exchange gave `out`, whose solve ended with `status`, and whose rendered
    /// force was replaced for not being finite when `force_replaced`.
    pub fn cause(
        &mut self,
        out: &SupervisorOutput,
        status: TickStatus,
        force_replaced: bool,
    ) -> ForceOffCause {
        for event in out.events.iter() {
            match event {
                SupervisorEvent::Disconnected { reason, .. } => {
                    self.loss = match reason {
                        LossReason::NoValidState => ForceOffCause::StaleLink,
                        LossReason::ImplausiblePositions => ForceOffCause::ImplausibleInput,
                        _ => ForceOffCause::Disconnected,
                    };
                }
                SupervisorEvent::Device(DeviceEvent::Fault { code: 0, .. }) => {
                    self.recovery = ForceOffCause::DeviceWatchdog
                }
                SupervisorEvent::StallStop => self.recovery = ForceOffCause::MonitorStop,
                SupervisorEvent::DroppedOut => self.recovery = ForceOffCause::DeviceDroppedOut,
                _ => {}
            }
        }
        if !out.connected || out.output_state == OutputState::Disconnected {
            return match self.loss {
                ForceOffCause::None => ForceOffCause::Disconnected,
                loss => loss,
            };
        }
        let flags = out.flags;
        match out.output_state {
            OutputState::Faulted => return ForceOffCause::DeviceFault,
            OutputState::EnableRefused => return ForceOffCause::EnableRefused,
            OutputState::Recovering => {
                return match self.recovery {
                    ForceOffCause::None => ForceOffCause::DeviceDroppedOut,
                    recovery => recovery,
                }
            }
            OutputState::Starting => return ForceOffCause::NotEnabled,
            _ => {}
        }
        if flags.contains(SafetyFlags::DEVICE_FAULTED) {
            return ForceOffCause::DeviceFault;
        }
        if flags.contains(SafetyFlags::DEVICE_NOT_ENABLED) {
            return ForceOffCause::DeviceDroppedOut;
        }
        if flags.contains(SafetyFlags::WATCHDOG) {
            return ForceOffCause::Watchdog;
        }
        if flags.contains(SafetyFlags::STALE_STATE) || out.output_state == OutputState::StaleState {
            return ForceOffCause::StaleLink;
        }
        if status == TickStatus::InputRejected {
            return ForceOffCause::ImplausibleInput;
        }
        if force_replaced || flags.contains(SafetyFlags::NON_FINITE) {
            return ForceOffCause::InvalidForce;
        }
        if out.output_state == OutputState::WaitingToEngage
            || flags.contains(SafetyFlags::WAITING_TO_ENGAGE)
            || flags.contains(SafetyFlags::OUTPUT_OFF)
        {
            return ForceOffCause::NotEngaged;
        }
        // Connected and passing force: the reasons of past losses and recoveries are history.
        self.loss = ForceOffCause::None;
        self.recovery = ForceOffCause::None;
        ForceOffCause::None
    }
}
