//! Force traces: one record per servo tick, written as CSV or MCAP with a JSON sidecar, and read back.
//!
//! Where it sits (docs/design.md, "Threads"): the servo thread fills a [`TraceSample`] every tick (a `Copy`
//! struct with no heap data, so it can travel through an SPSC ring without allocating) and the recorder
//! thread drains the ring into a [`TraceWriter`] made by [`create_trace_writer`]. A trace `TRACE` always
//! comes with a sidecar `TRACE.json` ([`Sidecar`]: the run's metadata, column units and flag bits).
//! `voxhap plot` and the tests read CSV traces back with [`read_csv_trace`] and MCAP traces with
//! [`read_mcap_trace`].
//!
//! Determinism: everything written is a function of the samples and the [`TraceMeta`], and only
//! `TraceMeta::created_utc` and an MCAP trace's log times (wall-clock UTC, so recordings line up with other
//! instruments) depend on the wall clock, so two runs of the same scenario write identical files apart from
//! those. Floats are written in shortest round-trip form, so reading a CSV trace
//! gives back the exact bits written.

mod columns;
pub mod compare;
mod csv;
mod error;
pub mod foxglove_scene;
mod mcap_trace;
mod meta;
mod output;
mod parquet_trace;
pub mod plot;
pub mod repair;

pub use self::columns::{columns, ColumnDoc, ColumnType};
pub use self::csv::{parse_csv_trace, read_csv_trace, CsvTraceWriter};
pub use self::error::{error_chain, TraceError, TraceReadError};
pub use self::mcap_trace::{
    parse_mcap_trace, read_mcap_trace, McapTraceWriter, SOLVER_TOPIC, STATE_TOPIC,
};
pub use self::meta::{sidecar_path, utc_now_ns, FlagDoc, Sidecar, TraceMeta, TRACE_FORMAT_VERSION};
pub use self::output::{
    check_output_path, create_new_file, create_or_replace_file, estimate_trace_bytes, OutputPolicy,
};
pub use self::parquet_trace::{
    read_parquet_trace, ParquetTraceWriter, SIDECAR_KEY as PARQUET_SIDECAR_KEY,
};

use glam::DVec3;
use std::borrow::Cow;
use std::path::{Path, PathBuf};

pub use voxhap_core::haptics::modes::MAX_MODES;
pub use voxhap_core::status::flags::*;

const fn flag(bit: u32, name: &'static str, meaning: &'static str) -> FlagDoc {
    FlagDoc {
        bit,
        name: Cow::Borrowed(name),
        meaning: Cow::Borrowed(meaning),
    }
}

/// How many flag bits are defined.
pub const FLAG_COUNT: usize = 17;

/// Every flag bit with its name and meaning, lowest bit first; written into the sidecar and, one boolean
/// column `flag_<name>` each, into the trace.
pub const FLAG_DOCS: [FlagDoc; FLAG_COUNT] = [
    flag(
        0,
        "solver_budget_hit",
        "solver stopped on its sweep or time budget before the certificate met its tolerance",
    ),
    flag(1, "force_clamped", "force clamped to the device maximum, direction kept"),
    flag(2, "workspace_limit", "probe at or beyond the device workspace limit"),
    flag(3, "overrun", "tick started late; missed ticks were skipped, not caught up"),
    flag(4, "non_finite_replaced", "a non-finite probe position or force was replaced by zero"),
    flag(5, "samples_dropped", "recorder ring was full; samples before this one were lost"),
    flag(
        6,
        "force_limited_by_safety",
        "force below what was rendered: ramping in, waiting to engage, slew-limited, or held at zero (watchdog, disconnect, device not enabled, stale state)",
    ),
    flag(7, "compute_over_budget", "tick compute exceeded its budget; the last safe force was sent again"),
    flag(
        8,
        "device_not_enabled",
        "device not accepting force (starting, recovering, faulted, or Enable refused): zero commanded",
    ),
    flag(9, "device_disconnected", "the device was disconnected this tick"),
    flag(10, "velocity_estimated", "probe velocity estimated by the host from positions, not reported by the device"),
    flag(
        11,
        "invalid_values",
        "the sample broke a trace rule (non-finite or negative value, wrong mode count) and was recorded as it came",
    ),
    flag(
        12,
        "position_rejected",
        "implausible device position (speed, workspace, non-finite); the last accepted one was held",
    ),
    flag(
        13,
        "velocity_replaced",
        "reported velocity disagreed with the positions; the estimate from positions was used",
    ),
    flag(14, "force_slew_limited", "the force's rise was limited by the slew rate"),
    flag(15, "stale_state", "no fresh device state for several periods: zero commanded"),
    flag(16, "device_faulted", "a device fault that needs a person is active"),
];

/// How a tick's solve ended, as recorded (`solver_status` column). Mirrors
/// `voxhap_core::haptics::tick::TickStatus`; `Unknown` for producers that do not say.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SolverStatus {
    /// Not reported.
    #[default]
    Unknown,
    /// The exact solver certified its answer within tolerance.
    Certified,
    /// The exact solver ran out of budget; the bound is honest but above tolerance.
    BudgetExhausted,
    /// The exact solver's bound stopped improving (f64 limit).
    Stalled,
    /// A baseline solver ran: no certificate.
    Uncertified,
    /// The tick's input was not finite; the proxy was held and no force sent.
    InputRejected,
}

impl SolverStatus {
    /// Every status, in code order.
    pub const ALL: [SolverStatus; 6] = [
        SolverStatus::Unknown,
        SolverStatus::Certified,
        SolverStatus::BudgetExhausted,
        SolverStatus::Stalled,
        SolverStatus::Uncertified,
        SolverStatus::InputRejected,
    ];

    /// The name written in traces.
    pub fn name(self) -> &'static str {
        match self {
            SolverStatus::Unknown => "unknown",
            SolverStatus::Certified => "certified",
            SolverStatus::BudgetExhausted => "budget_exhausted",
            SolverStatus::Stalled => "stalled",
            SolverStatus::Uncertified => "uncertified",
            SolverStatus::InputRejected => "input_rejected",
        }
    }

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
    /// [`FLAG_VELOCITY_ESTIMATED`] is set.
    pub probe_velocity_m_per_s: DVec3,
    /// Proxy position after the solve (m).
    pub proxy_m: DVec3,
    /// Force the renderer asked for, before the safety pipeline (N): coupling plus damping.
    pub rendered_force_n: DVec3,
    /// Force sent to the device, after the safety pipeline (N).
    pub force_n: DVec3,
    /// Force each mode's primitives exerted on the proxy at the solution (N); they sum to the coupling
    /// force `k (proxy - probe)` (exactly for the baselines, within `k error_bound_m` for the exact
    /// solver). Slots at and past `mode_count` are ignored and read back as 0.
    pub mode_force_n: [DVec3; MAX_MODES],
    /// Primitives each mode emitted this tick; slots at and past `mode_count` are ignored and read back
    /// as 0.
    pub primitives_per_mode: [u16; MAX_MODES],
    /// How many modes the scene has; must equal the trace's `TraceMeta::mode_names` length.
    pub mode_count: u8,
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
            force_n: DVec3::ZERO,
            mode_force_n: [DVec3::ZERO; MAX_MODES],
            primitives_per_mode: [0; MAX_MODES],
            mode_count,
            solver_status: SolverStatus::Unknown,
            sweeps: 0,
            error_bound_m: 0.0,
            device_sequence: None,
            device_time_us: None,
            flags: 0,
        }
    }

    /// The primitive counts of the modes in use.
    pub fn primitives(&self) -> &[u16] {
        &self.primitives_per_mode[..usize::from(self.mode_count).min(MAX_MODES)]
    }

    /// The per-mode forces of the modes in use.
    pub fn mode_forces(&self) -> &[DVec3] {
        &self.mode_force_n[..usize::from(self.mode_count).min(MAX_MODES)]
    }
}

pub use voxhap_api::TraceFormat;

/// What a finished trace wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TraceSummary {
    /// The trace file.
    pub trace_path: PathBuf,
    /// Its JSON sidecar.
    pub sidecar_path: PathBuf,
    /// Samples written.
    pub sample_count: u64,
}

/// A trace sink. Runs on the recorder thread (it allocates and does I/O; never call it on the servo
/// thread). Call [`TraceWriter::finish`] to close the files cleanly; writing after that is an error.
///
/// A sample that breaks a trace rule (a non-finite value, a wrong mode count) is recorded as it came with
/// [`FLAG_INVALID_VALUES`] set, so one bad tick never ends a trace; a sample whose tick does not increase
/// is left out and counted (`Sidecar::samples_rejected`). Only I/O errors end a trace: the caller then
/// calls [`TraceWriter::fail`] so the sidecar says why.
pub trait TraceWriter: Send {
    /// Appends one sample (see the trait docs for bad samples). Errors are I/O errors, or `Finished`.
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError>;
    /// Pushes buffered data to the file so a reader (or a crash) sees everything written so far: whole
    /// CSV lines, a closed MCAP chunk.
    fn flush(&mut self) -> Result<(), TraceError>;
    /// Writes the trailer (MCAP summary), flushes, and rewrites the sidecar with the final sample count.
    fn finish(&mut self) -> Result<TraceSummary, TraceError>;
    /// Gives up after an error: nothing more reaches the trace file (not even buffered bytes), and the
    /// sidecar records `error` (complete: false) and the samples that reached the file, exactly the ones
    /// a reader recovers. Best effort: the sidecar may be unwritable too.
    fn fail(&mut self, error: &str) -> Result<(), TraceError>;
    /// Samples that reached the file so far (whole CSV lines handed to the OS, closed Parquet row groups,
    /// closed MCAP chunks): the count the sidecar gives, never samples still in a buffer.
    fn sample_count(&self) -> u64;
    /// The servo's snapshot of a tick whose sample comes next (the recorder hands one over at most
    /// `foxglove_scene::RECORDED_SCENE_HZ` times a second of tick time, before that tick's sample): the
    /// MCAP writer draws the tick's primitives and operating state from it. Writers without scene topics
    /// ignore it.
    fn scene_frame(&mut self, _frame: &voxhap_api::Snapshot) {}
    /// The scene changed while recording (a volume loaded, a transfer function replaced): the MCAP writer
    /// draws the new volume picture with the first snapshot that shows `change.generation`. Writers
    /// without scene topics ignore it.
    fn scene_changed(&mut self, _change: &foxglove_scene::SceneChange) {}
}

/// Creates `path` (and `path.json`) in `format` for a run described by `meta`, refusing to replace an
/// existing file ([`create_trace_writer_with`] with [`OutputPolicy::default`]).
pub fn create_trace_writer(
    path: &Path,
    format: TraceFormat,
    meta: &TraceMeta,
) -> Result<Box<dyn TraceWriter>, TraceError> {
    create_trace_writer_with(path, format, meta, &OutputPolicy::default())
}

/// Creates `path` (and `path.json`) in `format` for a run described by `meta`, after checking `policy`:
/// an existing trace or sidecar is replaced only with `policy.overwrite` (removed, then created anew), a
/// file that is one of `policy.inputs` never is, and a symlink is never followed (see `output`).
pub fn create_trace_writer_with(
    path: &Path,
    format: TraceFormat,
    meta: &TraceMeta,
    policy: &OutputPolicy,
) -> Result<Box<dyn TraceWriter>, TraceError> {
    check_output_path(path, policy)?;
    if policy.overwrite {
        output::remove_replaced(path)?;
    }
    Ok(match format {
        TraceFormat::Csv => Box::new(CsvTraceWriter::create(path, meta)?),
        TraceFormat::Mcap => Box::new(McapTraceWriter::create(path, meta)?),
        TraceFormat::Parquet => Box::new(ParquetTraceWriter::create(path, meta)?),
    })
}

/// A trace read back from disk.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// Mode names, in column order.
    pub mode_names: Vec<String>,
    /// The samples in file order.
    pub samples: Vec<TraceSample>,
    /// The sidecar, when `TRACE.json` exists.
    pub sidecar: Option<Sidecar>,
    /// What the reader skipped and why (a partial last CSV line, an unfinished MCAP chunk after a
    /// crash); empty for a cleanly finished trace. Callers show these to the user.
    pub warnings: Vec<String>,
}

/// What a trace's sidecar says that its data contradict, one warning each (empty when it tells the
/// truth, or when there is no sidecar): the sample count (of a finished trace, or of one whose sidecar
/// records the error that stopped it; a sidecar still provisional, `complete: false` without an error,
/// has no final count to check), the mode names, the columns, the format and the trace format version
/// (not `trace_file`: a trace and sidecar renamed together are still honest). The readers add these to `Trace::warnings`, which `voxhap plot`, `voxhap trace`, replay
/// and `voxhap compare` print on stderr: a lying sidecar is never trusted silently.
pub fn sidecar_warnings(
    sidecar: Option<&Sidecar>,
    path: &Path,
    format: TraceFormat,
    mode_names: &[String],
    sample_count: u64,
) -> Vec<String> {
    let Some(sidecar) = sidecar else {
        return Vec::new();
    };
    let mut warnings = Vec::new();
    let mut warn = |what: String| {
        warnings.push(format!(
            "{}: the sidecar {} does not match the trace: {what}; the trace's data are used",
            path.display(),
            sidecar_path(path).display()
        ))
    };
    if (sidecar.complete || sidecar.error.is_some()) && sidecar.sample_count != sample_count {
        warn(format!(
            "it says {} samples, the trace holds {sample_count}",
            sidecar.sample_count
        ));
    }
    if sidecar.meta.mode_names != mode_names {
        warn(format!(
            "it names the modes {:?}, the trace has {:?}",
            sidecar.meta.mode_names, mode_names
        ));
    } else if sidecar.columns != columns(mode_names) {
        warn("its column list differs from the trace's columns".to_owned());
    }
    if sidecar.trace_format != format {
        warn(format!(
            "it says trace_format {}, the file is {format}",
            sidecar.trace_format
        ));
    }
    if sidecar.meta.format_version != TRACE_FORMAT_VERSION {
        warn(format!(
            "it says format_version {}, this reader reads {TRACE_FORMAT_VERSION}",
            sidecar.meta.format_version
        ));
    }
    warnings
}

/// Adds [`sidecar_warnings`] for a trace just read from `path` to its warnings.
pub(crate) fn check_sidecar(mut trace: Trace, path: &Path, format: TraceFormat) -> Trace {
    let found = sidecar_warnings(
        trace.sidecar.as_ref(),
        path,
        format,
        &trace.mode_names,
        trace.samples.len() as u64,
    );
    trace.warnings.extend(found);
    trace
}

/// Opens a trace (or sidecar) for reading: a regular file only, so a FIFO or a device (`replay:/dev/zero`)
/// is refused at once instead of blocking or reading without end.
pub(crate) fn open_trace_file(path: &Path) -> Result<(std::fs::File, u64), TraceReadError> {
    voxhap_io::open_regular(path).map_err(|error| TraceReadError::Io {
        path: path.to_path_buf(),
        source: match error {
            voxhap_io::FileError::Io(source) => source,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
        },
    })
}

/// Reads a whole trace file (a regular file; its size bounds the read).
pub(crate) fn read_trace_file(path: &Path) -> Result<Vec<u8>, TraceReadError> {
    use std::io::Read;
    let (file, size_bytes) = open_trace_file(path)?;
    let mut bytes = Vec::with_capacity(usize::try_from(size_bytes).unwrap_or(0));
    file.take(size_bytes)
        .read_to_end(&mut bytes)
        .map_err(|source| TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(bytes)
}

/// Reads a CSV, MCAP or Parquet trace, choosing by the file's first bytes (the MCAP magic, `PAR1`)
/// rather than its name.
pub fn read_trace(path: &Path) -> Result<Trace, TraceReadError> {
    let mut magic = [0u8; 8];
    let is_mcap = {
        use std::io::Read;
        let (mut file, _) = open_trace_file(path)?;
        let mut filled = 0;
        while filled < magic.len() {
            match file.read(&mut magic[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(source) => {
                    return Err(TraceReadError::Io {
                        path: path.to_path_buf(),
                        source,
                    })
                }
            }
        }
        filled == magic.len() && magic[..] == *mcap::MAGIC
    };
    if is_mcap {
        read_mcap_trace(path)
    } else if magic.starts_with(b"PAR1") {
        read_parquet_trace(path)
    } else {
        read_csv_trace(path)
    }
}

/// Applies the trace rules to samples on their way into a writer; shared by every writer.
#[derive(Clone, Debug)]
struct SampleChecker {
    mode_count: usize,
    last_tick: Option<u64>,
    count: u64,
    rejected: u64,
    finished: bool,
}

impl SampleChecker {
    fn new(mode_count: usize) -> Self {
        SampleChecker {
            mode_count,
            last_tick: None,
            count: 0,
            rejected: 0,
            finished: false,
        }
    }

    /// The sample to record (flagged [`FLAG_INVALID_VALUES`] if it broke a value rule), or `None` when
    /// its tick does not increase (counted in `rejected`).
    fn admit(&mut self, sample: &TraceSample) -> Result<Option<TraceSample>, TraceError> {
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
        if usize::from(sample.mode_count) != self.mode_count {
            // Record the trace's modes; counts and forces past the sample's own are zero.
            for slot in usize::from(sample.mode_count).min(MAX_MODES)..MAX_MODES {
                sample.primitives_per_mode[slot] = 0;
                sample.mode_force_n[slot] = DVec3::ZERO;
            }
            sample.mode_count = self.mode_count as u8;
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
        ("force_n", sample.force_n.is_finite()),
    ];
    for (field, finite) in finite_fields {
        if !finite {
            return Err(TraceError::NonFinite { tick, field });
        }
    }
    if !sample.mode_forces().iter().all(|f| f.is_finite()) {
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
fn check_sample(
    sample: &TraceSample,
    mode_count: usize,
    last_tick: Option<u64>,
) -> Result<(), TraceError> {
    let tick = sample.tick;
    if usize::from(sample.mode_count) != mode_count {
        return Err(TraceError::ModeCountMismatch {
            tick,
            expected: mode_count,
            found: usize::from(sample.mode_count),
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

#[cfg(test)]
pub(crate) mod test_support {
    //! Deterministic synthetic traces for the writer and reader tests.
    use super::*;

    /// A `TraceMeta` with a fixed creation time, so files are comparable byte for byte.
    pub fn meta(mode_names: &[&str]) -> TraceMeta {
        let mut meta = TraceMeta::new(
            mode_names.iter().map(|s| s.to_string()).collect(),
            1000.0,
            serde_json::json!({"name": "unit-test", "arm": {"mass_kg": 0.1}}),
            "procedural:sphere",
            "exact-dual",
        );
        meta.created_utc = "2000-01-01T00:00:00Z".to_string();
        meta.start_utc_ns = 946_684_800_000_000_000;
        meta
    }

    /// `count` samples of a probe circling a plane, with awkward floats (negative zero, tiny bounds,
    /// an infinite bound) to exercise exact round-trips.
    pub fn samples(count: u64, mode_count: u8) -> Vec<TraceSample> {
        (0..count)
            .map(|i| {
                let t_s = i as f64 * 1e-3;
                let angle = t_s * 7.0;
                let probe_m = DVec3::new(0.02 * angle.cos(), 0.02 * angle.sin(), -0.001 * t_s);
                let proxy_m = DVec3::new(probe_m.x, probe_m.y, probe_m.z.max(0.0));
                let mut primitives_per_mode = [0u16; MAX_MODES];
                for (m, slot) in primitives_per_mode
                    .iter_mut()
                    .take(usize::from(mode_count))
                    .enumerate()
                {
                    *slot = ((i as usize + m) % 3) as u16;
                }
                let force_n = (proxy_m - probe_m) * 500.0 + DVec3::new(-0.0, 1e-300, 0.1);
                let mut mode_force_n = [DVec3::ZERO; MAX_MODES];
                for (m, slot) in mode_force_n
                    .iter_mut()
                    .take(usize::from(mode_count))
                    .enumerate()
                {
                    *slot = force_n * (m as f64 + 1.0) / 3.0;
                }
                TraceSample {
                    tick: i * 2,
                    t_s,
                    probe_m,
                    probe_velocity_m_per_s: DVec3::new(
                        -0.14 * angle.sin(),
                        0.14 * angle.cos(),
                        -0.001,
                    ),
                    proxy_m,
                    rendered_force_n: force_n * 1.5,
                    force_n,
                    mode_force_n,
                    primitives_per_mode,
                    mode_count,
                    solver_status: SolverStatus::ALL[(i % 6) as usize],
                    sweeps: (i % 5) as u32,
                    error_bound_m: if i % 7 == 3 {
                        f64::INFINITY
                    } else {
                        1e-17 * (i as f64 + 1.0).powi(3)
                    },
                    device_sequence: (i % 3 != 0).then_some(i * 10),
                    device_time_us: (i % 2 == 0).then_some(i * 1000 + 17),
                    flags: (i % 4) as u32
                        | if i % 11 == 5 {
                            FLAG_DEVICE_NOT_ENABLED
                        } else {
                            0
                        },
                }
            })
            .collect()
    }
}
