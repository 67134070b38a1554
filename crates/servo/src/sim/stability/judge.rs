//! One run at a stiffness and its verdict.
//!
//! The run: a released hand pushes the arm onto a plane with [`PUSH_N`], starting at rest half the static force
//! off the contact's equilibrium (`z = -PUSH_N / K + 0.5 PUSH_N / K`), so that a passive contact stays in contact
//! and decays, and an active one grows into bouncing. Position quantisation is off (it adds its own limit
//! cycles), so the arm is the linear loop of the zero-order-hold analysis.
//!
//! A stiffness is passive when, over the run, (1) the contact's oscillation decays (the largest distance from
//! the equilibrium in the last fifth of the run is below the largest in the first fifth), (2) the energy ledger
//! finds no limit cycle, and (3) the energy the loop generated, summed from the samples (not from the ledger),
//! never exceeds [`tolerance_j`]: the arm's kinetic energy plus the coupling spring's, less their start
//! values, less the work the hand's constant push did, `½ m v² + ½ K |proxy − probe|² − F_hand · (x − x0)`,
//! is what the coupling and the arm's damping together gave the arm beyond what the hand gave it.

use super::arms::ArmCase;
use super::error::StabilityError;
use super::local::run_local;
use super::memory::MemoryTrace;
use super::setup::{scenario_text, Sample, PUSH_N};
use crate::sim::{self, Scenario};
use glam::DVec3;
use std::path::Path;
use voxhap_core::haptics::tick::SolverKind;
use voxhap_device::sim::zoh_boundary;

/// Who closes the contact loop, and how fast.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LoopKind {
    /// The host renders the wall and sends the force (set-force) every period of `rate_hz`; the force acts
    /// `latency_s` after it was computed; `control`: the passivity controller on.
    Host {
        /// Host rate, Hz.
        rate_hz: f64,
        /// Transport latency, s.
        latency_s: f64,
        /// `[passivity] mode = "control"` (else `"off"`).
        control: bool,
    },
    /// The host sends a local model every period of `host_rate_hz` (each arriving `latency_s` after it was
    /// built) and the device renders the latest one with its own loop at `device_rate_hz`.
    Local {
        /// Host rate, Hz.
        host_rate_hz: f64,
        /// The device loop's rate, Hz (a whole multiple of the host's).
        device_rate_hz: f64,
        /// Latency of each model on the link, s.
        latency_s: f64,
    },
}

impl LoopKind {
    /// The passivity bound `b / (T/2 + tau)` of the loop that closes the contact (Colgate and Schenkel,
    /// J. Robotic Systems 14(1), 1997, `K < 2b/T` without delay; the delay term as in Hulin, Albu-Schäffer and
    /// Hirzinger, IEEE TCST 2014): for a local model `T` is the device's period and no link latency enters,
    /// since the device senses and acts in its own loop (the model's age moves what it renders, not when).
    pub fn bound_n_per_m(&self, damping_n_s_per_m: f64) -> f64 {
        match *self {
            LoopKind::Host {
                rate_hz, latency_s, ..
            } => damping_n_s_per_m / (0.5 / rate_hz + latency_s),
            LoopKind::Local { device_rate_hz, .. } => damping_n_s_per_m * 2.0 * device_rate_hz,
        }
    }

    /// The exact zero-order-hold stability boundary of the loop that closes the contact, for an arm of
    /// `mass_kg` and `damping_n_s_per_m` (`voxhap_device::sim::zoh_boundary`): the host's period and the link's
    /// latency (any fraction of a period) for a host loop; the device's period and no latency for a local
    /// model, as for [`Self::bound_n_per_m`].
    pub fn exact_boundary_n_per_m(
        &self,
        mass_kg: f64,
        damping_n_s_per_m: f64,
    ) -> Result<f64, StabilityError> {
        let (period_s, latency_s) = match *self {
            LoopKind::Host {
                rate_hz, latency_s, ..
            } => (1.0 / rate_hz, latency_s),
            LoopKind::Local { device_rate_hz, .. } => (1.0 / device_rate_hz, 0.0),
        };
        Ok(zoh_boundary(
            mass_kg,
            damping_n_s_per_m,
            period_s,
            latency_s,
        )?)
    }

    /// The rate of the loop that closes the contact, Hz.
    pub fn loop_rate_hz(&self) -> f64 {
        match *self {
            LoopKind::Host { rate_hz, .. } => rate_hz,
            LoopKind::Local { device_rate_hz, .. } => device_rate_hz,
        }
    }
}

/// The tolerance on the generated energy (J): the storage of a sampled spring is not exactly `½ K |d|²` at
/// the sample instants; the held force lags the motion by `T/2 + tau`, so between what the samples book and
/// what the loop stores lies at most the excess of one step of that lag, `(2 d + 1) K |Δx|² / 2`, taken at
/// the largest step of the run (`d` the latency in loop periods), and 1 µJ for rounding.
pub fn tolerance_j(k: f64, latency_ticks: usize, largest_step_m: f64) -> f64 {
    (2 * latency_ticks + 1) as f64 * k * largest_step_m * largest_step_m / 2.0 + 1e-6
}

/// What one run at a stiffness showed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    /// The oscillation about the equilibrium decayed.
    pub decays: bool,
    /// The energy ledger found a contact limit cycle.
    pub oscillating: bool,
    /// The most energy the loop generated at any sample, J.
    pub generated_j: f64,
    /// What [`tolerance_j`] allows, J.
    pub tolerance_j: f64,
}

impl Verdict {
    /// Passive: decays, no limit cycle, and no more energy generated than the tolerance.
    pub fn passive(&self) -> bool {
        self.decays && !self.oscillating && self.generated_j <= self.tolerance_j
    }
}

/// The verdict on `samples` (one per loop period) of a run at `k` on an arm of `mass_kg`; `latency_ticks`
/// periods pass before a force acts; `oscillating` is the energy ledger's finding.
pub fn verdict(
    samples: &[Sample],
    mass_kg: f64,
    k: f64,
    latency_ticks: usize,
    oscillating: bool,
) -> Verdict {
    let equilibrium_z = -PUSH_N / k;
    let fifth = (samples.len() / 5).max(1);
    let distance = |s: &[Sample]| {
        s.iter()
            .map(|s| (s.probe_m.z - equilibrium_z).abs().max(s.probe_m.x.abs()))
            .fold(0.0f64, f64::max)
    };
    let decays = distance(&samples[samples.len().saturating_sub(fifth)..])
        < distance(&samples[..fifth.min(samples.len())]);
    // The books open once the latency's pipe has filled: before, the arm moved under the hand alone (no
    // coupling force had arrived yet), and the spring's energy it gained is the start's, not the loop's.
    let samples = &samples[latency_ticks.min(samples.len().saturating_sub(1))..];
    let stored = |s: &Sample| {
        0.5 * mass_kg * s.velocity_m_per_s.length_squared()
            + 0.5 * k * (s.proxy_m - s.probe_m).length_squared()
    };
    let hand = DVec3::new(0.0, 0.0, -PUSH_N);
    let mut generated_j = f64::NEG_INFINITY;
    let mut largest_step_m = 0.0f64;
    for pair in samples.windows(2) {
        largest_step_m = largest_step_m.max((pair[1].probe_m - pair[0].probe_m).length());
    }
    if let Some(first) = samples.first() {
        for s in samples {
            let given = stored(s) - stored(first) - hand.dot(s.probe_m - first.probe_m);
            generated_j = generated_j.max(given);
        }
    }
    Verdict {
        decays,
        oscillating,
        generated_j,
        tolerance_j: tolerance_j(k, latency_ticks, largest_step_m),
    }
}

/// Runs `arm` at stiffness `k` under `kind` and judges it.
pub fn judge(arm: &ArmCase, kind: LoopKind, k: f64) -> Result<Verdict, StabilityError> {
    match kind {
        LoopKind::Host {
            rate_hz,
            latency_s,
            control,
        } => {
            let text = scenario_text(arm, rate_hz, latency_s, control, k);
            let loaded = Scenario::parse(&text, "stiffness-sweep")?
                .load(Path::new(""), "stiffness-sweep")?;
            let mut trace = MemoryTrace::default();
            let summary = sim::run(&loaded, SolverKind::Exact, &mut trace, |_| {})?;
            let samples: Vec<Sample> = trace
                .0
                .iter()
                .map(|s| Sample {
                    probe_m: s.probe_m,
                    velocity_m_per_s: s.probe_velocity_m_per_s,
                    proxy_m: s.proxy_m,
                })
                .collect();
            let latency_ticks = (latency_s * rate_hz).round() as usize;
            Ok(verdict(
                &samples,
                arm.mass_kg,
                k,
                latency_ticks,
                summary.energy.oscillating(),
            ))
        }
        LoopKind::Local {
            host_rate_hz,
            device_rate_hz,
            latency_s,
        } => {
            let run = run_local(arm, host_rate_hz, device_rate_hz, latency_s, k)?;
            Ok(verdict(
                &run.samples,
                arm.mass_kg,
                run.k_n_per_m,
                0,
                run.oscillating,
            ))
        }
    }
}
