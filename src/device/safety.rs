//! The host's safety pipeline: every force passes through it before any driver (DESIGN.md section 6).
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
//! 4. **Engagement.** After enable (and after a stall or reconnect) the output stays zero until the rendered force
//!    is small (`|f| <= engage_threshold_n`, so the user is not kicked by a force that built up while disabled),
//!    then ramps in linearly over `ramp_time_us`: `f_out = f · min(1, (t - t_engage) / ramp_time)`.
//! 5. **Disconnect.** While the device is disconnected or disabled the output is zero.
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
    /// A gap between ticks longer than this (µs) counts as a stalled loop.
    pub watchdog_timeout_us: u64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            max_force_n: 3.0,
            ramp_time_us: 500_000,
            engage_threshold_n: 0.1,
            watchdog_timeout_us: 20_000,
        }
    }
}

/// The configuration cannot be used.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("safety setting {name} = {value} must be {requirement}")]
pub struct SafetyConfigError {
    /// Setting name.
    pub name: &'static str,
    /// Offending value.
    pub value: f64,
    /// What it must be.
    pub requirement: &'static str,
}

impl SafetyConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SafetyConfigError> {
        let non_negative = |name, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(())
            } else {
                Err(SafetyConfigError {
                    name,
                    value,
                    requirement: "finite and >= 0",
                })
            }
        };
        non_negative("max_force_n", self.max_force_n)?;
        non_negative("engage_threshold_n", self.engage_threshold_n)?;
        if self.watchdog_timeout_us == 0 {
            return Err(SafetyConfigError {
                name: "watchdog_timeout_us",
                value: 0.0,
                requirement: "> 0",
            });
        }
        Ok(())
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

    /// True if every bit of `other` is set.
    pub fn contains(self, other: SafetyFlags) -> bool {
        self.0 & other.0 == other.0
    }

    /// True if the output differs from the (finite, clamped) input because of engagement, watchdog or state.
    pub fn limited(self) -> bool {
        self.0
            & (Self::WAITING_TO_ENGAGE.0 | Self::RAMPING.0 | Self::WATCHDOG.0 | Self::OUTPUT_OFF.0)
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
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Engagement {
    Off,
    WaitingForSmallForce,
    Ramping { since_us: u64 },
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
}

impl SafetyPipeline {
    /// A pipeline with output off until enabled.
    pub fn new(config: SafetyConfig) -> Result<SafetyPipeline, SafetyConfigError> {
        config.validate()?;
        Ok(SafetyPipeline {
            config,
            engagement: Engagement::Off,
            last_tick_us: None,
            counters: SafetyCounters::default(),
        })
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
        self.engagement = Engagement::WaitingForSmallForce;
        self.last_tick_us = Some(now_us);
    }

    /// The device was disabled: output off.
    pub fn disable(&mut self) {
        self.engagement = Engagement::Off;
        self.last_tick_us = None;
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

    /// Makes `force_n`, rendered at `now_us`, safe to send.
    pub fn process(&mut self, force_n: DVec3, now_us: u64) -> SafeForce {
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
            self.engagement = Engagement::WaitingForSmallForce;
            flags |= SafetyFlags::WATCHDOG;
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
            Engagement::WaitingForSmallForce => {
                if force.length() <= self.config.engage_threshold_n {
                    self.engagement = Engagement::Ramping { since_us: now_us };
                    self.ramp_scale(now_us, now_us, &mut flags)
                } else {
                    flags |= SafetyFlags::WAITING_TO_ENGAGE;
                    0.0
                }
            }
            Engagement::Ramping { since_us } => self.ramp_scale(since_us, now_us, &mut flags),
            Engagement::Engaged => 1.0,
        };
        SafeForce {
            force_n: force * scale,
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
            watchdog_timeout_us: 5_000,
        }
    }

    fn engaged(now_us: u64) -> SafetyPipeline {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        pipeline.enable(now_us);
        pipeline.process(DVec3::ZERO, now_us);
        pipeline.process(DVec3::ZERO, now_us + 1_000);
        assert!(pipeline.is_engaged());
        pipeline
    }

    #[test]
    fn output_is_zero_until_enabled() {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        let out = pipeline.process(DVec3::X, 0);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::OUTPUT_OFF));
    }

    #[test]
    fn non_finite_forces_become_zero() {
        let mut pipeline = engaged(0);
        let out = pipeline.process(DVec3::new(f64::NAN, 1.0, 0.0), 1_500);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::NON_FINITE));
        assert_eq!(pipeline.counters().non_finite, 1);
    }

    #[test]
    fn clamping_keeps_the_direction() {
        let mut pipeline = engaged(0);
        let out = pipeline.process(DVec3::new(3.0, 4.0, 0.0), 1_500);
        assert!((out.force_n.length() - 2.0).abs() < 1e-12);
        assert!((out.force_n.normalize() - DVec3::new(0.6, 0.8, 0.0)).length() < 1e-12);
        assert!(out.flags.contains(SafetyFlags::CLAMPED));
    }

    #[test]
    fn engages_only_once_the_force_is_small_then_ramps_linearly() {
        let mut pipeline = SafetyPipeline::new(config()).unwrap();
        pipeline.enable(0);
        let big = DVec3::new(1.0, 0.0, 0.0);
        let out = pipeline.process(big, 100);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::WAITING_TO_ENGAGE));
        // Small force at t = 200 us: engagement starts, scale 0.
        pipeline.process(DVec3::new(0.05, 0.0, 0.0), 200);
        let out = pipeline.process(big, 450);
        assert!((out.force_n.x - 0.25).abs() < 1e-12, "{:?}", out.force_n);
        assert!(out.flags.contains(SafetyFlags::RAMPING));
        let out = pipeline.process(big, 1_200);
        assert_eq!(out.force_n, big);
        assert!(pipeline.is_engaged());
    }

    #[test]
    fn a_stalled_loop_zeroes_the_output_and_ramps_in_again() {
        let mut pipeline = engaged(0);
        let force = DVec3::new(0.0, 1.0, 0.0);
        assert_eq!(pipeline.process(force, 2_000).force_n, force);
        assert!(pipeline.stalled(8_000));
        let out = pipeline.process(force, 8_000);
        assert_eq!(out.force_n, DVec3::ZERO);
        assert!(out.flags.contains(SafetyFlags::WATCHDOG));
        assert_eq!(pipeline.counters().watchdog_trips, 1);
        // The big force is still asked for: held at zero until it is small.
        assert_eq!(pipeline.process(force, 8_500).force_n, DVec3::ZERO);
    }

    #[test]
    fn disconnect_turns_the_output_off() {
        let mut pipeline = engaged(0);
        pipeline.disconnect();
        assert_eq!(pipeline.process(DVec3::X, 1_500).force_n, DVec3::ZERO);
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
                let out = pipeline.process(DVec3::new(x, y, z), now_us);
                prop_assert!(out.force_n.is_finite());
                prop_assert!(out.force_n.length() <= 2.0 + 1e-9);
            }
        }
    }
}
