//! The servo session's outside face: what a server, a CLI or a test reads from a running servo loop
//! ([`Snapshot`], [`StatsReport`], [`SceneReport`], a [`Slice`] of a volume) and what it may ask of it ([`ControlCommand`]).
//!
//! Where it sits (docs/design.md, "Threads"): the servo thread publishes a [`Snapshot`] through a triple buffer
//! every tick and keeps its statistics in atomics; [`SessionApi`] is the non-real-time side of those
//! boundaries. Control commands are validated and turned into ready-built scenes here, off the servo
//! thread, then handed over through an SPSC ring and applied at a tick boundary. Nothing in this module
//! runs on the servo thread except filling a `Snapshot` (`Copy`, no heap).
//!
//! The HTTP/WebSocket server is written against the [`SessionApi`] trait, so it can be tested
//! against the real session and knows nothing about threads or rings.

pub mod folders;
pub mod link_delay;
pub mod slice;
pub mod truth;

pub use link_delay::LinkDelayReport;
pub use truth::{
    crtk_operating_state, DeviceLocal, EnergyReport, ForceOffCause, TickEnergy, TickTruth,
};

use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use voxhap_core::haptics::modes::{ModeConfig, TransferFunction, MAX_MODES};
use voxhap_core::haptics::tick::TickStatus;
use voxhap_core::haptics::{Primitive, PrimitiveKind};
use voxhap_core::status::OutputState;
use voxhap_core::volume::AnyVolume;

/// One primitive the solver used this tick, as plain data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PrimitiveView {
    /// `point`, `line`, `plane` or `directed`.
    pub kind: PrimitiveKind,
    /// Index of the mode that emitted it.
    pub mode: u8,
    /// A point of the primitive (m); zero for `directed`.
    pub position_m: DVec3,
    /// Unit direction (line direction, plane normal, directed force direction); zero for `point`.
    pub direction: DVec3,
    /// Strength s (N).
    pub strength_n: f64,
}

impl PrimitiveView {
    /// The view of `primitive`, emitted by mode `mode`.
    pub fn new(primitive: &Primitive, mode: u8) -> Self {
        PrimitiveView {
            kind: primitive.kind(),
            mode,
            position_m: primitive.position_m(),
            direction: primitive.direction(),
            strength_n: primitive.strength_n(),
        }
    }
}

/// The servo loop's newest state, published every tick (triple buffer). `Copy`, fixed size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Snapshot {
    /// Ticks since the session started (gaps in a sequence of snapshots are ticks not looked at, or ticks
    /// skipped after an overrun).
    pub tick: u64,
    /// Time of this tick since the session started (s).
    pub t_s: f64,
    /// Probe (device) position (m).
    pub probe_m: DVec3,
    /// Probe velocity as the device reports it (m/s).
    pub probe_velocity_m_per_s: DVec3,
    /// Proxy position after the solve (m).
    pub proxy_m: DVec3,
    /// Force the tick rendered: coupling spring plus damping (N), before safety.
    pub rendered_force_n: DVec3,
    /// Force actually sent to the device after the safety pipeline (N).
    pub sent_force_n: DVec3,
    /// Primitives of this tick; only the first `primitive_count` are valid ([`Snapshot::primitives`]).
    #[serde(skip)]
    pub primitive_slots: [Option<PrimitiveView>; MAX_MODES],
    pub primitive_count: u8,
    /// Certified bound on the proxy's distance from the exact equilibrium (m); `+inf` (serialised as
    /// `null`) without a certificate.
    pub error_bound_m: f64,
    /// How the solve ended.
    pub status: TickStatus,
    /// Solver sweeps this tick.
    pub sweeps: u32,
    /// Coupling stiffness in use (N/m).
    pub stiffness_n_per_m: f64,
    /// Coupling damping in use (N s/m).
    pub damping_n_s_per_m: f64,
    /// True while the device is connected and enabled.
    pub connected: bool,
    /// True once the safety pipeline passes forces at full strength.
    pub engaged: bool,
    /// Where the output stands (why force is or is not reaching the hand).
    pub output_state: OutputState,
    /// Latched faults the device last reported (bit n = fault code n).
    pub active_faults: u16,
    /// `FLAG_*` bits of the trace format for this tick.
    pub flags: u32,
    /// Incremented every time a command changes the scene (k, damping, modes, volume).
    pub scene_generation: u64,
    /// Simulated arm only: where the virtual hand is being pulled to (m, scene frame), when a client set it.
    pub hand_target_m: Option<DVec3>,
    /// The tick's truth: energy ledger, force-off cause, device faults, sample age ([`truth`]).
    pub truth: TickTruth,
}

#[cfg(any(test, feature = "test-support"))]
impl Snapshot {
    /// A plausible certified tick with no primitives, for tests that build messages from a snapshot and
    /// change the fields they look at (`Snapshot { tick: 42, ..Snapshot::example() }`).
    pub fn example() -> Snapshot {
        Snapshot {
            tick: 5,
            t_s: 0.005,
            probe_m: DVec3::X,
            probe_velocity_m_per_s: DVec3::ZERO,
            proxy_m: DVec3::Y,
            rendered_force_n: DVec3::Z,
            sent_force_n: DVec3::Z,
            primitive_slots: [None; MAX_MODES],
            primitive_count: 0,
            error_bound_m: 0.0,
            status: TickStatus::Certified,
            sweeps: 2,
            stiffness_n_per_m: 500.0,
            damping_n_s_per_m: 0.0,
            connected: true,
            engaged: true,
            output_state: OutputState::Engaged,
            active_faults: 0,
            flags: 0,
            scene_generation: 1,
            hand_target_m: None,
            truth: TickTruth::default(),
        }
    }
}

impl Snapshot {
    /// The valid primitives of this tick.
    pub fn primitives(&self) -> impl Iterator<Item = &PrimitiveView> {
        self.primitive_slots[..usize::from(self.primitive_count).min(MAX_MODES)]
            .iter()
            .flatten()
    }
}

/// Percentiles of one histogram (µs).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct HistogramReport {
    pub count: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
}

/// The servo loop's statistics since it started (or since `reset`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct StatsReport {
    /// Loop rate (Hz).
    pub rate_hz: f64,
    /// Ticks run.
    pub ticks: u64,
    /// How late each tick started after its deadline.
    pub lateness: HistogramReport,
    /// Compute time of each tick: commands, modes, solve and coupling force (the pure tick), from the tick's
    /// start to the force being ready for the safety pipeline.
    pub compute: HistogramReport,
    /// Time of each tick's device exchange: safety pipeline, write force, read state (for the simulated
    /// arm this includes stepping its physics).
    pub device: HistogramReport,
    /// Ticks that started after the next deadline had already passed (schedule skipped).
    pub overruns: u64,
    /// Ticks skipped by those overruns.
    pub skipped_ticks: u64,
    /// Ticks whose compute exceeded its budget (the last safe force went out instead).
    pub budget_overruns: u64,
    /// Most solver sweeps in one tick.
    pub max_sweeps: u32,
    /// Worst certificate bound of a tick (m).
    pub worst_error_bound_m: f64,
    /// Device errors (timeouts, disconnects, protocol errors).
    pub device_errors: u64,
    /// Device disconnects.
    pub disconnects: u64,
    /// Samples the recorder ring had no room for.
    pub recorder_drops: u64,
    /// Trace writer errors (disk full, I/O error): each stops the recording; the message is on stderr
    /// and in the trace's sidecar.
    pub recorder_errors: u64,
    /// Commands applied at tick boundaries.
    pub commands_applied: u64,
    /// Which real-time features the thread got (`SCHED_FIFO`, memory lock, pinned core).
    pub realtime: RealtimeReport,
    /// What the safety pipeline and the device's status did (README "Safety").
    pub safety: SafetyReport,
    /// The energy ledger's totals and verdicts so far ([`truth`]).
    pub energy: EnergyReport,
    /// The device link's delay: declared at open, timed every tick, and the observer's pairing ([`link_delay`]).
    pub link_delay: LinkDelayReport,
}

/// The safety side of the statistics: where the output stands and what every safety rule did so far.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct SafetyReport {
    /// Where the output stands now.
    pub output_state: OutputState,
    /// What that means for the operator.
    pub output_state_explanation: &'static str,
    /// Latched faults the device last reported (bit n = fault code n).
    pub active_faults: u16,
    /// Faults the device reported (its watchdog included).
    pub device_faults: u64,
    /// Device watchdog trips among them (re-enabled automatically).
    pub device_watchdog_trips: u64,
    /// Commands the device refused.
    pub device_rejections: u64,
    /// Enables sent.
    pub enables: u64,
    /// Ticks on which the device was not accepting force (zero sent, flagged in the trace).
    pub not_enabled_ticks: u64,
    /// Ticks on which zero was sent because the device's state was stale.
    pub stale_ticks: u64,
    /// Device positions rejected as implausible (held).
    pub positions_rejected: u64,
    /// Reported velocities replaced by the estimate.
    pub velocities_replaced: u64,
    /// Ticks whose force rise was slew-limited.
    pub slew_limited_ticks: u64,
    /// Forces clamped to the device maximum.
    pub forces_clamped: u64,
    /// Stops by the stall monitor (counted by the monitor).
    pub monitor_stops: u64,
    /// Device events the servo thread could not hand to the reporter (ring full).
    pub events_dropped: u64,
    /// Messages the device sent beyond what its protocol answers commands with (read, the newest used).
    pub device_surplus: u64,
}

/// What the servo thread was granted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct RealtimeReport {
    pub sched_fifo: bool,
    pub memory_locked: bool,
    pub pinned_cpu: Option<u32>,
}

impl RealtimeReport {
    /// The line the statistics tables end with: `real time: SCHED_FIFO yes, memory locked yes, pinned CPU 1`.
    pub fn summary(&self) -> String {
        let yes_no = |value: bool| if value { "yes" } else { "no" };
        format!(
            "real time: SCHED_FIFO {}, memory locked {}, pinned CPU {}",
            yes_no(self.sched_fifo),
            yes_no(self.memory_locked),
            self.pinned_cpu.map_or("no".to_owned(), |c| c.to_string())
        )
    }
}

impl StatsReport {
    /// The table `voxhap serve` prints on exit and `voxhap bench-loop` prints.
    pub fn table(&self) -> String {
        let row = |name: &str, h: &HistogramReport| {
            format!(
                "{name:<10} {:>10} {:>10.1} {:>10.1} {:>10.1} {:>10.1}\n",
                h.count, h.p50_us, h.p99_us, h.p999_us, h.max_us
            )
        };
        let mut text = format!(
            "{:<10} {:>10} {:>10} {:>10} {:>10} {:>10}\n",
            "(us)", "count", "p50", "p99", "p99.9", "max"
        );
        text += &row("lateness", &self.lateness);
        text += &row("compute", &self.compute);
        text += &row("device", &self.device);
        text += &format!(
            "rate {} Hz, ticks {}, overruns {} (skipped {} ticks), compute over budget {}\n",
            self.rate_hz, self.ticks, self.overruns, self.skipped_ticks, self.budget_overruns
        );
        text += &format!(
            "solver: max sweeps {}, worst certificate bound {:.3e} m\n",
            self.max_sweeps, self.worst_error_bound_m
        );
        text += &format!(
            "device errors {}, disconnects {}, recorder drops {}, recorder errors {}, commands applied {}\n",
            self.device_errors,
            self.disconnects,
            self.recorder_drops,
            self.recorder_errors,
            self.commands_applied
        );
        let safety = &self.safety;
        text += &format!(
            "safety: output {} ({}); device faults {} (watchdog {}), refusals {}, enables {}, ticks not enabled {}, \
             stale {}, positions rejected {}, velocities replaced {}, slew-limited {}, clamped {}, monitor stops {}, \
             surplus device messages {}\n",
            safety.output_state.name(),
            safety.output_state_explanation,
            safety.device_faults,
            safety.device_watchdog_trips,
            safety.device_rejections,
            safety.enables,
            safety.not_enabled_ticks,
            safety.stale_ticks,
            safety.positions_rejected,
            safety.velocities_replaced,
            safety.slew_limited_ticks,
            safety.forces_clamped,
            safety.monitor_stops,
            safety.device_surplus,
        );
        text += &self.energy.summary();
        text += &self.link_delay.summary();
        text += &self.realtime.summary();
        text
    }
}

/// The scene as configured now (off the real-time path; for clients that show controls).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneReport {
    pub stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    /// The modes, in order, with their settings.
    pub modes: Vec<ModeConfig>,
    /// Volume names and where they came from (`builtin:sphere`, a file path).
    pub volumes: Vec<VolumeReport>,
    /// The device spec the session was started with (`sim`, `mock:/dev/pts/3`, ...).
    pub device: String,
    /// True when the device is the in-process simulated arm (hand target commands work).
    pub simulated: bool,
    /// The trace being recorded, if any (it stays named after a write error stopped it, until a stop).
    pub recording: Option<PathBuf>,
    /// Why the last recording stopped early (the writer's error with the OS reason, e.g. `No space left
    /// on device`), once one did: the session goes on unrecorded, `recorder_errors` in the statistics
    /// counts it, and `voxhap serve` exits non-zero at the end.
    pub recording_error: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VolumeReport {
    pub name: String,
    pub source: String,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// `scalar` or `vector`.
    pub kind: &'static str,
    /// World-space bounding box (m).
    pub min_m: DVec3,
    pub max_m: DVec3,
}

/// A request to change a running session. JSON: `{"command": "set_stiffness", "k": 400}` etc.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "command", rename_all = "snake_case", deny_unknown_fields)]
pub enum ControlCommand {
    /// Coupling stiffness k (N/m), finite, > 0 and at most the device's maximum.
    SetStiffness { k: f64 },
    /// Coupling damping b (N s/m), finite, >= 0.
    SetDamping { damping: f64 },
    /// Stiffness and damping together (`POST /api/stiffness` with both): both are checked, the damping against
    /// the new stiffness, before either is applied; a refusal changes nothing. Not a wire command.
    #[serde(skip)]
    SetCoupling { k: f64, damping: f64 },
    /// Replace the transfer function of the mode named `mode`.
    SetTransfer {
        mode: String,
        transfer: TransferFunction,
    },
    /// Switch the mode named `mode` on or off. Off keeps its breakpoints (and every other setting) and
    /// renders no force; allowed while recording (the trace keeps its columns).
    SetModeEnabled { mode: String, enabled: bool },
    /// Add a mode (scene-file syntax) at the end.
    AddMode { mode: ModeConfig },
    /// Remove the mode named `name` (modes that depend on it, like friction, must go first).
    RemoveMode { name: String },
    /// Load a volume file (or `builtin:NAME`) and swap it in for the volume named `name` (default: the first
    /// volume).
    LoadVolume {
        path: PathBuf,
        #[serde(default)]
        name: Option<String>,
    },
    /// Start recording every tick to `path` (format from `format` or the file extension). Through
    /// `voxhap serve`'s servers `path` is a plain file name in the `--record-dir` folder ([`RecordDir`]).
    StartRecording {
        path: PathBuf,
        #[serde(default)]
        format: Option<TraceFormat>,
    },
    /// Stop recording; the trace is flushed and closed.
    StopRecording,
    /// Simulated arm only: pull the virtual hand towards `position_m` (m, scene frame: mapped through the
    /// session's workspace mapping into the device frame), or `null` to resume its path.
    SetHandTarget { position_m: Option<[f64; 3]> },
    /// The operator's explicit acknowledgement of a device fault that needs a person: ClearFault goes to the
    /// device, which is then enabled again (forces ramp in) once the link is healthy. voxhap never sends
    /// ClearFault by itself.
    ClearFault,
    /// Only with `serve --external-force`: a force (N, scene frame) added to the rendered force before the
    /// safety pipeline, for the staleness timeout from now (then zero unless sent again). Finite, magnitude
    /// at most 1000 N; the device's own limits apply to the sum.
    SetExternalForce { force_n: [f64; 3] },
}

/// What a successful command did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ControlReply {
    /// Human-readable summary: `stiffness set to 400 N/m`.
    pub message: String,
    /// The scene generation the change produced (0 when the scene did not change).
    pub scene_generation: u64,
}

/// Why a command was refused. A refused command changed nothing.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControlError {
    /// A value out of range, not finite, or a scene that does not build (the message says which key).
    #[error("invalid: {0}")]
    Invalid(String),
    /// A mode, volume or file that does not exist.
    #[error("not found: {0}")]
    NotFound(String),
    /// Not possible in the current state (already recording, not the simulated arm, ...).
    #[error("conflict: {0}")]
    Conflict(String),
    /// The servo did not take the command in time (stopped, or its command ring is full).
    #[error("unavailable: {0}")]
    Unavailable(String),
}

impl ControlError {
    /// The HTTP status a server should answer with.
    pub fn http_status(&self) -> u16 {
        match self {
            ControlError::Invalid(_) => 400,
            ControlError::NotFound(_) => 404,
            ControlError::Conflict(_) => 409,
            ControlError::Unavailable(_) => 503,
        }
    }
}

/// The axis a slice is normal to: `z` gives the x-y plane (top view), `y` the x-z plane, `x` the y-z plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SliceAxis {
    X,
    Y,
    Z,
}

impl SliceAxis {
    /// `x`, `y` or `z`.
    pub fn name(self) -> &'static str {
        match self {
            SliceAxis::X => "x",
            SliceAxis::Y => "y",
            SliceAxis::Z => "z",
        }
    }
}

impl std::str::FromStr for SliceAxis {
    type Err = ControlError;

    fn from_str(text: &str) -> Result<Self, ControlError> {
        match text {
            "x" => Ok(SliceAxis::X),
            "y" => Ok(SliceAxis::Y),
            "z" => Ok(SliceAxis::Z),
            other => Err(ControlError::Invalid(format!(
                "axis must be x, y or z, got {other:?}"
            ))),
        }
    }
}

/// Samples per side of a slice: smallest, largest and default.
pub const SLICE_SIZE_RANGE: (usize, usize) = (16, 512);
pub const SLICE_SIZE_DEFAULT: usize = 128;

/// What part of a volume to sample ([`SessionApi::slice`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SliceRequest {
    pub axis: SliceAxis,
    /// Samples per side, [`SLICE_SIZE_RANGE`].
    pub size: usize,
    /// A point of the plane (m); default the latest proxy position (the volume's centre before the first
    /// tick).
    pub at_m: Option<DVec3>,
    /// The volume to sample; default the scene's first scalar volume. A vector volume gives its magnitude.
    pub volume: Option<String>,
}

/// What a request leaves out: a `SLICE_SIZE_DEFAULT` slice normal to `z` through the proxy, of the first
/// scalar volume (the protocol's defaults; every decoder starts from these).
impl Default for SliceRequest {
    fn default() -> Self {
        SliceRequest {
            axis: SliceAxis::Z,
            size: SLICE_SIZE_DEFAULT,
            at_m: None,
            volume: None,
        }
    }
}

/// An axis-aligned plane of a volume sampled on a regular `width` x `height` grid spanning the volume's
/// bounding box: sample `(i, j)` is at `origin_m + i u_m + j v_m` and is `values[j * width + i]` (row-major, v
/// outer). Off the real-time path.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Slice {
    pub axis: SliceAxis,
    pub width: usize,
    pub height: usize,
    /// World position of sample (0, 0) (m).
    pub origin_m: DVec3,
    /// Step between neighbouring samples along the width (m).
    pub u_m: DVec3,
    /// Step between neighbouring samples along the height (m).
    pub v_m: DVec3,
    /// Smallest and largest value in `values`.
    pub min: f32,
    pub max: f32,
    pub values: Vec<f32>,
    /// The volume sampled, `scalar` or `vector` (a vector volume gives its magnitude), and its bounding box.
    pub volume: String,
    pub volume_kind: &'static str,
    pub volume_min_m: DVec3,
    pub volume_max_m: DVec3,
}

voxhap_core::named_enum! {
    /// On-disk format of a trace. `--format csv|mcap` on the command line, `"csv"`/`"mcap"` in files.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(rename_all = "lowercase")]
    pub enum TraceFormat {
        /// Comma-separated text, one row per tick.
        Csv => "csv",
        /// MCAP: voxhap's JSON-encoded state and solver messages, plus the probe, proxy and force as Foxglove
        /// protobuf messages; readable by the `mcap` Python package, Foxglove and Lichtblick.
        Mcap => "mcap",
        /// Apache Parquet: the CSV columns, typed and compressed, one row group per second; readable by
        /// pandas, polars and DuckDB.
        Parquet => "parquet",
    }
}

impl TraceFormat {
    /// Guesses the format from a file name: `.mcap` is MCAP, `.parquet` Parquet, anything else CSV.
    pub fn from_path(path: &std::path::Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(ext) if ext.eq_ignore_ascii_case("mcap") => TraceFormat::Mcap,
            Some(ext) if ext.eq_ignore_ascii_case("parquet") => TraceFormat::Parquet,
            _ => TraceFormat::Csv,
        }
    }
}

impl std::fmt::Display for TraceFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A volume with where it came from.
#[derive(Debug, Clone)]
pub struct NamedVolume {
    pub name: String,
    pub source: String,
    pub volume: AnyVolume,
}

impl NamedVolume {
    pub fn report(&self) -> VolumeReport {
        let grid = self.volume.grid();
        let (min_m, max_m) = grid.bounds_world();
        VolumeReport {
            name: self.name.clone(),
            source: self.source.clone(),
            dims: grid.dims(),
            kind: self.volume.kind(),
            min_m,
            max_m,
        }
    }
}

/// A running session as a server sees it. Every method is cheap and never blocks the servo thread.
pub trait SessionApi: Send + Sync + 'static {
    /// The newest published state; `None` before the first tick.
    fn snapshot(&self) -> Option<Snapshot>;
    /// Statistics so far.
    fn stats(&self) -> StatsReport;
    /// The scene as configured now.
    fn scene(&self) -> SceneReport;
    /// Validates and applies `command`; returns once the servo thread has taken it (or refused).
    fn control(&self, command: ControlCommand) -> Result<ControlReply, ControlError>;
    /// Samples a plane of a volume of the scene (off the servo thread; may take milliseconds for a large
    /// `size`, so async callers run it on a blocking thread). Bad requests are [`ControlError::Invalid`], an
    /// unknown volume [`ControlError::NotFound`].
    fn slice(&self, request: SliceRequest) -> Result<Slice, ControlError>;
}
