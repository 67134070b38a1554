//! The status words every layer shares: the per-tick flag bits of the trace format ([`flags`]) and where
//! the force output stands ([`OutputState`]). The servo loop sets them, the device layer computes the output
//! state, the trace format names them; they live here, below all of those, so none imports another for them.
//! Bit numbers and codes are part of the trace format: never renumber one.

/// The flag bits of one tick (`flags` in a snapshot and a trace sample). Their names and meanings as
/// written into traces are `voxhap_record::FLAG_DOCS`.
pub mod flags {
    /// Flag bit: the solver stopped on its budget (sweeps or time) before its certificate met the tolerance.
    pub const FLAG_SOLVER_BUDGET_HIT: u32 = 1 << 0;
    /// Flag bit: the safety pipeline clamped the force to the device maximum (direction kept).
    pub const FLAG_FORCE_CLAMPED: u32 = 1 << 1;
    /// Flag bit: the probe was at or beyond the device's workspace limit (the simulated arm's wall pushed).
    pub const FLAG_WORKSPACE_LIMIT: u32 = 1 << 2;
    /// Flag bit: this tick started late; the schedule skipped the missed ticks (tick numbers jump).
    pub const FLAG_OVERRUN: u32 = 1 << 3;
    /// Flag bit: a non-finite value (probe position or force) was replaced by zero this tick.
    pub const FLAG_NON_FINITE_REPLACED: u32 = 1 << 4;
    /// Flag bit: the recorder ring was full and samples before this one were lost (tick numbers jump).
    pub const FLAG_SAMPLES_DROPPED: u32 = 1 << 5;
    /// Flag bit: the force output was ramping in (enable) or held at zero (watchdog, disconnect).
    pub const FLAG_FORCE_LIMITED_BY_SAFETY: u32 = 1 << 6;

    /// Flag bit: the tick's compute (modes and solve) took longer than its budget, so the last safe force was
    /// sent again instead of this tick's.
    pub const FLAG_COMPUTE_OVER_BUDGET: u32 = 1 << 7;
    /// Flag bit: the device was not accepting force (starting, recovering from its watchdog, faulted, or it
    /// refused Enable): zero was commanded, whatever the scene rendered.
    pub const FLAG_DEVICE_NOT_ENABLED: u32 = 1 << 8;
    /// Flag bit: the device was disconnected this tick (the force went nowhere; the probe is the last known).
    pub const FLAG_DEVICE_DISCONNECTED: u32 = 1 << 9;
    /// Flag bit: the probe velocity is the host's estimate from positions, not the device's report.
    pub const FLAG_VELOCITY_ESTIMATED: u32 = 1 << 10;
    /// Flag bit: the sample broke a trace rule (a non-finite or negative value, a mode count that differs
    /// from the trace's); it was recorded as it came (NaN stays NaN) so the trace goes on.
    pub const FLAG_INVALID_VALUES: u32 = 1 << 11;
    /// Flag bit: the device's position was implausible (a jump beyond its maximum speed, outside its workspace,
    /// not finite); the last accepted one was used.
    pub const FLAG_POSITION_REJECTED: u32 = 1 << 12;
    /// Flag bit: the device's reported velocity disagreed with its positions (or exceeded its maximum speed);
    /// the estimate from positions was used.
    pub const FLAG_VELOCITY_REPLACED: u32 = 1 << 13;
    /// Flag bit: the force's rise was limited by the slew rate.
    pub const FLAG_FORCE_SLEW_LIMITED: u32 = 1 << 14;
    /// Flag bit: no fresh device state for several periods; zero was commanded.
    pub const FLAG_STALE_STATE: u32 = 1 << 15;
    /// Flag bit: a fault that needs a person is active on the device.
    pub const FLAG_DEVICE_FAULTED: u32 = 1 << 16;
}

crate::named_enum! {
    /// Where the output stands, for people and traces: why force is or is not reaching the hand.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
    #[serde(rename_all = "snake_case")]
    #[repr(u8)]
    pub enum OutputState {
        /// No device.
        #[default]
        Disconnected = 0 => "disconnected",
        /// Connected; waiting for the servo loop to run steadily before enabling.
        Starting = 1 => "starting",
        /// Enabled; waiting for the rendered force to be small before engaging.
        WaitingToEngage = 2 => "waiting_to_engage",
        /// Forces ramping in.
        RampingIn = 3 => "ramping_in",
        /// Forces at full strength.
        Engaged = 4 => "engaged",
        /// The device dropped out (its watchdog, a stall): enabling again once the link is healthy.
        Recovering = 5 => "recovering",
        /// A fault that needs a person: waiting for the operator's `clear_fault`.
        Faulted = 6 => "faulted",
        /// The device refused Enable: stays off (check the configuration; `clear_fault` retries).
        EnableRefused = 7 => "enable_refused",
        /// No fresh state for several periods: zero sent.
        StaleState = 8 => "stale_state",
    }
}

impl OutputState {
    /// From its code (unknown codes read as `Disconnected`).
    pub fn from_code(code: u8) -> OutputState {
        OutputState::ALL
            .get(usize::from(code))
            .copied()
            .unwrap_or_default()
    }

    /// What the operator should know.
    pub fn explanation(self) -> &'static str {
        match self {
            OutputState::Disconnected => "no device: reconnecting",
            OutputState::Starting => "connected; enabling once the servo loop runs steadily",
            OutputState::WaitingToEngage => {
                "waiting for the rendered force to be small (move the handle out of the object)"
            }
            OutputState::RampingIn => "forces ramping in",
            OutputState::Engaged => "forces on",
            OutputState::Recovering => {
                "the device dropped out (its watchdog or a stall); enabling again once the link is healthy"
            }
            OutputState::Faulted => {
                "the device reported a fault that needs a person: check the arm, then send clear_fault"
            }
            OutputState::EnableRefused => {
                "the device refused to enable (configuration?); clear_fault retries"
            }
            OutputState::StaleState => "no fresh state from the device: zero force sent",
        }
    }
}
