//! Input plausibility: the "in" half of the safety pipeline (docs/safety.md), applied by the supervisor to
//! every sample a device reports, for every driver, before the servo loop uses it.
//!
//! Where it sits: on the servo thread, between a driver's `read_state` and the tick that renders the next force.
//! Per sample ([`InputGuard::check`]):
//!
//! 1. **Position.** A position that is not finite, lies outside the device's workspace box widened by
//!    `workspace_margin_m`, or is further from the last accepted one than the device's maximum speed allows in
//!    the time between them (`|p - p_last| > max_speed · Δt + position_noise_m`) is rejected: the last accepted
//!    position is held, the sample is flagged and counted. Δt is the longest the handle can have had
//!    ([`SampleTime`]): from the earliest the last accepted sample can have been taken (when the force it
//!    answers was sent; the supervisor keeps those times in [`WriteTimes`]) to the latest this one can have
//!    been (when the driver handed it over), so a sample that came late in its tick, or an earlier one handed
//!    out again, is never refused for the host's own delay.
//!    Δt grows while samples are rejected, so a real fast movement is accepted again as soon as it is
//!    plausible; a run of more than `max_rejected_run` rejections means the link is broken
//!    ([`InputVerdict::link_broken`]) and the supervisor drops it.
//! 2. **Velocity estimate.** Every accepted position updates an estimate: the backward difference
//!    `(p - p_last) / Δt`, smoothed by a first-order low-pass filter (an exponential moving average with
//!    `α = 1 - exp(-2π f_c Δt)`, cutoff `f_c` = `velocity_cutoff_hz`, 50 Hz by default: time constant 3.2 ms,
//!    lag about 3 ms, encoder quantisation noise cut by about 5 at 1 kHz). Δt is the device's own clock where it
//!    reports one, else the host's (between the times the driver handed the two samples over).
//! 3. **Reported velocity.** Drivers without a velocity measurement report zero; the estimate is used instead.
//!    A reported velocity is used only while it is finite, at most the maximum speed, and within
//!    `velocity_tolerance_m_per_s + velocity_tolerance_relative · |v_est|` of the estimate; otherwise the
//!    estimate replaces it and the sample is flagged. (A device that reports 1e30 m/s, or 0.5 m/s while its
//!    positions stand still, would otherwise turn the coupling damping into a force step.)
//!
//! Nothing here allocates, locks, reads a clock or does I/O: times are passed in.

use super::safety::SettingError;
use super::{DeviceInfo, DeviceState};
use glam::DVec3;

/// Settings of the input checks (per device; a device profile may lower the speed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputConfig {
    /// Fastest plausible handle speed (m/s); lowered to the device's own maximum when it opens.
    pub max_speed_m_per_s: f64,
    /// Sensor noise allowed on top of the speed limit in one step (m).
    pub position_noise_m: f64,
    /// How far outside its declared workspace box a position may lie before it is rejected (m).
    pub workspace_margin_m: f64,
    /// Cutoff of the velocity estimate's low-pass filter (Hz).
    pub velocity_cutoff_hz: f64,
    /// Absolute disagreement allowed between a reported velocity and the estimate (m/s).
    pub velocity_tolerance_m_per_s: f64,
    /// Relative disagreement allowed on top, as a fraction of the estimate's magnitude.
    pub velocity_tolerance_relative: f64,
    /// Consecutive rejected positions after which the link counts as broken.
    pub max_rejected_run: u32,
}

impl Default for InputConfig {
    fn default() -> Self {
        InputConfig {
            max_speed_m_per_s: super::info::DEFAULT_MAX_SPEED_M_PER_S,
            position_noise_m: 0.5e-3,
            workspace_margin_m: 0.05,
            velocity_cutoff_hz: 50.0,
            velocity_tolerance_m_per_s: 0.1,
            velocity_tolerance_relative: 0.5,
            max_rejected_run: 10,
        }
    }
}

impl InputConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SettingError> {
        SettingError::positive("max_speed_m_per_s", self.max_speed_m_per_s)?;
        SettingError::positive("velocity_cutoff_hz", self.velocity_cutoff_hz)?;
        SettingError::non_negative("position_noise_m", self.position_noise_m)?;
        SettingError::non_negative("workspace_margin_m", self.workspace_margin_m)?;
        SettingError::non_negative(
            "velocity_tolerance_m_per_s",
            self.velocity_tolerance_m_per_s,
        )?;
        SettingError::non_negative(
            "velocity_tolerance_relative",
            self.velocity_tolerance_relative,
        )?;
        let run = self.max_rejected_run;
        SettingError::require(run != 0, "max_rejected_run", 0.0, ">= 1")
    }
}

/// Counters of the input checks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InputCounters {
    /// Samples whose position was rejected (held at the last accepted one).
    pub positions_rejected: u64,
    /// Samples whose reported velocity was replaced by the estimate.
    pub velocities_replaced: u64,
}

/// What the checks made of one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputVerdict {
    /// The sample to use: the accepted (or held) position and the velocity to render damping with.
    pub state: DeviceState,
    /// The reported position was rejected; `state` holds the last accepted one.
    pub position_rejected: bool,
    /// The reported velocity was replaced by the estimate.
    pub velocity_replaced: bool,
    /// The device reports no velocity; the estimate is used.
    pub velocity_estimated: bool,
    /// More than `max_rejected_run` positions in a row were rejected: drop the link.
    pub link_broken: bool,
    /// False when the position was rejected and there was no accepted one to hold: nothing may be rendered
    /// from this sample.
    pub usable: bool,
}

/// When a sample was taken, as far as the host can tell (host clock, µs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleTime {
    /// The earliest it can have been taken: when the force it answers was sent.
    pub taken_after_us: u64,
    /// The latest: when the driver handed it over.
    pub received_by_us: u64,
}

impl SampleTime {
    /// A sample taken and handed over at `us`.
    pub fn at(us: u64) -> SampleTime {
        SampleTime {
            taken_after_us: us,
            received_by_us: us,
        }
    }
}

/// Forces written whose tick times are kept: a state answering an older one is timed from the link's start.
const WRITE_TIMES: usize = 16;

/// When the forces on this link went out (servo clock, µs): the earliest a state answering one can have been
/// taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct WriteTimes {
    /// The ticks of the last [`WRITE_TIMES`] forces written, the newest at `(writes - 1) % WRITE_TIMES`.
    at_us: [u64; WRITE_TIMES],
    /// Forces written on this link.
    writes: u64,
    /// When this link was attached.
    attached_us: u64,
}

impl WriteTimes {
    pub(crate) fn new(attached_us: u64) -> WriteTimes {
        WriteTimes {
            at_us: [0; WRITE_TIMES],
            writes: 0,
            attached_us,
        }
    }

    /// A force went out on the tick at `now_us`.
    pub(crate) fn wrote(&mut self, now_us: u64) {
        self.at_us[(self.writes % WRITE_TIMES as u64) as usize] = now_us;
        self.writes += 1;
    }

    /// The earliest a state `age_ticks` old can have been taken: the tick that wrote the force it answers, or
    /// the link's start for one older than the forces kept.
    pub(crate) fn taken_after_us(&self, age_ticks: u32) -> u64 {
        let age = u64::from(age_ticks);
        if age < self.writes && age < WRITE_TIMES as u64 {
            self.at_us[((self.writes - 1 - age) % WRITE_TIMES as u64) as usize]
        } else {
            self.attached_us
        }
    }
}

/// The last accepted sample.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Accepted {
    position_m: DVec3,
    time: SampleTime,
    device_us: Option<u64>,
}

/// The input checks' state for one device connection.
#[derive(Debug, Clone)]
pub struct InputGuard {
    config: InputConfig,
    workspace_min_m: DVec3,
    workspace_max_m: DVec3,
    reports_velocity: bool,
    last: Option<Accepted>,
    estimate_m_per_s: DVec3,
    rejected_run: u32,
    counters: InputCounters,
}

impl InputGuard {
    /// Checks for no device yet (no workspace limit until [`InputGuard::attach`]).
    pub fn new(config: InputConfig) -> Result<InputGuard, SettingError> {
        config.validate()?;
        Ok(InputGuard {
            config,
            workspace_min_m: DVec3::splat(f64::NEG_INFINITY),
            workspace_max_m: DVec3::splat(f64::INFINITY),
            reports_velocity: false,
            last: None,
            estimate_m_per_s: DVec3::ZERO,
            rejected_run: 0,
            counters: InputCounters::default(),
        })
    }

    /// The settings in force (the speed limit lowered to the device's).
    pub fn config(&self) -> &InputConfig {
        &self.config
    }

    /// Counters since the guard was made.
    pub fn counters(&self) -> InputCounters {
        self.counters
    }

    /// The current velocity estimate (m/s).
    pub fn estimate_m_per_s(&self) -> DVec3 {
        self.estimate_m_per_s
    }

    /// A (re)connected device: its workspace and speed apply from now, and the history starts over.
    /// Allocation-free.
    pub fn attach(&mut self, info: &DeviceInfo) {
        if info.max_speed_m_per_s.is_finite() && info.max_speed_m_per_s > 0.0 {
            self.config.max_speed_m_per_s =
                self.config.max_speed_m_per_s.min(info.max_speed_m_per_s);
        }
        let box_ok = info.workspace_min_m.is_finite()
            && info.workspace_max_m.is_finite()
            && info.workspace_min_m.cmple(info.workspace_max_m).all()
            && info.workspace_min_m != info.workspace_max_m;
        let margin = DVec3::splat(self.config.workspace_margin_m);
        (self.workspace_min_m, self.workspace_max_m) = if box_ok {
            (info.workspace_min_m - margin, info.workspace_max_m + margin)
        } else {
            (DVec3::splat(f64::NEG_INFINITY), DVec3::splat(f64::INFINITY))
        };
        self.reports_velocity = info.reports_velocity;
        self.reset();
    }

    /// Forgets the history (after a reconnect): the next finite in-workspace position is accepted as is.
    pub fn reset(&mut self) {
        self.last = None;
        self.estimate_m_per_s = DVec3::ZERO;
        self.rejected_run = 0;
    }

    /// Checks one raw sample taken within `time` (host clock). The speed check measures time on the host's
    /// clock (robust to a device clock that restarts, as a replayed trace's does at its loop); the velocity
    /// estimate uses the device's clock while it advances.
    pub fn check(&mut self, raw: DeviceState, time: SampleTime) -> InputVerdict {
        let position = raw.position_m;
        let in_box = position.is_finite()
            && position.cmpge(self.workspace_min_m).all()
            && position.cmple(self.workspace_max_m).all();
        let plausible = in_box
            && match self.last {
                None => true,
                Some(last) => {
                    let dt_us = time.received_by_us.saturating_sub(last.time.taken_after_us);
                    let dt_s = dt_us as f64 * 1e-6;
                    let reach_m =
                        self.config.max_speed_m_per_s * dt_s + self.config.position_noise_m;
                    (position - last.position_m).length() <= reach_m
                }
            };
        let mut verdict = InputVerdict {
            state: raw,
            position_rejected: false,
            velocity_replaced: false,
            velocity_estimated: !self.reports_velocity,
            link_broken: false,
            usable: true,
        };
        if !plausible {
            self.counters.positions_rejected += 1;
            self.rejected_run += 1;
            verdict.position_rejected = true;
            verdict.link_broken = self.rejected_run > self.config.max_rejected_run;
            // Hold the last accepted position; with no history there is nothing to hold, so the sample
            // keeps a finite stand-in and is marked unusable.
            verdict.state.position_m = match self.last {
                Some(last) => last.position_m,
                None => {
                    verdict.usable = false;
                    DVec3::ZERO
                }
            };
            verdict.state.velocity_m_per_s = self.estimate_m_per_s;
            return verdict;
        }
        self.rejected_run = 0;
        if let Some(last) = self.last {
            // The device's clock where it has one and it advanced; otherwise the host's.
            let dt_us = match (raw.device_time_us, last.device_us) {
                (Some(now), Some(then)) if now > then => now - then,
                _ => time.received_by_us.saturating_sub(last.time.received_by_us),
            };
            if dt_us > 0 {
                let dt_s = dt_us as f64 * 1e-6;
                let raw_velocity = (position - last.position_m) / dt_s;
                let alpha = 1.0
                    - (-2.0 * std::f64::consts::PI * self.config.velocity_cutoff_hz * dt_s).exp();
                self.estimate_m_per_s += alpha * (raw_velocity - self.estimate_m_per_s);
            }
        }
        self.last = Some(Accepted {
            position_m: position,
            time,
            device_us: raw.device_time_us,
        });
        let estimate = self.estimate_m_per_s;
        if self.reports_velocity {
            let reported = raw.velocity_m_per_s;
            let allowed = self.config.velocity_tolerance_m_per_s
                + self.config.velocity_tolerance_relative * estimate.length();
            let believable = reported.is_finite()
                && reported.length() <= self.config.max_speed_m_per_s
                && (reported - estimate).length() <= allowed;
            if !believable {
                self.counters.velocities_replaced += 1;
                verdict.velocity_replaced = true;
                verdict.state.velocity_m_per_s = estimate;
            }
        } else {
            verdict.state.velocity_m_per_s = estimate;
        }
        verdict
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(reports_velocity: bool) -> DeviceInfo {
        DeviceInfo {
            reports_velocity,
            ..DeviceInfo::basic("test", DVec3::splat(-0.1), DVec3::splat(0.1))
        }
    }

    fn at(position_m: DVec3, velocity_m_per_s: DVec3) -> DeviceState {
        DeviceState {
            velocity_m_per_s,
            ..DeviceState::at_rest(position_m)
        }
    }

    fn guard(reports_velocity: bool) -> InputGuard {
        let mut guard = InputGuard::new(InputConfig::default()).unwrap();
        guard.attach(&info(reports_velocity));
        guard
    }

    #[test]
    fn a_position_jump_beyond_the_speed_limit_is_held_and_counted() {
        let mut guard = guard(false);
        guard.check(at(DVec3::ZERO, DVec3::ZERO), SampleTime::at(0));
        // 5 cm in 1 ms is 50 m/s: rejected, the last position held.
        let verdict = guard.check(
            at(DVec3::new(0.05, 0.0, 0.0), DVec3::ZERO),
            SampleTime::at(1_000),
        );
        assert!(verdict.position_rejected);
        assert_eq!(verdict.state.position_m, DVec3::ZERO);
        assert_eq!(guard.counters().positions_rejected, 1);
        // 2 mm in 1 ms (2 m/s) is plausible.
        let verdict = guard.check(
            at(DVec3::new(0.002, 0.0, 0.0), DVec3::ZERO),
            SampleTime::at(2_000),
        );
        assert!(!verdict.position_rejected);
    }

    #[test]
    fn the_speed_check_spans_from_the_earliest_the_last_sample_was_taken_to_the_latest_this_one_was(
    ) {
        let mut guard = guard(false);
        // Taken after 1 ms (when its force went out), handed over by 1.3 ms.
        let first = SampleTime {
            taken_after_us: 1_000,
            received_by_us: 1_300,
        };
        guard.check(at(DVec3::ZERO, DVec3::ZERO), first);
        // 6 mm on: 5 m/s allows 5.5 mm in the 1 ms to a sample handed over at 2 ms, 6.5 mm in the 1.2 ms to one
        // handed over at 2.2 ms.
        let six_mm = at(DVec3::new(0.006, 0.0, 0.0), DVec3::ZERO);
        let late = SampleTime {
            taken_after_us: 2_000,
            received_by_us: 2_200,
        };
        assert!(
            guard
                .clone()
                .check(six_mm, SampleTime::at(2_000))
                .position_rejected
        );
        assert!(!guard.check(six_mm, late).position_rejected);
    }

    #[test]
    fn a_long_run_of_rejections_breaks_the_link() {
        let mut guard = guard(false);
        guard.check(at(DVec3::ZERO, DVec3::ZERO), SampleTime::at(0));
        let mut broken_at = None;
        for tick in 1..=20u64 {
            let verdict = guard.check(
                at(DVec3::splat(f64::NAN), DVec3::ZERO),
                SampleTime::at(tick * 1_000),
            );
            assert!(verdict.position_rejected);
            assert!(verdict.state.position_m.is_finite());
            if verdict.link_broken && broken_at.is_none() {
                broken_at = Some(tick);
            }
        }
        assert_eq!(broken_at, Some(11));
    }

    #[test]
    fn positions_outside_the_workspace_are_rejected() {
        let mut guard = guard(false);
        let verdict = guard.check(
            at(DVec3::new(0.5, 0.0, 0.0), DVec3::ZERO),
            SampleTime::at(0),
        );
        assert!(verdict.position_rejected);
    }

    #[test]
    fn the_estimate_follows_a_steady_movement() {
        let mut guard = guard(false);
        let speed = 0.2;
        let mut last = DVec3::ZERO;
        for tick in 0..200u64 {
            let p = DVec3::new(speed * tick as f64 * 1e-3 - 0.05, 0.0, 0.0);
            last = guard
                .check(at(p, DVec3::ZERO), SampleTime::at(tick * 1_000))
                .state
                .velocity_m_per_s;
        }
        assert!((last.x - speed).abs() < 1e-9, "{last:?}");
    }

    #[test]
    fn absurd_or_inconsistent_reported_velocities_are_replaced_by_the_estimate() {
        let mut guard = guard(true);
        for tick in 0..10u64 {
            guard.check(at(DVec3::ZERO, DVec3::ZERO), SampleTime::at(tick * 1_000));
        }
        let verdict = guard.check(
            at(DVec3::ZERO, DVec3::new(1e30, 0.0, 0.0)),
            SampleTime::at(10_000),
        );
        assert!(verdict.velocity_replaced);
        assert_eq!(verdict.state.velocity_m_per_s, DVec3::ZERO);
        let verdict = guard.check(
            at(DVec3::ZERO, DVec3::new(0.5, 0.0, 0.0)),
            SampleTime::at(11_000),
        );
        assert!(verdict.velocity_replaced);
        let verdict = guard.check(
            at(DVec3::ZERO, DVec3::new(0.01, 0.0, 0.0)),
            SampleTime::at(12_000),
        );
        assert!(!verdict.velocity_replaced);
        assert_eq!(verdict.state.velocity_m_per_s.x, 0.01);
        assert_eq!(guard.counters().velocities_replaced, 2);
    }

    #[test]
    fn bad_settings_are_named() {
        let config = InputConfig {
            max_speed_m_per_s: 0.0,
            ..InputConfig::default()
        };
        assert_eq!(
            InputGuard::new(config).unwrap_err().name,
            "max_speed_m_per_s"
        );
    }
}
