//! [`ServoDevice`]: the device as the servo thread sees it, and its implementation for every supervised driver.

use super::error::ConnectError;
use crate::monitor::StopSlot;
use glam::DVec3;
use std::sync::Arc;
use voxhap_device::latency::{LinkDelaySeen, LinkLatency};
use voxhap_device::mapping::WorkspaceMapping;
use voxhap_device::plausibility::InputCounters;
use voxhap_device::supervisor::{
    ClearFaultOutcome, OutputState, Supervisor, SupervisorCounters, SupervisorOutput, TickInput,
};
use voxhap_device::{DeviceError, DeviceInfo, HapticDevice};

/// The device as the servo thread sees it: one exchange per tick, plus a few queries.
pub trait ServoDevice: Send {
    /// Makes the tick's force safe, sends it and reads the answering state (see [`Supervisor::tick`]).
    fn exchange(&mut self, input: TickInput) -> SupervisorOutput;
    /// The supervisor's counters.
    fn counters(&self) -> SupervisorCounters;
    /// The input checks' counters.
    fn input_counters(&self) -> InputCounters;
    /// True once the safety pipeline passes forces at full strength.
    fn engaged(&self) -> bool;
    /// Where the output stands.
    fn output_state(&self) -> OutputState;
    /// Age (servo periods) of the state the next force is rendered from ([`Supervisor::state_age_ticks`]).
    fn state_age_ticks(&self) -> u32 {
        0
    }
    /// The operator's `clear_fault` (ClearFault goes out on the next tick).
    fn request_clear_fault(&mut self) -> ClearFaultOutcome;
    /// Zero force, disable, close.
    fn stop(&mut self);
    /// Opens the device now (before the loop starts), so a missing device fails `serve` at once.
    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError>;
    /// The servo clock starts over at `now_us` after a set-up it did not see ([`Supervisor::restart_clock`]).
    fn restart_clock(&mut self, now_us: u64);
    /// The device's capabilities, while connected.
    fn info(&self) -> Option<DeviceInfo>;
    /// The servo period (µs), for the slew limit.
    fn set_period_us(&mut self, period_us: u64);
    /// Where the stall monitor finds the device's stop channel, and the flag it raises after using it.
    fn set_stop_slot(&mut self, slot: Arc<StopSlot>);
    /// The connected device's declared maximum stiffness at 1 kHz (N/m), without allocating.
    fn max_stiffness_n_per_m(&self) -> Option<f64>;
    /// Lines for the operator from the device profile (`servo::mapped`): how the workspace is mapped into the
    /// scene when that is not the identity, and limits the profile asks for above the device's own.
    fn profile_notes(&self) -> Vec<String> {
        Vec::new()
    }
    /// A damping limit below the passivity bound (N s/m, scene units), from a device profile.
    fn max_damping_n_s_per_m(&self) -> Option<f64> {
        None
    }
    /// The mapping from the device frame into the scene in force (after `connect`; `servo::mapped`): the
    /// control side maps a client's hand target (scene frame) through it into the device frame.
    fn workspace_mapping(&self) -> WorkspaceMapping {
        WorkspaceMapping::IDENTITY
    }
    /// The connected device's link latency as its driver declares it (`HapticDevice::link_latency`), `None`
    /// when none is connected or the driver does not know it: the passivity observer's pairing.
    fn link_latency(&self) -> Option<LinkLatency> {
        None
    }
    /// The round trips the connected device's driver timed on every tick since it opened
    /// (`HapticDevice::link_delay_seen`), `None` when none is connected or the driver times none: the delay the
    /// link really had, which the passivity observer's pairing follows. Allocation-free.
    fn link_delay_seen(&self) -> Option<LinkDelaySeen> {
        None
    }
    /// The force the connected device reports reached the arm with its last state (N;
    /// `HapticDevice::reported_force_n`), `None` when it reports none. Allocation-free.
    fn reported_force_n(&self) -> Option<DVec3> {
        None
    }
}

/// The [`ServoDevice`] methods a wrapper answers as the device it wraps, the field `$inner` (a [`ServoDevice`]):
/// the supervisor's counters, state, latency and fault clearing, which neither a workspace mapping
/// (`crate::mapped`) nor a reconnection (`super::reconnect`) changes. Written inside the wrapper's
/// `impl ServoDevice`.
macro_rules! forward_to_wrapped {
    ($inner:ident) => {
        fn counters(&self) -> ::voxhap_device::supervisor::SupervisorCounters {
            self.$inner.counters()
        }

        fn input_counters(&self) -> ::voxhap_device::plausibility::InputCounters {
            self.$inner.input_counters()
        }

        fn engaged(&self) -> bool {
            self.$inner.engaged()
        }

        fn output_state(&self) -> ::voxhap_device::supervisor::OutputState {
            self.$inner.output_state()
        }

        fn state_age_ticks(&self) -> u32 {
            self.$inner.state_age_ticks()
        }

        fn link_latency(&self) -> Option<::voxhap_device::latency::LinkLatency> {
            self.$inner.link_latency()
        }

        fn link_delay_seen(&self) -> Option<::voxhap_device::latency::LinkDelaySeen> {
            self.$inner.link_delay_seen()
        }

        fn request_clear_fault(&mut self) -> ::voxhap_device::supervisor::ClearFaultOutcome {
            self.$inner.request_clear_fault()
        }

        fn set_period_us(&mut self, period_us: u64) {
            self.$inner.set_period_us(period_us);
        }

        fn restart_clock(&mut self, now_us: u64) {
            self.$inner.restart_clock(now_us);
        }
    };
}
pub(crate) use forward_to_wrapped;

impl<D, F> ServoDevice for Supervisor<D, F>
where
    D: HapticDevice + Send,
    F: FnMut() -> Result<D, DeviceError> + Send,
{
    fn exchange(&mut self, input: TickInput) -> SupervisorOutput {
        self.tick(input)
    }

    fn counters(&self) -> SupervisorCounters {
        Supervisor::counters(self)
    }

    fn input_counters(&self) -> InputCounters {
        Supervisor::input_counters(self)
    }

    fn engaged(&self) -> bool {
        self.safety().is_engaged()
    }

    fn output_state(&self) -> OutputState {
        Supervisor::output_state(self)
    }

    fn state_age_ticks(&self) -> u32 {
        Supervisor::state_age_ticks(self)
    }

    fn reported_force_n(&self) -> Option<DVec3> {
        self.device()
            .and_then(|device| device.device().reported_force_n())
    }

    fn link_latency(&self) -> Option<LinkLatency> {
        Supervisor::link_latency(self)
    }

    fn link_delay_seen(&self) -> Option<LinkDelaySeen> {
        Supervisor::link_delay_seen(self)
    }

    fn request_clear_fault(&mut self) -> ClearFaultOutcome {
        Supervisor::request_clear_fault(self)
    }

    fn stop(&mut self) {
        Supervisor::stop(self);
    }

    fn connect(&mut self, now_us: u64) -> Result<(), ConnectError> {
        Supervisor::connect(self, now_us).map_err(|kind| ConnectError {
            kind,
            message: format!("could not open the device ({kind:?})"),
        })
    }

    fn info(&self) -> Option<DeviceInfo> {
        self.device().map(|d| d.info().clone())
    }

    fn set_period_us(&mut self, period_us: u64) {
        Supervisor::set_period_us(self, period_us);
    }

    fn restart_clock(&mut self, now_us: u64) {
        Supervisor::restart_clock(self, now_us);
    }

    fn set_stop_slot(&mut self, slot: Arc<StopSlot>) {
        if let Some(device) = self.device() {
            slot.install(device.emergency_stop());
        }
        self.set_stall_flag(slot.tripped_flag());
    }

    fn max_stiffness_n_per_m(&self) -> Option<f64> {
        self.device().map(|d| d.info().max_stiffness_n_per_m)
    }
}
