//! What a real device adds between the physics and the servo loop: transport latency, position and force
//! quantisation, period jitter and a velocity estimated from quantised positions ([`DeviceEffects`], keys of
//! `[arm]`), and the small fixed-size state that carries them from tick to tick ([`EffectsState`]).
//!
//! Where it sits: [`super::SimArm::step`] queues each rendered force (quantised to `force_resolution_n`) to act
//! `latency_s` after it was sent; it integrates the tick between two sample instants that jitter by up to
//! `period_jitter_s` about the nominal ones; [`super::SimArm::position_m`] reports the position rounded to
//! `position_resolution_m`, and [`super::SimArm::velocity_m_per_s`] the exact velocity or, with
//! `velocity_window_ticks = n`, the difference of the reported positions `n` samples apart over the time between
//! them, as drivers without a velocity sensor do. Everything is allocated when the arm is built; `step` does
//! not allocate.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::preset::ArmPreset;
use super::SimError;

/// Longest accepted `latency_s` (s).
pub const MAX_LATENCY_S: f64 = 0.1;
/// Largest accepted `position_resolution_m` (m).
pub const MAX_POSITION_RESOLUTION_M: f64 = 0.01;
/// Largest accepted `force_resolution_n` (N).
pub const MAX_FORCE_RESOLUTION_N: f64 = 1.0;
/// Most samples a velocity estimate may span.
pub const MAX_VELOCITY_WINDOW_TICKS: u32 = 64;
/// Shortest tick the latency queue is sized for (s): the fastest servo rate a scenario may ask for.
pub const MIN_TICK_S: f64 = 1e-5;

/// The device effects of `[arm]`; every one defaults to off (an ideal device).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DeviceEffects {
    /// The preset the figures came from, if any (super::preset).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preset: Option<ArmPreset>,
    /// Time from a force being sent to the arm feeling it (s), 0 to [`MAX_LATENCY_S`].
    pub latency_s: f64,
    /// Reported positions are rounded to multiples of this on each axis (m); 0 for none.
    pub position_resolution_m: f64,
    /// Applied forces are rounded to multiples of this on each axis (N); 0 for none.
    pub force_resolution_n: f64,
    /// Each sample instant is off its nominal time by up to this, uniformly (s); below half a tick.
    pub period_jitter_s: f64,
    /// Seed of the jitter's generator (the same seed, the same run).
    pub jitter_seed: u32,
    /// 0: report the exact velocity; n >= 1: estimate it from the reported positions n samples apart.
    pub velocity_window_ticks: u32,
}

fn within(name: &'static str, value: f64, max: f64, unit: &'static str) -> Result<(), SimError> {
    if value.is_finite() && (0.0..=max).contains(&value) {
        Ok(())
    } else {
        Err(SimError::OutOfRange {
            name,
            value,
            min: 0.0,
            max,
            min_excluded: false,
            unit,
        })
    }
}

impl DeviceEffects {
    /// Checks every value against its range; the error names the key.
    pub fn validate(&self) -> Result<(), SimError> {
        within("arm.latency_s", self.latency_s, MAX_LATENCY_S, "s")?;
        within(
            "arm.position_resolution_m",
            self.position_resolution_m,
            MAX_POSITION_RESOLUTION_M,
            "m",
        )?;
        within(
            "arm.force_resolution_n",
            self.force_resolution_n,
            MAX_FORCE_RESOLUTION_N,
            "N",
        )?;
        within(
            "arm.period_jitter_s",
            self.period_jitter_s,
            MAX_LATENCY_S,
            "s",
        )?;
        if self.velocity_window_ticks > MAX_VELOCITY_WINDOW_TICKS {
            return Err(SimError::OutOfRange {
                name: "arm.velocity_window_ticks",
                value: f64::from(self.velocity_window_ticks),
                min: 0.0,
                max: f64::from(MAX_VELOCITY_WINDOW_TICKS),
                min_excluded: false,
                unit: "ticks",
            });
        }
        Ok(())
    }

    /// `x` rounded to multiples of `resolution` on each axis (unchanged for 0).
    pub fn quantise(x: DVec3, resolution: f64) -> DVec3 {
        if resolution > 0.0 {
            (x / resolution).round() * resolution
        } else {
            x
        }
    }
}

/// A force and the time it starts to act.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Queued {
    at_s: f64,
    force_n: DVec3,
}

/// The tick-to-tick state of the effects: the forces in flight, the recent reported positions and the jitter
/// generator. Fixed capacity, allocated once.
#[derive(Clone, Debug)]
pub struct EffectsState {
    /// Forces sent but maybe not yet acting, oldest first; `queue[head]` is the one acting now.
    queue: Vec<Queued>,
    head: usize,
    len: usize,
    /// Reported positions and their times, newest last (a ring of `window + 1`).
    samples: Vec<(f64, DVec3)>,
    samples_next: usize,
    samples_len: usize,
    rng: u64,
}

impl EffectsState {
    /// Room for every force that can be in flight at [`MIN_TICK_S`] ticks, and for the velocity window.
    pub fn new(effects: &DeviceEffects) -> Self {
        let in_flight = (effects.latency_s / MIN_TICK_S).ceil() as usize + 3;
        EffectsState {
            queue: vec![
                Queued {
                    at_s: f64::NEG_INFINITY,
                    force_n: DVec3::ZERO,
                };
                in_flight
            ],
            head: 0,
            len: 1,
            samples: vec![(0.0, DVec3::ZERO); effects.velocity_window_ticks as usize + 1],
            samples_next: 0,
            samples_len: 0,
            rng: u64::from(effects.jitter_seed) ^ 0x9E37_79B9_7F4A_7C15,
        }
    }

    /// Sends `force_n` to act from `at_s`. When the queue is full (ticks shorter than [`MIN_TICK_S`]) the
    /// newest queued force is replaced, so the queue never grows.
    pub fn send(&mut self, at_s: f64, force_n: DVec3) {
        let capacity = self.queue.len();
        if self.len == capacity {
            let last = (self.head + self.len - 1) % capacity;
            self.queue[last] = Queued { at_s, force_n };
            return;
        }
        let slot = (self.head + self.len) % capacity;
        self.queue[slot] = Queued { at_s, force_n };
        self.len += 1;
    }

    /// The force acting at `t_s` (after dropping the ones superseded by then) and when the next one starts
    /// (infinity when none is queued).
    pub fn acting_at(&mut self, t_s: f64) -> (DVec3, f64) {
        let capacity = self.queue.len();
        while self.len > 1 && self.queue[(self.head + 1) % capacity].at_s <= t_s {
            self.head = (self.head + 1) % capacity;
            self.len -= 1;
        }
        let next_s = if self.len > 1 {
            self.queue[(self.head + 1) % capacity].at_s
        } else {
            f64::INFINITY
        };
        (self.queue[self.head].force_n, next_s)
    }

    /// The next jitter offset, uniform in `[-jitter_s, jitter_s]` (SplitMix64).
    pub fn next_jitter_s(&mut self, jitter_s: f64) -> f64 {
        if jitter_s <= 0.0 {
            return 0.0;
        }
        self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        let unit = (z >> 11) as f64 / (1u64 << 53) as f64;
        jitter_s * (2.0 * unit - 1.0)
    }

    /// Records a reported position at `t_s`; returns the velocity over the window (`None` until it is full,
    /// or with no window).
    pub fn record(&mut self, t_s: f64, position_m: DVec3) -> Option<DVec3> {
        let n = self.samples.len();
        self.samples[self.samples_next] = (t_s, position_m);
        self.samples_next = (self.samples_next + 1) % n;
        self.samples_len = (self.samples_len + 1).min(n);
        if n < 2 || self.samples_len < n {
            return None;
        }
        // The oldest is the slot written next.
        let (t0, x0) = self.samples[self.samples_next];
        (t_s > t0).then(|| (position_m - x0) / (t_s - t0))
    }

    /// Forgets every queued force and sample (the arm was moved, e.g. into the scene frame).
    pub fn reset(&mut self) {
        self.head = 0;
        self.len = 1;
        self.queue[0] = Queued {
            at_s: f64::NEG_INFINITY,
            force_n: DVec3::ZERO,
        };
        self.samples_len = 0;
    }
}

#[cfg(test)]
#[path = "effects_tests.rs"]
mod tests;
