//! What a device is and what it senses: [`DeviceInfo`], the capability record every driver fills in (chai3d's
//! `cHapticDeviceInfo` in spirit: degrees of freedom, workspace, maximum force, stiffness and speed, rates),
//! [`DeviceState`], one sample of the handle, and [`DeviceStatus`], what the device itself says about whether
//! it is applying force.
//!
//! Where it sits: the servo loop reads `DeviceInfo` once after open (it sizes the safety pipeline's clamp, the
//! plausibility checks and the coupling caps), and a `DeviceState` every tick (the probe position). The status
//! a device reports is the truth the supervisor acts on (docs/design.md, "The safety pipeline"): force is
//! commanded only while the device says it is enabled. Units are SI.

use glam::DVec3;

/// The hand speed assumed when a driver does not know its device's (m/s): a fast human hand movement.
pub const DEFAULT_MAX_SPEED_M_PER_S: f64 = 5.0;

/// Capabilities of a device, as plain data.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// Model name, for people.
    pub model: String,
    /// Serial number or other identity, may be empty.
    pub serial_number: String,
    /// Sensed degrees of freedom (3 for a position-only arm, 2 for a planar one).
    pub position_dof: u8,
    /// Actuated degrees of freedom.
    pub force_dof: u8,
    /// Number of buttons reported in [`DeviceState::buttons`].
    pub button_count: u8,
    /// Lower corner of the reachable box in the device frame (m).
    pub workspace_min_m: DVec3,
    /// Upper corner of the reachable box in the device frame (m).
    pub workspace_max_m: DVec3,
    /// Largest force the device renders (N).
    pub max_force_n: f64,
    /// Largest coupling stiffness rendered stably at 1 kHz (N/m); 0 when the device does not state one.
    pub max_stiffness_n_per_m: f64,
    /// Fastest the handle can move (m/s); positions that jump further in one sample are rejected.
    pub max_speed_m_per_s: f64,
    /// True when [`DeviceState::velocity_m_per_s`] is measured by the device; false when the driver reports
    /// zero and the host estimates velocity from positions.
    pub reports_velocity: bool,
    /// State rates the device can stream at (Hz); empty when it only answers each force (lockstep).
    pub state_rates_hz: Vec<u16>,
}

impl DeviceInfo {
    /// The components of position and velocity this device senses ([`super::dof`], SPEC 6.8).
    pub fn position_axes(&self) -> super::dof::UsedAxes {
        super::dof::UsedAxes::from_dof(self.position_dof)
    }

    /// The components of force this device renders ([`super::dof`], SPEC 6.8).
    pub fn force_axes(&self) -> super::dof::UsedAxes {
        super::dof::UsedAxes::from_dof(self.force_dof)
    }

    /// A record with the given model and workspace and conservative defaults for the rest (3 DOF, 3 N,
    /// 1 000 N/m, [`DEFAULT_MAX_SPEED_M_PER_S`], no velocity, lockstep); drivers override what they know.
    pub fn basic(model: &str, workspace_min_m: DVec3, workspace_max_m: DVec3) -> DeviceInfo {
        DeviceInfo {
            model: model.to_owned(),
            serial_number: String::new(),
            position_dof: 3,
            force_dof: 3,
            button_count: 0,
            workspace_min_m,
            workspace_max_m,
            max_force_n: 3.0,
            max_stiffness_n_per_m: 1000.0,
            max_speed_m_per_s: DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: false,
            state_rates_hz: Vec::new(),
        }
    }
}

/// What the device says about its drive, where it says anything (voxhap protocol status bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeviceStatus {
    /// The device is applying the forces it receives.
    pub enabled: bool,
    /// A latched fault holds the device at zero force until it is cleared.
    pub faulted: bool,
    /// The device's own watchdog dropped the force since the last Enable.
    pub watchdog_tripped: bool,
    /// The device scaled the force it applies down to its maximum.
    pub force_clamped: bool,
    /// Latched fault codes: bit n = fault code n.
    pub active_faults: u16,
}

/// One sample of a device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceState {
    /// Handle position in the device frame (m).
    pub position_m: DVec3,
    /// Handle velocity (m/s); drivers without a velocity measurement report zero (see
    /// [`DeviceInfo::reports_velocity`]).
    pub velocity_m_per_s: DVec3,
    /// Button `n` pressed = bit `n`.
    pub buttons: u16,
    /// Device clock at the sample (µs), where the device has one.
    pub device_time_us: Option<u64>,
    /// The device's own sequence number of this sample, where it has one.
    pub sequence: Option<u32>,
    /// The drive status the device reported with this sample; `None` for devices that report none (their
    /// status follows the host's lifecycle).
    pub status: Option<DeviceStatus>,
}

impl DeviceState {
    /// A handle at rest at `position_m`.
    pub fn at_rest(position_m: DVec3) -> DeviceState {
        DeviceState {
            position_m,
            velocity_m_per_s: DVec3::ZERO,
            buttons: 0,
            device_time_us: None,
            sequence: None,
            status: None,
        }
    }
}

/// Something the device told the host outside a state sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceEvent {
    /// The device dropped to zero force for `code` (voxhap protocol numbering: 0 its watchdog expired, which
    /// does not latch; 1 and up latch until cleared).
    Fault {
        /// Fault code.
        code: u8,
        /// All latched fault bits after the event.
        active_faults: u16,
    },
    /// The device refused a command and changed nothing.
    Rejected {
        /// Type byte of the refused message.
        message_type: u8,
        /// Reason code (1 no session, 2 version mismatch, 3 faulted, 4 invalid argument).
        reason: u8,
    },
    /// The device sent more than the host asked for (a second answer to one command, a flood of replies):
    /// the driver rendered from the newest and dropped the rest. Reported at the first surplus message, at 10,
    /// 100 and 1 000, then every 1 000 more ([`SurplusCount`]).
    Surplus {
        /// Surplus messages since the driver was opened.
        total: u64,
    },
}

/// Counts the messages a device sent beyond what the host asked for, and says when to report them
/// ([`DeviceEvent::Surplus`]: at 1, 10, 100, 1 000, then every 1 000 more, so a device that always answers
/// twice is reported without flooding the event ring). Allocation-free.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SurplusCount {
    total: u64,
    next_report: u64,
}

impl SurplusCount {
    /// Adds `n` surplus messages; returns the event to report when a reporting threshold was crossed.
    pub fn add(&mut self, n: u64) -> Option<DeviceEvent> {
        if n == 0 {
            return None;
        }
        self.total = self.total.saturating_add(n);
        if self.next_report == 0 {
            self.next_report = 1;
        }
        if self.total < self.next_report {
            return None;
        }
        while self.next_report <= self.total {
            self.next_report = if self.next_report < 1_000 {
                self.next_report * 10
            } else {
                self.next_report.saturating_add(1_000)
            };
        }
        Some(DeviceEvent::Surplus { total: self.total })
    }

    /// Surplus messages counted so far.
    pub fn total(&self) -> u64 {
        self.total
    }
}

/// Fault code of the device's own force watchdog (voxhap protocol): it does not latch.
pub const FAULT_WATCHDOG_EXPIRED: u8 = 0;

/// A human name for a voxhap protocol fault code.
pub fn fault_name(code: u8) -> &'static str {
    match code {
        0 => "device watchdog expired",
        1 => "emergency stop",
        2 => "over-temperature",
        3 => "over-current",
        4 => "encoder fault",
        5 => "amplifier fault",
        6 => "supply voltage fault",
        7 => "internal fault",
        8 => "motor stall",
        9 => "stability ceiling reached",
        _ => "unknown fault",
    }
}

/// A human name for a voxhap protocol reject reason.
pub fn reject_reason_name(reason: u8) -> &'static str {
    match reason {
        1 => "no session",
        2 => "version mismatch",
        3 => "device faulted",
        4 => "invalid argument",
        _ => "unknown reason",
    }
}

/// Message type byte of Enable in the voxhap protocol (for recognising a refused Enable).
pub const MESSAGE_TYPE_ENABLE: u8 = 0x02;
/// Reject reason: no session (the host must say Hello again).
pub const REJECT_NO_SESSION: u8 = 1;
/// Reject reason: the device is faulted.
pub const REJECT_FAULTED: u8 = 3;

#[cfg(test)]
mod tests {
    use super::{DeviceEvent, SurplusCount};

    #[test]
    fn surplus_is_reported_at_1_10_100_1000_then_every_1000() {
        let mut count = SurplusCount::default();
        let mut reported = Vec::new();
        for _ in 0..3_500 {
            if let Some(DeviceEvent::Surplus { total }) = count.add(1) {
                reported.push(total);
            }
        }
        assert_eq!(reported, [1, 10, 100, 1_000, 2_000, 3_000]);
        assert_eq!(count.total(), 3_500);
        // A burst crossing several thresholds is one report.
        let mut count = SurplusCount::default();
        assert_eq!(count.add(0), None);
        assert_eq!(count.add(150), Some(DeviceEvent::Surplus { total: 150 }));
        assert_eq!(count.add(500), None);
        assert_eq!(count.add(400), Some(DeviceEvent::Surplus { total: 1_050 }));
    }
}
