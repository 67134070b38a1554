//! Each tick's truth, as every output shows it: the energy ledger's running totals, why the force is off
//! ([`ForceOffCause`]), which device faults are latched, and how old the device state the tick rendered from
//! was. One `Copy` value ([`TickTruth`]) travels from the servo thread in the [`crate::Snapshot`] and the
//! trace sample, so the trace columns, `/api/state`, `/api/stats`, the page and the Foxglove view all read
//! the same numbers.
//!
//! The CRTK operating state ([`crtk_operating_state`]) lives here too, so the ROS 2 output and the
//! Foxglove view compute it the same way: `FAULT` whenever the safety pipeline is faulted.

use glam::DVec3;
use serde::Serialize;
use voxhap_core::status::OutputState;

voxhap_core::named_enum! {
    /// Why no force (or less than rendered) can reach the hand this tick, in order of precedence: the first
    /// that applies is reported. `None` means the safety pipeline passes the rendered force (ramping in
    /// included); a zero force in free space is `None` too.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize)]
    #[serde(rename_all = "snake_case")]
    #[repr(u8)]
    pub enum ForceOffCause {
        /// Force passes the safety pipeline.
        #[default]
        None = 0 => "none",
        /// No device connected (it went away, or failed exchanges in a row; reconnecting).
        Disconnected = 1 => "disconnected",
        /// Connected, not enabled yet: the servo loop must run steadily first.
        NotEnabled = 2 => "not_enabled",
        /// Enabled, waiting for the rendered force to be small before engaging.
        NotEngaged = 3 => "not_engaged",
        /// The device reported a fault that needs a person (which: the `device_fault_bits`); `clear_fault`.
        DeviceFault = 4 => "device_fault",
        /// The device refused Enable; `clear_fault` retries.
        EnableRefused = 5 => "enable_refused",
        /// The device's own watchdog tripped; re-enabling once the link is healthy.
        DeviceWatchdog = 6 => "device_watchdog",
        /// The device's status said it was not enabled although the host had enabled it.
        DeviceDroppedOut = 7 => "device_dropped_out",
        /// The stall monitor stopped the device while the servo thread was stalled.
        MonitorStop = 8 => "monitor_stop",
        /// The host watchdog: the servo loop did not tick within the watchdog timeout.
        Watchdog = 9 => "watchdog",
        /// The state the force would be rendered from is older than the staleness bound, or no valid state
        /// came within the link timeout.
        StaleLink = 10 => "stale_link",
        /// The device's input was rejected: a non-finite probe, or a run of implausible positions dropped the
        /// link.
        ImplausibleInput = 11 => "implausible_input",
        /// The rendered force was not finite (replaced by zero).
        InvalidForce = 12 => "invalid_force",
    }
}

impl ForceOffCause {
    /// The cause with this name.
    pub fn from_name(name: &str) -> Option<ForceOffCause> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    /// True when the safety pipeline is faulted: a fault or refusal that needs the operator.
    pub fn is_fault(self) -> bool {
        matches!(
            self,
            ForceOffCause::DeviceFault | ForceOffCause::EnableRefused
        )
    }
}

/// The energy ledger's running totals at a tick (J), from what the device reported and what was sent
/// (zero-order hold). The quantities are defined in the servo's `energy` module and docs/recording.md.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct TickEnergy {
    /// Work the sent force did on the probe since the run started.
    pub work_on_probe_j: f64,
    /// The coupling spring's energy at this tick, `k/2 |proxy - probe|^2`.
    pub coupling_energy_j: f64,
    /// Energy the renderer generated: work on the probe plus the change of the coupling energy.
    pub generated_j: f64,
    /// Work of the directed-force modes on the probe (intended active work).
    pub active_work_j: f64,
    /// The least the device's own damping dissipated.
    pub device_dissipation_j: f64,
    /// Generated, less active work and device dissipation.
    pub net_generated_j: f64,
    /// Work the passivity controller's damping took from the probe since the run started (0 with the
    /// controller off or observing).
    pub passivity_dissipated_j: f64,
}

/// One tick's truth (module docs). `Copy`, fixed size.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct TickTruth {
    /// The energy ledger's totals at this tick.
    pub energy: TickEnergy,
    /// Why the force is off, `none` when it is not.
    pub force_off_cause: ForceOffCause,
    /// The device's latched faults (bit n = fault code n; 0 when none or unknown).
    pub device_fault_bits: u16,
    /// Age of the device state this tick rendered from (servo periods, counted from the force it
    /// answers): 0 for a state that answers the previous tick's force. Drivers that cannot tell report 0.
    pub sample_age_ticks: u32,
    /// The force the device itself reports reached the arm, with this tick's state (N, scene frame): the
    /// Haply Inverse3's `current_cursor_force`, after the Inverse Service's own filters. `None` for devices
    /// that report none, and on ticks without a state.
    pub device_force_n: Option<DVec3>,
    /// The external force added to the rendered force this tick (N, scene frame; `serve --external-force`):
    /// zero when the input is off, nothing was sent, the last force is older than the staleness timeout, or
    /// the tick had no device state to render from.
    pub external_force_n: DVec3,
    /// What a device with the local-model capability reported about its own loop with this tick's state
    /// (protocol SPEC section 10.4, in the scene frame): the proxy it solved, its certificate and the age of the
    /// model it rendered. `None` on ticks that sent no local model, and before the device's first report.
    pub device_local: Option<DeviceLocal>,
}

/// A capable device's own proxy, certificate and model age (protocol SPEC section 10.4), scene frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DeviceLocal {
    /// The proxy the device's loop solved (m).
    pub proxy_m: DVec3,
    /// The certified error bound of that solve (m): the device's proxy is within this of the exact one for
    /// the model it rendered.
    pub proxy_bound_m: f64,
    /// Sequence number of the model the device rendered (0: none yet).
    pub model_sequence: u32,
    /// Device time since that model arrived (s).
    pub model_age_s: f64,
}

/// The energy ledger's totals and verdicts for a whole run (`/api/stats` → `energy`, the run summary).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct EnergyReport {
    /// The totals at the last tick.
    #[serde(flatten)]
    pub totals: TickEnergy,
    /// The largest rise of the net generated energy over any window (J).
    pub largest_rise_j: f64,
    /// Contacts begun.
    pub contacts: u64,
    /// The longest run of undecaying contacts in quick succession.
    pub longest_cycle_run: u32,
    /// `--fail-on active` would be met: the net generated energy rose by more than the tolerance.
    pub active: bool,
    /// `--fail-on oscillation` would be met: a contact limit cycle.
    pub oscillating: bool,
}

impl EnergyReport {
    /// The line of the run summary (`serve`'s exit table), with a newline.
    pub fn summary(&self) -> String {
        format!(
            "energy: work on probe {:.6} J, coupling {:.6} J, generated {:.6} J, active work {:.6} J, \
             device dissipation {:.6} J, net generated {:.6} J (largest rise {:.6} J{}), passivity \
             controller dissipated {:.6} J, contacts {}, longest undecaying contact run {}{}\n",
            self.totals.work_on_probe_j,
            self.totals.coupling_energy_j,
            self.totals.generated_j,
            self.totals.active_work_j,
            self.totals.device_dissipation_j,
            self.totals.net_generated_j,
            self.largest_rise_j,
            if self.active { ": active" } else { "" },
            self.totals.passivity_dissipated_j,
            self.contacts,
            self.longest_cycle_run,
            if self.oscillating { ": oscillation" } else { "" },
        )
    }
}

/// CRTK's standard operating states.
pub mod crtk_state {
    pub const DISABLED: &str = "DISABLED";
    pub const ENABLED: &str = "ENABLED";
    pub const PAUSED: &str = "PAUSED";
    pub const FAULT: &str = "FAULT";
}

/// The CRTK state, `is_homed` and `is_busy` for `output` and the tick's force-off cause (`None`: the servo
/// loop has not ticked yet).
///
/// FAULT whenever the safety pipeline is faulted (`faulted`, `enable_refused`, or a force-off cause that is
/// a fault): the operator's `clear_fault`. ENABLED is force reaching the hand or about to (`engaged`;
/// `waiting_to_engage` and `ramping_in` are ENABLED and busy); DISABLED is no force, busy while voxhap is
/// bringing the device up on its own (`starting`, `recovering`, `stale_state`). `is_homed` is true while a
/// device is connected: voxhap's devices report calibrated positions from connection on.
pub fn crtk_operating_state(
    output: Option<(OutputState, ForceOffCause)>,
) -> (&'static str, bool, bool) {
    let Some((output, cause)) = output else {
        return (crtk_state::DISABLED, false, true);
    };
    let homed = output != OutputState::Disconnected;
    if cause.is_fault() {
        return (crtk_state::FAULT, homed, false);
    }
    let (name, busy) = match output {
        OutputState::Faulted | OutputState::EnableRefused => (crtk_state::FAULT, false),
        OutputState::Engaged => (crtk_state::ENABLED, false),
        OutputState::WaitingToEngage | OutputState::RampingIn => (crtk_state::ENABLED, true),
        OutputState::Starting | OutputState::Recovering | OutputState::StaleState => {
            (crtk_state::DISABLED, true)
        }
        OutputState::Disconnected => (crtk_state::DISABLED, false),
    };
    (name, homed, busy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_unique() {
        for (code, cause) in ForceOffCause::ALL.into_iter().enumerate() {
            assert_eq!(cause as u8 as usize, code);
            assert_eq!(ForceOffCause::from_name(cause.name()), Some(cause));
        }
        let mut names: Vec<_> = ForceOffCause::ALL.iter().map(|c| c.name()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), ForceOffCause::ALL.len());
    }

    /// CRTK "Robot API status": FAULT is a state the robot does not leave without the operator. A faulted
    /// pipeline is FAULT whatever output state a caller pairs it with.
    #[test]
    fn a_faulted_pipeline_is_fault_in_every_output_state() {
        for output in OutputState::ALL {
            let (name, _, _) = crtk_operating_state(Some((output, ForceOffCause::DeviceFault)));
            assert_eq!(name, "FAULT", "{output:?}");
        }
        assert_eq!(
            crtk_operating_state(Some((OutputState::Faulted, ForceOffCause::None))).0,
            "FAULT"
        );
        assert_eq!(
            crtk_operating_state(Some((OutputState::Engaged, ForceOffCause::None))).0,
            "ENABLED"
        );
    }
}
