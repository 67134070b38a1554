//! The host's safety pipeline, "out" half: every force passes through it before any driver (docs/safety.md).
//! The "in" half (position and velocity plausibility) is `device::plausibility`; the supervisor runs both, and
//! decides from the device's reported status whether the device may receive force at all.
//!
//! Where it sits: on the servo thread, between the solver's coupling force and `write_force`. Per tick
//! ([`SafetyPipeline::process`]) it applies, in order:
//!
//! 1. **Finite check.** A force with a NaN or infinite component becomes zero (counted, flagged).
//! 2. **Clamp.** A force longer than `max_force_n` is scaled to that length, keeping its direction:
//!    `f' = f · max / |f|`.
//! 3. **Host watchdog.** If more than `watchdog_timeout_us` passed since the previous tick, the servo loop
//!    stalled: this tick outputs zero and engagement starts over (the device's own watchdog has usually dropped
//!    the force already; the host must not resume a stale force at full strength either).
//! 4. **Engagement.** After enable (and after a stall, a device watchdog trip or a reconnect) the output stays
//!    zero until the rendered force has been small (`|f| <= engage_threshold_n`) for `engage_ticks` ticks in a
//!    row, each computed from a fresh, plausible device sample (a tick with no valid sample renders zero, which
//!    would look small, so it does not count), then ramps in linearly over `ramp_time_us`:
//!    `f_out = f · min(1, (t - t_engage) / ramp_time)`. While it waits, the flag says why.
//! 5. **Slew limit.** The magnitude of the output may rise by at most `slew_n_per_ms · period` per tick
//!    (0.5 N per ms by default): `|f_out| <= |f_prev| + slew · T`, direction kept. Falls are never limited:
//!    dropping force is always safe.
//! 6. **Off.** While the device is disconnected, not enabled or faulted, the output is zero.
//!
//! The time source is passed in (microseconds from the servo loop's `Clock`); nothing here reads a clock,
//! allocates, locks or does I/O.

use glam::DVec3;

/// Settings of the safety pipeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyConfig {
    /// Largest force sent to the device (N). Usually the device's own maximum.
    pub max_force_n: f64,
    /// Time over which forces ramp in after engagement (µs); 0 engages at once.
    pub ramp_time_us: u64,
    /// Forces engage only once the rendered force is at most this long (N).
    pub engage_threshold_n: f64,
    /// Ticks in a row the rendered force must be small for before forces engage.
    pub engage_ticks: u32,
    /// A gap between ticks longer than this (µs) counts as a stalled loop.
    pub watchdog_timeout_us: u64,
    /// Fastest rise of the output's magnitude (N per ms).
    pub slew_n_per_ms: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            max_force_n: 3.0,
            ramp_time_us: 500_000,
            engage_threshold_n: 1.0,
            engage_ticks: 10,
            watchdog_timeout_us: 20_000,
            slew_n_per_ms: 0.5,
        }
    }
}

/// The stiffness a device is assumed to render stably at 1 kHz when it states none (N/m).
pub const DEFAULT_MAX_STIFFNESS_N_PER_M: f64 = 1000.0;

/// Coupling stiffness and damping caps for one device at one servo rate (README "Safety").
///
/// A device declares the largest stiffness `K₁` it renders stably at 1 kHz (`T₀` = 1 ms). Colgate and
/// Schenkel's passivity condition for a sampled virtual wall of stiffness `K` and damping `B` on a device with
/// physical damping `b` is `b > K T / 2 + |B|`. Reading the declaration through it gives the device's damping:
/// `b ≥ K₁ T₀ / 2`. At servo period `T` the host therefore caps
///
/// - the stiffness at `K_max = K₁ · min(1, T₀ / T)` (never above the declaration, lower at slower rates), and
/// - the damping at `B_max(K) = max(0, K₁ T₀ / 2 − K T / 2)`, what passivity leaves after the spring.
///
/// A device that states no stiffness (0) is treated as `K₁` = [`DEFAULT_MAX_STIFFNESS_N_PER_M`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CouplingCaps {
    /// Largest coupling stiffness at this rate (N/m).
    pub max_stiffness_n_per_m: f64,
    /// The device damping implied by its declaration, `K₁ T₀ / 2` (N s/m).
    pub device_damping_n_s_per_m: f64,
    /// Servo period (s).
    pub period_s: f64,
    /// A further damping limit (N s/m; a device profile's, in scene units); infinite when none.
    pub damping_limit_n_s_per_m: f64,
}

impl CouplingCaps {
    /// Caps for a device declaring `max_stiffness_at_1khz_n_per_m`, at servo period `period_s`.
    pub fn new(max_stiffness_at_1khz_n_per_m: f64, period_s: f64) -> CouplingCaps {
        let declared =
            if max_stiffness_at_1khz_n_per_m.is_finite() && max_stiffness_at_1khz_n_per_m > 0.0 {
                max_stiffness_at_1khz_n_per_m
            } else {
                DEFAULT_MAX_STIFFNESS_N_PER_M
            };
        let period_s = if period_s.is_finite() && period_s > 0.0 {
            period_s
        } else {
            1e-3
        };
        CouplingCaps {
            max_stiffness_n_per_m: declared * (1e-3 / period_s).min(1.0),
            device_damping_n_s_per_m: declared * 1e-3 / 2.0,
            period_s,
            damping_limit_n_s_per_m: f64::INFINITY,
        }
    }

    /// These caps with the damping further limited to `limit_n_s_per_m` where one is given (finite, >= 0).
    pub fn with_damping_limit(mut self, limit_n_s_per_m: Option<f64>) -> CouplingCaps {
        if let Some(limit) = limit_n_s_per_m.filter(|l| l.is_finite() && *l >= 0.0) {
            self.damping_limit_n_s_per_m = limit;
        }
        self
    }

    /// The largest damping passivity allows with stiffness `stiffness_n_per_m` (N s/m).
    pub fn max_damping_n_s_per_m(&self, stiffness_n_per_m: f64) -> f64 {
        (self.device_damping_n_s_per_m - stiffness_n_per_m * self.period_s / 2.0)
            .max(0.0)
            .min(self.damping_limit_n_s_per_m)
    }

    /// `(stiffness, damping)` capped.
    pub fn cap(&self, stiffness_n_per_m: f64, damping_n_s_per_m: f64) -> (f64, f64) {
        let k = stiffness_n_per_m.min(self.max_stiffness_n_per_m);
        (k, damping_n_s_per_m.min(self.max_damping_n_s_per_m(k)))
    }
}

/// A setting that cannot be used: its name, its value and what it must be (the supervisor's error says which
/// stage's settings it belongs to).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{name} = {value} must be {requirement}")]
pub struct SettingError {
    /// Setting name.
    pub name: &'static str,
    /// Offending value.
    pub value: f64,
    /// What it must be.
    pub requirement: &'static str,
}

impl SettingError {
    /// `Ok` when `holds`, else the error for `name = value`.
    pub fn require(
        holds: bool,
        name: &'static str,
        value: f64,
        requirement: &'static str,
    ) -> Result<(), SettingError> {
        if holds {
            Ok(())
        } else {
            Err(SettingError {
                name,
                value,
                requirement,
            })
        }
    }

    /// Checks that `value` is finite and > 0.
    pub fn positive(name: &'static str, value: f64) -> Result<(), SettingError> {
        Self::require(
            value.is_finite() && value > 0.0,
            name,
            value,
            "finite and > 0",
        )
    }

    /// Checks that `value` is finite and >= 0.
    pub fn non_negative(name: &'static str, value: f64) -> Result<(), SettingError> {
        Self::require(
            value.is_finite() && value >= 0.0,
            name,
            value,
            "finite and >= 0",
        )
    }
}

impl SafetyConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SettingError> {
        SettingError::non_negative("max_force_n", self.max_force_n)?;
        SettingError::non_negative("engage_threshold_n", self.engage_threshold_n)?;
        SettingError::positive("slew_n_per_ms", self.slew_n_per_ms)?;
        let watchdog_us = self.watchdog_timeout_us;
        SettingError::require(watchdog_us != 0, "watchdog_timeout_us", 0.0, "> 0")
    }
}

/// What the pipeline did to one force: a bit set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SafetyFlags(pub u32);

impl SafetyFlags {
    /// A non-finite force was replaced by zero.
    pub const NON_FINITE: SafetyFlags = SafetyFlags(1);
    /// The force was scaled down to the maximum.
    pub const CLAMPED: SafetyFlags = SafetyFlags(1 << 1);
    /// Held at zero until the rendered force is small.
    pub const WAITING_TO_ENGAGE: SafetyFlags = SafetyFlags(1 << 2);
    /// Scaled down while ramping in.
    pub const RAMPING: SafetyFlags = SafetyFlags(1 << 3);
    /// The host watchdog fired on this tick (the loop stalled).
    pub const WATCHDOG: SafetyFlags = SafetyFlags(1 << 4);
    /// Zero because the device is disabled or disconnected.
    pub const OUTPUT_OFF: SafetyFlags = SafetyFlags(1 << 5);
    /// The output's rise was limited by the slew rate.
    pub const SLEW_LIMITED: SafetyFlags = SafetyFlags(1 << 6);
    /// Zero because the device is connected but not accepting force (starting, recovering from its
    /// watchdog, faulted, or it refused Enable).
    pub const DEVICE_NOT_ENABLED: SafetyFlags = SafetyFlags(1 << 7);
    /// Zero because no fresh device sample arrived for several periods.
    pub const STALE_STATE: SafetyFlags = SafetyFlags(1 << 8);
    /// The device's position this tick was implausible and the last accepted one was held.
    pub const POSITION_REJECTED: SafetyFlags = SafetyFlags(1 << 9);
    /// The device's reported velocity was implausible and the estimate was used.
    pub const VELOCITY_REPLACED: SafetyFlags = SafetyFlags(1 << 10);
    /// A fault that needs a person is active on the device.
    pub const DEVICE_FAULTED: SafetyFlags = SafetyFlags(1 << 11);
    /// The velocity used is the host's estimate from positions (the device reports none).
    pub const VELOCITY_ESTIMATED: SafetyFlags = SafetyFlags(1 << 12);

    /// True if every bit of `other` is set.
    pub fn contains(self, other: SafetyFlags) -> bool {
        self.0 & other.0 == other.0
    }

    /// True if the output differs from the (finite, clamped) input because of engagement, watchdog or state.
    pub fn limited(self) -> bool {
        self.0
            & (Self::WAITING_TO_ENGAGE.0
                | Self::RAMPING.0
                | Self::WATCHDOG.0
                | Self::OUTPUT_OFF.0
                | Self::SLEW_LIMITED.0
                | Self::DEVICE_NOT_ENABLED.0
                | Self::STALE_STATE.0)
            != 0
    }
}

impl std::ops::BitOrAssign for SafetyFlags {
    fn bitor_assign(&mut self, other: SafetyFlags) {
        self.0 |= other.0;
    }
}

/// The force to send, and what was done to it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafeForce {
    /// Force for the driver (N); always finite and at most `max_force_n` long.
    pub force_n: DVec3,
    /// What the pipeline did.
    pub flags: SafetyFlags,
}

/// Counters of the safety pipeline.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SafetyCounters {
    /// Non-finite forces replaced by zero.
    pub non_finite: u64,
    /// Forces clamped to the maximum.
    pub clamped: u64,
    /// Host watchdog trips (stalled loop).
    pub watchdog_trips: u64,
    /// Disconnects reported.
    pub disconnects: u64,
    /// Ticks whose rise was slew-limited.
    pub slew_limited: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Engagement {
    Off,
    WaitingForSmallForce { small_ticks: u32 },
    Ramping { since_us: u64 },
    Engaged,
}

/// Where the output stands, for people: why forces are not (fully) on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EngagementState {
    /// Output off (device not enabled or gone).
    Off,
    /// Waiting for the rendered force to be small.
    WaitingToEngage,
    /// Ramping in.
    Ramping,
    /// Forces pass at full strength.
    Engaged,
}

/// The safety pipeline's state. Create one per device; call [`SafetyPipeline::enable`] when the device is
/// enabled and [`SafetyPipeline::process`] every tick.
#[derive(Debug, Clone)]
pub struct SafetyPipeline {
    config: SafetyConfig,
    engagement: Engagement,
    last_tick_us: Option<u64>,
    counters: SafetyCounters,
    /// Largest rise of the output's magnitude in one tick (N): the slew rate times the servo period.
    max_rise_n: f64,
    /// The output of the previous tick (zero while off).
    last_output_n: DVec3,
}

/// The servo period assumed until [`SafetyPipeline::set_period_us`] is called (µs).
const DEFAULT_PERIOD_US: u64 = 1_000;

impl SafetyPipeline {
    /// A pipeline with output off until enabled.
    pub fn new(config: SafetyConfig) -> Result<SafetyPipeline, SettingError> {
        config.validate()?;
        Ok(SafetyPipeline {
            config,
            engagement: Engagement::Off,
            last_tick_us: None,
            counters: SafetyCounters::default(),
            max_rise_n: config.slew_n_per_ms * DEFAULT_PERIOD_US as f64 * 1e-3,
            last_output_n: DVec3::ZERO,
        })
    }

    /// The servo period (µs), which turns the slew rate into a largest rise per tick.
    pub fn set_period_us(&mut self, period_us: u64) {
        self.max_rise_n = self.config.slew_n_per_ms * period_us.max(1) as f64 * 1e-3;
    }

    /// Where engagement stands.
    pub fn engagement(&self) -> EngagementState {
        match self.engagement {
            Engagement::Off => EngagementState::Off,
            Engagement::WaitingForSmallForce { .. } => EngagementState::WaitingToEngage,
            Engagement::Ramping { .. } => EngagementState::Ramping,
            Engagement::Engaged => EngagementState::Engaged,
        }
    }

    /// Records a tick on which the output was forced to zero outside the pipeline (device not accepting
    /// force), so the slew limit starts from zero again.
    pub fn note_zero_output(&mut self) {
        self.last_output_n = DVec3::ZERO;
    }

    /// The settings.
    pub fn config(&self) -> &SafetyConfig {
        &self.config
    }

    /// Counters.
    pub fn counters(&self) -> SafetyCounters {
        self.counters
    }

    /// Lowers (or raises) the force limit, for example to the maximum a device reported when it opened.
    /// A non-finite or negative value is ignored.
    pub fn set_max_force_n(&mut self, max_force_n: f64) {
        if max_force_n.is_finite() && max_force_n >= 0.0 {
            self.config.max_force_n = max_force_n;
        }
    }

    /// True once forces pass at full strength.
    pub fn is_engaged(&self) -> bool {
        self.engagement == Engagement::Engaged
    }

    /// The device was enabled at `now_us`: wait for a small force, then ramp in.
    pub fn enable(&mut self, now_us: u64) {
        self.engagement = Engagement::WaitingForSmallForce { small_ticks: 0 };
        self.last_tick_us = Some(now_us);
        self.last_output_n = DVec3::ZERO;
    }

    /// The device was disabled: output off.
    pub fn disable(&mut self) {
        self.engagement = Engagement::Off;
        self.last_tick_us = None;
        self.last_output_n = DVec3::ZERO;
    }

    /// The device disconnected: output off, counted. Enable again after the reconnect.
    pub fn disconnect(&mut self) {
        self.counters.disconnects += 1;
        self.disable();
    }

    /// True if the loop has not ticked for longer than the watchdog timeout (for a monitor outside the loop).
    pub fn stalled(&self, now_us: u64) -> bool {
        self.last_tick_us
            .is_some_and(|last| now_us.saturating_sub(last) > self.config.watchdog_timeout_us)
    }

    /// Makes `force_n`, rendered at `now_us`, safe to send. `valid` says the force was computed from a fresh,
    /// plausible device sample; only valid small forces let the output engage.
    pub fn process(&mut self, force_n: DVec3, now_us: u64, valid: bool) -> SafeForce {
        let mut flags = SafetyFlags::default();
        let mut force = if force_n.is_finite() {
            force_n
        } else {
            self.counters.non_finite += 1;
            flags |= SafetyFlags::NON_FINITE;
            DVec3::ZERO
        };
        let length_n = force.length();
        if length_n > self.config.max_force_n {
            self.counters.clamped += 1;
            flags |= SafetyFlags::CLAMPED;
            force *= self.config.max_force_n / length_n;
        }

        let stalled = self.stalled(now_us);
        if self.engagement != Engagement::Off {
            self.last_tick_us = Some(now_us);
        }
        if stalled {
            self.counters.watchdog_trips += 1;
            self.engagement = Engagement::WaitingForSmallForce { small_ticks: 0 };
            flags |= SafetyFlags::WATCHDOG;
            self.last_output_n = DVec3::ZERO;
            return SafeForce {
                force_n: DVec3::ZERO,
                flags,
            };
        }

        let scale = match self.engagement {
            Engagement::Off => {
                flags |= SafetyFlags::OUTPUT_OFF;
                0.0
            }
            Engagement::WaitingForSmallForce { small_ticks } => {
                let small = valid && force.length() <= self.config.engage_threshold_n;
                let small_ticks = if small { small_ticks + 1 } else { 0 };
                if small_ticks >= self.config.engage_ticks.max(1) {
                    self.engagement = Engagement::Ramping { since_us: now_us };
                    self.ramp_scale(now_us, now_us, &mut flags)
                } else {
                    self.engagement = Engagement::WaitingForSmallForce { small_ticks };
                    flags |= SafetyFlags::WAITING_TO_ENGAGE;
                    0.0
                }
            }
            Engagement::Ramping { since_us } => self.ramp_scale(since_us, now_us, &mut flags),
            Engagement::Engaged => 1.0,
        };
        let mut output = force * scale;
        let allowed_n = self.last_output_n.length() + self.max_rise_n;
        let output_n = output.length();
        if output_n > allowed_n {
            output *= allowed_n / output_n;
            flags |= SafetyFlags::SLEW_LIMITED;
            self.counters.slew_limited += 1;
        }
        self.last_output_n = output;
        SafeForce {
            force_n: output,
            flags,
        }
    }

    fn ramp_scale(&mut self, since_us: u64, now_us: u64, flags: &mut SafetyFlags) -> f64 {
        let elapsed_us = now_us.saturating_sub(since_us);
        if elapsed_us >= self.config.ramp_time_us {
            self.engagement = Engagement::Engaged;
            1.0
        } else {
            *flags |= SafetyFlags::RAMPING;
            elapsed_us as f64 / self.config.ramp_time_us as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn config() -> SafetyConfig {
        SafetyConfig {
            max_force_n: 2.0,
            ramp_time_us: 1_000,
            engage_threshold_n: 0.1,
            engage_ticks: 1,
            watchdog_timeout_us: 5_000,
            // Fast enough not to interfere, except in the slew tests.
            slew_n_per_ms: 1_000.0,
        }
    }

    fn engaged(now_us: u64) -> SafetyPipeline {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        pipeline.enable(now_us);
        pipeline.process(DVec3::ZERO, now_us, true);
        pipeline.process(DVec3::ZERO, now_us + 1_000, true);
        assert!(pipeline.is_engaged());
        pipeline
    }

    #[test]
    fn output_is_zero_until_enabled() {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        let out = pipeline.process(DVec3::X, 0, true);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::OUTPUT_OFF));
    }

    #[test]
    fn non_finite_forces_become_zero() {
        let mut pipeline = engaged(0);
        let out = pipeline.process(DVec3::new(f64::NAN, 1.0, 0.0), 1_500, true);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::NON_FINITE));
        assert_eq!(pipeline.counters().non_finite, 1);
    }

    #[test]
    fn clamping_keeps_the_direction() {
        let mut pipeline = engaged(0);
        let out = pipeline.process(DVec3::new(3.0, 4.0, 0.0), 1_500, true);
        assert!((out.force_n.length() - 2.0).abs() < 1e-12);
        assert!((out.force_n.normalize() - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-12);
        assert!(out.flags.contains(SafetyFlags::CLAMPED));
    }

    #[test]
    fn engages_only_once_the_force_is_small_then_ramps_linearly() {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        pipeline.enable(0);
        let big = DVec3::new(1.0, 0.0, 0.0);
        let out = pipeline.process(big, 100, true);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::WAITING_TO_ENGAGE));
        // Small force at t = 200 us: engagement starts, scale 0.
        pipeline.process(DVec3::new(0.05, 0.0, 0.0), 200, true);
        let out = pipeline.process(big, 450, true);
        assert!((out.force_n.x - 0.25).abs() < 1e-12, "{:?}", out.force_n);
        assert!(out.flags.contains(SafetyFlags::RAMPING));
        let out = pipeline.process(big, 1_200, true);
        assert_eq!(out.force_n, big);
        assert!(pipeline.is_engaged());
    }

    #[test]
    fn a_stalled_loop_zeroes_the_output_and_ramps_in_again() {
        let mut pipeline = engaged(0);
        let force = DVec3::new(0.0, 1.0, 0.0);
        assert_eq!(pipeline.process(force, 2_000, true).force_n, force);
        assert!(pipeline.stalled(8_000));
        let out = pipeline.process(force, 8_000, true);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::WATCHDOG));
        assert_eq!(pipeline.counters().watchdog_trips, 1);
        // The big force is still asked for: held at zero until it is small.
        assert_eq!(pipeline.process(force, 8_500, true).force_n, DVec3::ZERO);
    }

    #[test]
    fn disconnect_turns_the_output_off() {
        let mut pipeline = engaged(0);
        pipeline.disconnect();
        assert_eq!(pipeline.process(DVec3::X, 1_500, true).force_n, DVec3::ZERO);
        assert_eq!(pipeline.counters().disconnects, 1);
    }

    #[test]
    fn invalid_configuration_is_refused() {
        let bad = SafetyConfig {
            max_force_n: f64::NAN,
            ..config()
        };
        assert_eq!(SafetyPipeline::new(bad).unwrap_err().name, "max_force_n");
    }

    #[test]
    fn the_rise_of_the_output_is_slew_limited_and_falls_are_not() {
        let mut pipeline = SafetyPipeline::new(SafetyConfig {
            slew_n_per_ms: 0.5,
            ..config()
        })
        .unwrap();
        pipeline.set_period_us(1_000);
        pipeline.enable(0);
        pipeline.process(DVec3::ZERO, 0, true);
        pipeline.process(DVec3::ZERO, 1_000, true);
        assert!(pipeline.is_engaged());
        let step = DVec3::new(2.0, 0.0, 0.0);
        let out = pipeline.process(step, 2_000, true);
        assert!((out.force_n.x - 0.5).abs() < 1e-12, "{:?}", out.force_n);
        assert!(out.flags.contains(SafetyFlags::SLEW_LIMITED));
        let out = pipeline.process(step, 3_000, true);
        assert!((out.force_n.x - 1.0).abs() < 1e-12);
        // Dropping is immediate.
        let out = pipeline.process(DVec3::ZERO, 4_000, true);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert_eq!(pipeline.counters().slew_limited, 2);
    }

    #[test]
    fn only_valid_small_forces_let_the_output_engage() {
        let mut pipeline = SafetyPipeline::new(SafetyConfig {
            engage_ticks: 3,
            ..config()
        })
        .unwrap();
        pipeline.enable(0);
        // Zero forces from ticks without a device sample do not count.
        for tick in 1..10u64 {
            pipeline.process(DVec3::ZERO, tick * 100, false);
        }
        assert_eq!(pipeline.engagement(), EngagementState::WaitingToEngage);
        // A large valid force resets the count.
        pipeline.process(DVec3::ZERO, 1_000, true);
        pipeline.process(DVec3::ZERO, 1_100, true);
        pipeline.process(DVec3::X, 1_200, true);
        pipeline.process(DVec3::ZERO, 1_300, true);
        pipeline.process(DVec3::ZERO, 1_400, true);
        assert_eq!(pipeline.engagement(), EngagementState::WaitingToEngage);
        pipeline.process(DVec3::ZERO, 1_500, true);
        assert_eq!(pipeline.engagement(), EngagementState::Ramping);
    }

    #[test]
    fn coupling_caps_follow_the_passivity_bound() {
        let caps = CouplingCaps::new(2000.0, 1e-3);
        assert_eq!(caps.max_stiffness_n_per_m, 2000.0);
        // b = 2000 * 1 ms / 2 = 1 N s/m; at K = 1000 the spring takes 0.5 of it.
        assert!((caps.max_damping_n_s_per_m(1000.0) - 0.5).abs() < 1e-12);
        assert_eq!(caps.cap(1e7, 1e6), (2000.0, 0.0));
        // Slower loops get less stiffness; faster ones never more than declared.
        assert_eq!(
            CouplingCaps::new(2000.0, 2e-3).max_stiffness_n_per_m,
            1000.0
        );
        assert_eq!(
            CouplingCaps::new(2000.0, 1e-4).max_stiffness_n_per_m,
            2000.0
        );
        // A device that states nothing gets the default.
        assert_eq!(
            CouplingCaps::new(0.0, 1e-3).max_stiffness_n_per_m,
            DEFAULT_MAX_STIFFNESS_N_PER_M
        );
    }

    proptest! {
        #[test]
        fn output_is_always_finite_and_bounded(
            xs in proptest::collection::vec((any::<f64>(), any::<f64>(), any::<f64>(), 0u64..3_000), 1..64)
        ) {
            let mut pipeline = SafetyPipeline::new(config()).unwrap();
            pipeline.enable(0);
            let mut now_us = 0;
            for (x, y, z, dt) in xs {
                now_us += dt;
                let out = pipeline.process(DVec3::new(x, y, z), now_us, true);
                prop_assert!(out.force_n.is_finite());
                prop_assert!(out.force_n.length() <= 2.0 + 1e-9);
            }
        }
    }
}
