//! What the late-answer tests share (tests/late_states.rs through the supervisor alone, tests/servo_truth.rs
//! through the servo loop): the script of how a device double answers each read, the ages it keeps, its
//! declaration and the supervisor it runs under.

use glam::DVec3;
use voxhap::device::safety::SafetyConfig;
use voxhap::device::supervisor::{Supervisor, SupervisorConfig};
use voxhap::device::{DeviceError, DeviceInfo, HapticDevice};

/// What the double does on one tick's read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Answer {
    /// A state answering the force of this many ticks ago.
    Aged(u32),
    /// No state in time.
    Late,
}

/// How old the double's information is: the newest state it handed out (counted on while no answer comes;
/// unknown, `u32::MAX`, before the first), and the age of its last answer (what it reports as
/// `state_age_ticks`).
#[derive(Debug, Clone, Copy)]
pub struct Ages {
    pub information: u32,
    pub last: u32,
}

impl Ages {
    pub fn new() -> Self {
        Ages {
            information: u32::MAX,
            last: 0,
        }
    }

    /// One read answered as `answer`: `Ok` for a state (the ages it carries), the driver's timeout for none.
    pub fn read(&mut self, answer: Answer) -> Result<(), DeviceError> {
        match answer {
            Answer::Aged(age) => {
                self.information = age;
                self.last = age;
                Ok(())
            }
            Answer::Late => {
                self.information = self.information.saturating_add(1);
                Err(DeviceError::Timeout {
                    waited_us: 400,
                    waiting_for: "the scripted answer",
                })
            }
        }
    }
}

/// The double's declaration: 2 N, 1000 N/m, a 0.2 m cube, no velocity of its own.
pub fn late_info() -> DeviceInfo {
    DeviceInfo {
        model: "late".into(),
        serial_number: String::new(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        workspace_min_m: DVec3::splat(-0.1),
        workspace_max_m: DVec3::splat(0.1),
        max_force_n: 2.0,
        max_stiffness_n_per_m: 1000.0,
        max_speed_m_per_s: 5.0,
        reports_velocity: false,
        state_rates_hz: Vec::new(),
    }
}

/// The supervisor over `device` (opened once), connected at t = 0: a 10 ms ramp-in, and timeouts that never
/// drop the link (they are part of the script; only the staleness rules are under test).
pub fn late_supervisor<D: HapticDevice + 'static>(
    device: D,
) -> Supervisor<D, impl FnMut() -> Result<D, DeviceError>> {
    let config = SupervisorConfig {
        safety: SafetyConfig {
            ramp_time_us: 10_000,
            ..SafetyConfig::default()
        },
        max_consecutive_errors: 1000,
        link_timeout_us: 1_000_000,
        ..SupervisorConfig::default()
    };
    let mut device = Some(device);
    let mut supervisor = Supervisor::new(config, move || {
        device.take().ok_or(DeviceError::Open {
            path: "late".into(),
            message: "opened once".into(),
        })
    })
    .unwrap();
    supervisor.connect(0).unwrap();
    supervisor
}
