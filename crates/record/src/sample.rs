//! One recorded tick ([`TraceSample`], with its [`SolverStatus`]) and the rules every sample obeys:
//! [`SampleChecker`] on the way into a writer, [`check_sample`] on the way out of a reader.
//!
//! Invariant: `TraceSample` is `Copy` and heap-free, so the servo thread can push it through an SPSC ring
//! without allocating.

use crate::error::TraceError;
use crate::flags::FLAG_INVALID_VALUES;
use glam::DVec3;
use voxhap_api::{Snapshot, TickTruth};
use voxhap_core::haptics::tick::{ModeBreakdown, TickOutput};

voxhap_core::named_enum! {
    /// How a tick's solve ended, as recorded (`solver_status` column). Mirrors
    /// `voxhap_core::haptics::tick::TickStatus`; `Unknown` for producers that do not say.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
    pub enum SolverStatus {
        /// Not reported.
        #[default]
        Unknown => "unknown",
        /// The exact solver certified its answer within tolerance.
        Certified => "certified",
        /// The exact solver ran out of budget; the bound is honest but above tolerance.
        BudgetExhausted => "budget_exhausted",
        /// The exact solver's bound stopped improving (f64 limit).
        Stalled => "stalled",
        /// A baseline solver ran: no certificate.
        Uncertified => "uncertified",
        /// The tick's input was not finite; the proxy was held and no force sent.
        InputRejected => "input_rejected",
    }
}

impl SolverStatus {
    /// The status with this name.
    pub fn from_name(name: &str) -> Option<SolverStatus> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

impl From<voxhap_core::haptics::tick::TickStatus> for SolverStatus {
    fn from(status: voxhap_core::haptics::tick::TickStatus) -> Self {
        use SolverStatus as S;
        match status {
            voxhap_core::haptics::tick::TickStatus::Certified => S::Certified,
            voxhap_core::haptics::tick::TickStatus::BudgetExhausted => S::BudgetExhausted,
            voxhap_core::haptics::tick::TickStatus::Stalled => S::Stalled,
            voxhap_core::haptics::tick::TickStatus::Uncertified => S::Uncertified,
            voxhap_core::haptics::tick::TickStatus::InputRejected => S::InputRejected,
        }
    }
}

/// One servo tick, as recorded. `Copy` and heap-free: the servo thread writes it into an SPSC ring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceSample {
    /// Tick number since the run started; strictly increasing in a trace (gaps mean skipped ticks).
    pub tick: u64,
    /// Time of the tick since the run started (s), >= 0 (monotonic: the schedule's time, never stepped).
    /// The wall-clock UTC column is `TraceMeta::start_utc_ns + t_s`.
    pub t_s: f64,
    /// Probe (device) position (m).
    pub probe_m: DVec3,
    /// Probe velocity (m/s): the device's report, or the host's estimate when
    /// [`FLAG_VELOCITY_ESTIMATED`](crate::flags::FLAG_VELOCITY_ESTIMATED) is set.
    pub probe_velocity_m_per_s: DVec3,
    /// Proxy position after the solve (m).
    pub proxy_m: DVec3,
    /// Force the renderer asked for, before the safety pipeline (N): coupling plus damping.
    pub rendered_force_n: DVec3,
    /// Force sent to the device, after the safety pipeline (N).
    pub sent_force_n: DVec3,
    /// Primitives each mode emitted this tick and the force they exerted on the proxy at the solution (N),
    /// which sum to the coupling force `k (proxy - probe)` (exactly for the baselines, within
    /// `k error_bound_m` for the exact solver). Its count of modes must equal the trace's
    /// `TraceMeta::mode_names` length.
    pub modes: ModeBreakdown,
    /// How the solve ended.
    pub solver_status: SolverStatus,
    /// Solver sweeps this tick.
    pub sweeps: u32,
    /// Certificate bound on the proxy's distance from the exact equilibrium (m), >= 0; `+inf` when the
    /// solver produced no certificate.
    pub error_bound_m: f64,
    /// The device's own sequence number of the state this tick used, where the device sends one.
    pub device_sequence: Option<u64>,
    /// The device's clock at that state (us), where the device has one.
    pub device_time_us: Option<u64>,
    /// Bit set of `FLAG_*` constants.
    pub flags: u32,
    /// The tick's truth: energy ledger totals, force-off cause, device faults, sample age (the last
    /// columns, `truth_columns.rs`).
    pub truth: TickTruth,
}

impl TraceSample {
    /// A sample with every number zero for `mode_count` modes (tests and ring initialisation).
    pub fn zeroed(mode_count: u8) -> Self {
        TraceSample {
            tick: 0,
            t_s: 0.0,
            probe_m: DVec3::ZERO,
            probe_velocity_m_per_s: DVec3::ZERO,
            proxy_m: DVec3::ZERO,
            rendered_force_n: DVec3::ZERO,
            sent_force_n: DVec3::ZERO,
            modes: ModeBreakdown::zeroed(mode_count),
            solver_status: SolverStatus::Unknown,
            sweeps: 0,
            error_bound_m: 0.0,
            device_sequence: None,
            device_time_us: None,
            flags: 0,
            truth: TickTruth::default(),
        }
    }

    /// The sample of a tick the servo loop published as `snapshot`, with the per-mode figures of the tick's
    /// solve `out`; the snapshot's flags, and neither device sequence nor device clock.
    pub fn published(snapshot: &Snapshot, out: &TickOutput) -> Self {
        TraceSample {
            tick: snapshot.tick,
            t_s: snapshot.t_s,
            probe_m: snapshot.probe_m,
            probe_velocity_m_per_s: snapshot.probe_velocity_m_per_s,
            proxy_m: snapshot.proxy_m,
            rendered_force_n: snapshot.rendered_force_n,
            sent_force_n: snapshot.sent_force_n,
            modes: out.modes,
            solver_status: snapshot.status.into(),
            sweeps: snapshot.sweeps,
            error_bound_m: snapshot.error_bound_m,
            device_sequence: None,
            device_time_us: None,
            flags: snapshot.flags,
            truth: snapshot.truth,
        }
    }
}

/// Applies the trace rules to samples on their way into a writer; shared by every writer.
#[derive(Clone, Debug)]
pub(crate) struct SampleChecker {
    pub(crate) mode_count: usize,
    last_tick: Option<u64>,
    pub(crate) count: u64,
    pub(crate) rejected: u64,
    pub(crate) finished: bool,
}

impl SampleChecker {
    pub(crate) fn new(mode_count: usize) -> Self {
        SampleChecker {
            mode_count,
            last_tick: None,
            count: 0,
            rejected: 0,
            finished: false,
        }
    }

    /// [`Self::admit`] for a writer whose file is `open`: a writer whose file is gone (finished, failed) is
    /// [`TraceError::Finished`].
    pub(crate) fn admit_to(
        &mut self,
        open: bool,
        sample: &TraceSample,
    ) -> Result<Option<TraceSample>, TraceError> {
        if !open {
            return Err(TraceError::Finished);
        }
        self.admit(sample)
    }

    /// The sample to record (flagged [`FLAG_INVALID_VALUES`] if it broke a value rule), or `None` when
    /// its tick does not increase (counted in `rejected`).
    pub(crate) fn admit(
        &mut self,
        sample: &TraceSample,
    ) -> Result<Option<TraceSample>, TraceError> {
        if self.finished {
            return Err(TraceError::Finished);
        }
        if let Some(previous) = self.last_tick {
            if sample.tick <= previous {
                self.rejected += 1;
                return Ok(None);
            }
        }
        let mut sample = *sample;
        if sample.modes.count() != self.mode_count {
            // Record the trace's modes; counts and forces past the sample's own are zero.
            sample.modes.set_count(self.mode_count as u8);
            sample.flags |= FLAG_INVALID_VALUES;
        }
        if check_values(&sample).is_err() {
            sample.flags |= FLAG_INVALID_VALUES;
        }
        self.last_tick = Some(sample.tick);
        self.count += 1;
        Ok(Some(sample))
    }
}

/// The value rules of a sample: finite time, positions, velocity and forces, `t_s >= 0`, and a bound that
/// is `>= 0` or `+inf`.
fn check_values(sample: &TraceSample) -> Result<(), TraceError> {
    let tick = sample.tick;
    let finite_fields: [(&'static str, bool); 6] = [
        ("t_s", sample.t_s.is_finite()),
        ("probe_m", sample.probe_m.is_finite()),
        (
            "probe_velocity_m_per_s",
            sample.probe_velocity_m_per_s.is_finite(),
        ),
        ("proxy_m", sample.proxy_m.is_finite()),
        ("rendered_force_n", sample.rendered_force_n.is_finite()),
        ("force_n", sample.sent_force_n.is_finite()),
    ];
    for (field, finite) in finite_fields {
        if !finite {
            return Err(TraceError::NonFinite { tick, field });
        }
    }
    let e = &sample.truth.energy;
    let energy = [
        e.work_on_probe_j,
        e.coupling_energy_j,
        e.generated_j,
        e.active_work_j,
        e.device_dissipation_j,
        e.net_generated_j,
        e.passivity_dissipated_j,
    ];
    if !energy.iter().all(|j| j.is_finite()) {
        return Err(TraceError::NonFinite {
            tick,
            field: "energy",
        });
    }
    // The device's own force is absent (NaN in the tabular formats) or finite.
    if !sample.truth.device_force_n.is_none_or(|f| f.is_finite()) {
        return Err(TraceError::NonFinite {
            tick,
            field: "device_force_n",
        });
    }
    // A local-model device's report is absent (NaN in the tabular formats) or finite.
    if !sample.truth.device_local.is_none_or(|l| {
        l.proxy_m.is_finite() && l.proxy_bound_m.is_finite() && l.model_age_s.is_finite()
    }) {
        return Err(TraceError::NonFinite {
            tick,
            field: "device_local",
        });
    }
    if !sample.modes.forces_n().iter().all(|f| f.is_finite()) {
        return Err(TraceError::NonFinite {
            tick,
            field: "mode_force_n",
        });
    }
    if sample.t_s < 0.0 {
        return Err(TraceError::NegativeTime {
            tick,
            t_s: sample.t_s,
        });
    }
    if sample.error_bound_m.is_nan() || sample.error_bound_m < 0.0 {
        return Err(TraceError::InvalidErrorBound {
            tick,
            value: sample.error_bound_m,
        });
    }
    Ok(())
}

/// The rules every sample read back obeys: the mode count, increasing ticks, and the value rules unless
/// the sample is flagged [`FLAG_INVALID_VALUES`] (then its values are kept as recorded).
pub(crate) fn check_sample(
    sample: &TraceSample,
    mode_count: usize,
    last_tick: Option<u64>,
) -> Result<(), TraceError> {
    let tick = sample.tick;
    if sample.modes.count() != mode_count {
        return Err(TraceError::ModeCountMismatch {
            tick,
            expected: mode_count,
            found: sample.modes.count(),
        });
    }
    if let Some(previous) = last_tick {
        if tick <= previous {
            return Err(TraceError::TickOrder { previous, tick });
        }
    }
    if sample.flags & FLAG_INVALID_VALUES != 0 {
        return Ok(());
    }
    check_values(sample)
}
