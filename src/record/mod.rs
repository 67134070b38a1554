//! Force traces: one record per servo tick, written as CSV or MCAP with a JSON sidecar, and read back.
//!
//! Where it sits (DESIGN.md section 5): the servo thread fills a [`TraceSample`] every tick (a `Copy`
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

mod csv;
mod error;
pub mod foxglove_topics;
mod mcap_trace;
mod meta;
pub mod plot;

pub use self::csv::{parse_csv_trace, read_csv_trace, CsvTraceWriter};
pub use self::error::{TraceError, TraceReadError};
pub use self::mcap_trace::{
    parse_mcap_trace, read_mcap_trace, McapTraceWriter, SOLVER_TOPIC, STATE_TOPIC,
};
pub use self::meta::{sidecar_path, ColumnDoc, FlagDoc, Sidecar, TraceMeta, TRACE_FORMAT_VERSION};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::fmt;
use std::path::{Path, PathBuf};

/// The most haptic modes a trace records primitive counts for.
pub const MAX_MODES: usize = 8;

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
/// Flag bit: the device's position was implausible (a jump beyond its maximum speed, outside its workspace,
/// not finite); the last accepted one was used.
pub const FLAG_POSITION_REJECTED: u32 = 1 << 9;
/// Flag bit: the device's reported velocity disagreed with its positions (or exceeded its maximum speed);
/// the estimate from positions was used.
pub const FLAG_VELOCITY_REPLACED: u32 = 1 << 10;
/// Flag bit: the force's rise was limited by the slew rate.
pub const FLAG_FORCE_SLEW_LIMITED: u32 = 1 << 11;
/// Flag bit: no fresh device state for several periods; zero was commanded.
pub const FLAG_STALE_STATE: u32 = 1 << 12;
/// Flag bit: a fault that needs a person is active on the device.
pub const FLAG_DEVICE_FAULTED: u32 = 1 << 13;

/// Every flag bit with its name and meaning, lowest bit first; written into the sidecar.
pub const FLAG_DOCS: [FlagDoc; 14] = [
    FlagDoc {
        bit: 0,
        name: Cow::Borrowed("solver_budget_hit"),
        meaning: Cow::Borrowed(
            "solver stopped on its sweep or time budget before the certificate met its tolerance",
        ),
    },
    FlagDoc {
        bit: 1,
        name: Cow::Borrowed("force_clamped"),
        meaning: Cow::Borrowed("force clamped to the device maximum, direction kept"),
    },
    FlagDoc {
        bit: 2,
        name: Cow::Borrowed("workspace_limit"),
        meaning: Cow::Borrowed("probe at or beyond the device workspace limit"),
    },
    FlagDoc {
        bit: 3,
        name: Cow::Borrowed("overrun"),
        meaning: Cow::Borrowed("tick started late; missed ticks were skipped, not caught up"),
    },
    FlagDoc {
        bit: 4,
        name: Cow::Borrowed("non_finite_replaced"),
        meaning: Cow::Borrowed("a non-finite probe position or force was replaced by zero"),
    },
    FlagDoc {
        bit: 5,
        name: Cow::Borrowed("samples_dropped"),
        meaning: Cow::Borrowed("recorder ring was full; samples before this one were lost"),
    },
    FlagDoc {
        bit: 6,
        name: Cow::Borrowed("force_limited_by_safety"),
        meaning: Cow::Borrowed(
            "force below what was rendered: ramping in, waiting to engage, slew-limited, or held at zero \
             (watchdog, disconnect, device not enabled, stale state)",
        ),
    },
    FlagDoc {
        bit: 7,
        name: Cow::Borrowed("compute_over_budget"),
        meaning: Cow::Borrowed(
            "tick compute exceeded its budget; the last safe force was sent again",
        ),
    },
    FlagDoc {
        bit: 8,
        name: Cow::Borrowed("device_not_enabled"),
        meaning: Cow::Borrowed(
            "device not accepting force (starting, recovering, faulted, or Enable refused): zero commanded",
        ),
    },
    FlagDoc {
        bit: 9,
        name: Cow::Borrowed("position_rejected"),
        meaning: Cow::Borrowed(
            "implausible device position (speed, workspace, non-finite); the last accepted one was held",
        ),
    },
    FlagDoc {
        bit: 10,
        name: Cow::Borrowed("velocity_replaced"),
        meaning: Cow::Borrowed(
            "reported velocity disagreed with the positions; the estimate from positions was used",
        ),
    },
    FlagDoc {
        bit: 11,
        name: Cow::Borrowed("force_slew_limited"),
        meaning: Cow::Borrowed("the force's rise was limited by the slew rate"),
    },
    FlagDoc {
        bit: 12,
        name: Cow::Borrowed("stale_state"),
        meaning: Cow::Borrowed("no fresh device state for several periods: zero commanded"),
    },
    FlagDoc {
        bit: 13,
        name: Cow::Borrowed("device_faulted"),
        meaning: Cow::Borrowed("a device fault that needs a person is active"),
    },
];

/// One servo tick, as recorded. `Copy` and heap-free: the servo thread writes it into an SPSC ring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceSample {
    /// Tick number since the run started; strictly increasing in a trace (gaps mean skipped ticks).
    pub tick: u64,
    /// Time of the tick since the run started (s), >= 0.
    pub t_s: f64,
    /// Probe (device) position (m).
    pub probe_m: DVec3,
    /// Proxy position after the solve (m).
    pub proxy_m: DVec3,
    /// Force sent to the device (N).
    pub force_n: DVec3,
    /// Primitives each mode emitted this tick; slots at and past `mode_count` are ignored and read back
    /// as 0.
    pub primitives_per_mode: [u16; MAX_MODES],
    /// How many modes the scene has; must equal the trace's `TraceMeta::mode_names` length.
    pub mode_count: u8,
    /// Solver sweeps this tick.
    pub sweeps: u32,
    /// Certificate bound on the proxy's distance from the exact equilibrium (m), >= 0; `+inf` when the
    /// solver produced no certificate.
    pub error_bound_m: f64,
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
            proxy_m: DVec3::ZERO,
            force_n: DVec3::ZERO,
            primitives_per_mode: [0; MAX_MODES],
            mode_count,
            sweeps: 0,
            error_bound_m: 0.0,
            flags: 0,
        }
    }

    /// The primitive counts of the modes in use.
    pub fn primitives(&self) -> &[u16] {
        &self.primitives_per_mode[..usize::from(self.mode_count).min(MAX_MODES)]
    }
}

/// On-disk format of a trace. `--format csv|mcap` on the command line, `"csv"`/`"mcap"` in files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum TraceFormat {
    /// Comma-separated text, one row per tick.
    Csv,
    /// MCAP: voxhap's JSON-encoded state and solver messages, plus the probe, proxy and force as Foxglove
    /// protobuf messages; readable by the `mcap` Python package, Foxglove and Lichtblick.
    Mcap,
}

impl TraceFormat {
    /// Guesses the format from a file name: `.mcap` is MCAP, anything else CSV.
    pub fn from_path(path: &Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(ext) if ext.eq_ignore_ascii_case("mcap") => TraceFormat::Mcap,
            _ => TraceFormat::Csv,
        }
    }
}

impl fmt::Display for TraceFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            TraceFormat::Csv => "csv",
            TraceFormat::Mcap => "mcap",
        })
    }
}

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
pub trait TraceWriter: Send {
    /// Checks and appends one sample. Errors name the tick and the problem.
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError>;
    /// Pushes buffered data to the file so a reader (or a crash) sees everything written so far.
    fn flush(&mut self) -> Result<(), TraceError>;
    /// Writes the trailer (MCAP summary), flushes, and rewrites the sidecar with the final sample count.
    fn finish(&mut self) -> Result<TraceSummary, TraceError>;
    /// Samples written so far.
    fn sample_count(&self) -> u64;
}

/// Creates `path` (and `path.json`) in `format` for a run described by `meta`.
pub fn create_trace_writer(
    path: &Path,
    format: TraceFormat,
    meta: &TraceMeta,
) -> Result<Box<dyn TraceWriter>, TraceError> {
    Ok(match format {
        TraceFormat::Csv => Box::new(CsvTraceWriter::create(path, meta)?),
        TraceFormat::Mcap => Box::new(McapTraceWriter::create(path, meta)?),
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
}

/// Opens a trace (or sidecar) for reading: a regular file only, so a FIFO or a device (`replay:/dev/zero`)
/// is refused at once instead of blocking or reading without end.
pub(crate) fn open_trace_file(path: &Path) -> Result<(std::fs::File, u64), TraceReadError> {
    crate::volume::io::open_regular(path).map_err(|error| TraceReadError::Io {
        path: path.to_path_buf(),
        source: match error {
            crate::volume::io::FileError::Io(source) => source,
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

/// Reads a CSV or MCAP trace, choosing by the file's first bytes (the MCAP magic) rather than its name.
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
    } else {
        read_csv_trace(path)
    }
}

/// Checks one sample against the trace's rules; shared by both writers.
#[derive(Clone, Debug)]
struct SampleChecker {
    mode_count: usize,
    last_tick: Option<u64>,
    count: u64,
    finished: bool,
}

impl SampleChecker {
    fn new(mode_count: usize) -> Self {
        SampleChecker {
            mode_count,
            last_tick: None,
            count: 0,
            finished: false,
        }
    }

    fn check(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        if self.finished {
            return Err(TraceError::Finished);
        }
        check_sample(sample, self.mode_count, self.last_tick)?;
        self.last_tick = Some(sample.tick);
        self.count += 1;
        Ok(())
    }
}

/// The rules every recorded sample obeys (the reader applies the same ones).
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
    let finite_fields: [(&'static str, bool); 4] = [
        ("t_s", sample.t_s.is_finite()),
        ("probe_m", sample.probe_m.is_finite()),
        ("proxy_m", sample.proxy_m.is_finite()),
        ("force_n", sample.force_n.is_finite()),
    ];
    for (field, finite) in finite_fields {
        if !finite {
            return Err(TraceError::NonFinite { tick, field });
        }
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
                TraceSample {
                    tick: i * 2,
                    t_s,
                    probe_m,
                    proxy_m,
                    force_n: (proxy_m - probe_m) * 500.0 + DVec3::new(-0.0, 1e-300, 0.1),
                    primitives_per_mode,
                    mode_count,
                    sweeps: (i % 5) as u32,
                    error_bound_m: if i % 7 == 3 {
                        f64::INFINITY
                    } else {
                        1e-17 * (i as f64 + 1.0).powi(3)
                    },
                    flags: (i % 4) as u32,
                }
            })
            .collect()
    }
}
