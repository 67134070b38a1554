//! MCAP force traces: the writer ([`McapTraceWriter`]) and a reader ([`for_each_mcap_sample`](crate::mcap_read::for_each_mcap_sample)).
//!
//! File layout (uncompressed chunks, message indexes and a summary, so any MCAP reader can seek):
//!
//! * two channels, one per message kind, both with `json` message encoding and a `jsonschema` schema:
//!   [`STATE_TOPIC`] (`voxhap.State`: tick, t_s, utc_ns, probe_m, probe_velocity_m_per_s, proxy_m,
//!   rendered_force_n, force_n, vectors as `[x, y, z]`) and [`SOLVER_TOPIC`] (`voxhap.Solver`: tick, t_s,
//!   primitives and mode_force_n as objects keyed by mode name in mode order, solver_status, sweeps,
//!   error_bound_m (omitted when +inf), device_sequence and device_time_us (omitted when the device has
//!   none), flag_bits, truth: the tick's energy ledger, force-off cause, device fault bits and sample age,
//!   named as the CSV columns). The schemas use only the plain types Foxglove and Lichtblick accept (no
//!   `["number", "null"]` unions): a value that may be absent is an optional field, left out when absent.
//!   JSON has no NaN: a non-finite number in a sample flagged `invalid_values` is written as `null` and
//!   read back as NaN;
//! * three more channels with the Foxglove SDK's protobuf schemas, the same topics the live view publishes
//!   (`voxhap_view::topics`, CRTK names), so Foxglove and Lichtblick show a recording like a live
//!   session: `/voxhap/measured_cp` and `/voxhap/setpoint_cp` (`foxglove.FrameTransform`, frames `probe`
//!   and `proxy` in `world`, translation in m) and `/voxhap/setpoint_cf` (`foxglove.Vector3`, the sent force
//!   in N), one message per tick. The transforms' own timestamps equal the log time;
//! * the scene topics ([`RecordedScene`]): `/voxhap/volume` and `/voxhap/volume_frame` at the start and
//!   again when a scene change loads another volume ([`TraceWriter::scene_changed`]; the volume's bounds,
//!   iso-surface and camera framing), `/voxhap/primitives` (markers and the tick's primitives), `/voxhap/bound` and
//!   `/voxhap/operating_state` from the servo's snapshots ([`TraceWriter::scene_frame`], at most 60 Hz of
//!   tick time), the slices `/voxhap/volume/slice_x`, `_y`, `_z` 4 times a second, `/voxhap/stats`
//!   (`voxhap.TraceStats`) once a second;
//! * `log_time = publish_time` = wall-clock UTC (ns since the Unix epoch): the wall time at which the
//!   writer was created for the first sample, plus the tick time since the first sample for the others,
//!   so recordings line up with other instruments ([`log_time_start_ns`]: a trace whose `created_utc` was
//!   set to another time, as tests and reproducible runs do, starts at that time instead, so two such runs
//!   write identical files); `sequence` = the sample's index in the trace;
//! * one metadata record named [`METADATA_NAME`] with the sidecar's metadata fields as strings (JSON for
//!   the ones that are not strings).
//!
//! Crash safety: every [`TraceWriter::flush`] (the recorder flushes every 250 ms; `voxhap sim` every
//! 1000 ticks) closes the current chunk, and so does the first whole tick that takes a chunk past 1 MiB;
//! chunks always end between ticks. A crash loses at most the messages since then. A file without its
//! summary and end magic (the writer never finished) is read up to the last complete chunk, with a
//! warning, and to the last tick whose messages all made it (files from writers that cut chunks inside a
//! tick are read that way too); `voxhap trace repair` rewrites it as a finished file. After a write error
//! nothing more reaches the file and the sidecar counts the samples in closed chunks, exactly what a
//! reader recovers.
//!
//! The writer library string is `voxhap <version>` and the profile is empty. Numbers are written by
//! serde_json (shortest round-trip) and parsed with its `float_roundtrip` feature, so the reader
//! recovers the exact bits.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::ser::SerializeMap;
use serde::{Serialize, Serializer};

use ::foxglove::messages::{FrameTransform, Vector3};
use ::foxglove::Encode;

use crate::columns::{utc_cell, Cell};
use crate::error::TraceError;
use crate::foxglove_scene::RecordedScene;
use crate::meta::{Sidecar, TraceMeta, TraceSummary};
use crate::output::{OutputFile, StopSwitch};
use crate::sample::{SampleChecker, SolverStatus, TraceSample};
use crate::writer::TraceWriter;
use voxhap_api::TraceFormat;
use voxhap_view::topics::{
    frame_transform, set_translation, vector3, MEASURED_CP_TOPIC as PROBE_TOPIC, PROBE_FRAME,
    PROXY_FRAME, SETPOINT_CF_TOPIC as FORCE_TOPIC, SETPOINT_CP_TOPIC as PROXY_TOPIC,
};

/// Topic of the per-tick state messages (positions and force).
pub const STATE_TOPIC: &str = "/voxhap/state";
/// Topic of the per-tick solver messages (primitive counts, effort, certificate, flags).
pub const SOLVER_TOPIC: &str = "/voxhap/solver";
/// Name of the metadata record.
pub const METADATA_NAME: &str = "voxhap_trace";

const STATE_SCHEMA_NAME: &str = "voxhap.State";
const SOLVER_SCHEMA_NAME: &str = "voxhap.Solver";

fn state_schema() -> serde_json::Value {
    let vector = |description: &str| {
        serde_json::json!({
            "type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
            "description": description
        })
    };
    tick_message_schema(
        STATE_SCHEMA_NAME,
        serde_json::json!({
            "utc_ns": {"type": "integer", "description": "wall-clock UTC of the tick (ns since 1970); omitted when the run has no start time"},
            "probe_m": vector("probe (device) position [x, y, z] (m)"),
            "probe_velocity_m_per_s": vector("probe velocity [x, y, z] (m/s), reported or estimated"),
            "proxy_m": vector("proxy position [x, y, z] (m)"),
            "rendered_force_n": vector("force rendered before the safety pipeline [x, y, z] (N)"),
            "force_n": vector("force sent to the device [x, y, z] (N)")
        }),
        &[
            "probe_m",
            "probe_velocity_m_per_s",
            "proxy_m",
            "rendered_force_n",
            "force_n",
        ],
    )
}

fn solver_schema(mode_names: &[String]) -> serde_json::Value {
    let modes: serde_json::Map<String, serde_json::Value> = mode_names
        .iter()
        .map(|name| {
            (
                name.clone(),
                serde_json::json!({"type": "integer", "minimum": 0, "maximum": 65535}),
            )
        })
        .collect();
    let mode_forces: serde_json::Map<String, serde_json::Value> = mode_names
        .iter()
        .map(|name| {
            (
                name.clone(),
                serde_json::json!({
                    "type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
                    "description": "null for a non-finite value in a sample flagged invalid_values"
                }),
            )
        })
        .collect();
    let statuses: Vec<&str> = SolverStatus::ALL.iter().map(|s| s.name()).collect();
    tick_message_schema(
        SOLVER_SCHEMA_NAME,
        serde_json::json!({
            "primitives": {
                "type": "object", "properties": modes, "additionalProperties": false,
                "description": "primitives each haptic mode emitted this tick"
            },
            "mode_force_n": {
                "type": "object", "properties": mode_forces, "additionalProperties": false,
                "description": "force each mode's primitives exert on the proxy [x, y, z] (N)"
            },
            "solver_status": {"type": "string", "enum": statuses, "description": "how the solve ended"},
            "sweeps": {"type": "integer", "minimum": 0, "description": "solver sweeps"},
            "error_bound_m": {
                "type": "number", "minimum": 0,
                "description": "certificate bound on the proxy's distance from the equilibrium (m); omitted = none"
            },
            "device_sequence": {"type": "integer", "minimum": 0, "description": "the device's sequence number; omitted = none"},
            "device_time_us": {"type": "integer", "minimum": 0, "description": "the device's clock (us); omitted = none"},
            "flag_bits": {"type": "integer", "minimum": 0, "description": "bit set, see the sidecar's flag_bits"},
            "truth": crate::truth_columns::truth_schema()
        }),
        &[
            "primitives",
            "mode_force_n",
            "solver_status",
            "sweeps",
            "flag_bits",
            "truth",
        ],
    )
}

/// The JSON schema of a per-tick message titled `title`: the properties `tick` and `t_s`, then those of the
/// object `properties`; `tick`, `t_s` and the names in `required` are required.
fn tick_message_schema(
    title: &str,
    properties: serde_json::Value,
    required: &[&str],
) -> serde_json::Value {
    let mut all = serde_json::Map::new();
    all.insert(
        "tick".to_owned(),
        serde_json::json!({"type": "integer", "minimum": 0, "description": "servo tick number"}),
    );
    all.insert(
        "t_s".to_owned(),
        serde_json::json!({"type": "number", "description": "tick time since the run started (s)"}),
    );
    if let serde_json::Value::Object(rest) = properties {
        all.extend(rest);
    }
    let mut schema = voxhap_view::messages::message_schema(title, serde_json::Value::Object(all));
    let required: Vec<&str> = ["tick", "t_s"].iter().chain(required).copied().collect();
    schema["required"] = serde_json::json!(required);
    schema
}

#[derive(Serialize)]
struct StateMessage {
    tick: u64,
    t_s: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    utc_ns: Option<i64>,
    probe_m: [f64; 3],
    probe_velocity_m_per_s: [f64; 3],
    proxy_m: [f64; 3],
    rendered_force_n: [f64; 3],
    force_n: [f64; 3],
}

/// Per-mode values (primitive counts, forces) serialised as an object keyed by mode name, in mode order, each
/// value as `json` gives it.
struct ByMode<'a, T, J> {
    names: &'a [String],
    values: &'a [T],
    json: fn(&T) -> J,
}

impl<T, J: Serialize> Serialize for ByMode<'_, T, J> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.names.len()))?;
        for (name, value) in self.names.iter().zip(self.values) {
            map.serialize_entry(name, &(self.json)(value))?;
        }
        map.end()
    }
}

#[derive(Serialize)]
struct SolverMessage<'a> {
    tick: u64,
    t_s: f64,
    primitives: ByMode<'a, u16, u16>,
    mode_force_n: ByMode<'a, DVec3, [f64; 3]>,
    solver_status: &'static str,
    sweeps: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    error_bound_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    device_sequence: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    device_time_us: Option<u64>,
    flag_bits: u32,
    truth: crate::truth_columns::TruthMessage,
}

/// Writes an MCAP trace and its sidecar.
pub struct McapTraceWriter {
    path: PathBuf,
    writer: Option<mcap::Writer<BufWriter<OutputFile>>>,
    /// Stops the file at the first failure, so nothing reaches it afterwards.
    stop: StopSwitch,
    /// Samples in chunks that were closed and handed to the file: the count the sidecar gives.
    committed: u64,
    /// Samples written into the open chunk, and that chunk's message bytes.
    pending: u64,
    chunk_bytes: u64,
    /// The schemas and channels, added with the first sample so that they share its chunk: a chunk holding
    /// only schemas and channels has no message index and no message times, which Foxglove Studio and
    /// Lichtblick's `@mcap/core` refuse ("Chunks without message indexes are not currently supported") or
    /// date to 1970.
    channels: Option<Channels>,
    /// What the channels are made from.
    meta: TraceMeta,
    /// A scene change handed over before the first sample, for the scene once it exists.
    early_change: Option<crate::foxglove_scene::SceneChange>,
    /// The reusable Foxglove messages.
    probe_transform: FrameTransform,
    proxy_transform: FrameTransform,
    mode_names: Vec<String>,
    start_utc_ns: i64,
    message: Vec<u8>,
    checker: SampleChecker,
    sidecar: Sidecar,
    /// The servo's latest snapshot handed over for the scene topics (used with the sample of its tick).
    frame: Option<voxhap_api::Snapshot>,
    /// Wall-clock time (ns since the Unix epoch) of the first sample: log times are UTC wall clock.
    wall_start_ns: u64,
    first_t_s: Option<f64>,
}

/// The channel ids of a trace and its scene topics.
struct Channels {
    state: u16,
    solver: u16,
    probe: u16,
    proxy: u16,
    force: u16,
    /// The scene topics (markers and primitives, volume, slices, bound, operating state, statistics).
    scene: RecordedScene,
}

impl Channels {
    /// Adds the schemas and channels to `writer`.
    fn add<W: std::io::Write + std::io::Seek>(
        writer: &mut mcap::Writer<W>,
        meta: &TraceMeta,
    ) -> Result<Channels, mcap::McapError> {
        let state_schema = writer.add_schema(
            STATE_SCHEMA_NAME,
            "jsonschema",
            state_schema().to_string().as_bytes(),
        )?;
        let solver_schema = writer.add_schema(
            SOLVER_SCHEMA_NAME,
            "jsonschema",
            solver_schema(&meta.mode_names).to_string().as_bytes(),
        )?;
        let no_metadata = BTreeMap::new();
        let state = writer.add_channel(state_schema, STATE_TOPIC, "json", &no_metadata)?;
        let solver = writer.add_channel(solver_schema, SOLVER_TOPIC, "json", &no_metadata)?;
        let (probe, proxy, force) = add_foxglove_channels(writer)?;
        let scene = RecordedScene::add(writer, meta)?;
        Ok(Channels {
            state,
            solver,
            probe,
            proxy,
            force,
            scene,
        })
    }
}

/// A chunk is closed after the first whole tick that takes it past this many message bytes (besides every
/// flush), bounding the memory of a reader and what a crash loses.
const CHUNK_BYTES: u64 = 1 << 20;

/// Wall-clock time (ns since the Unix epoch) of a trace's first sample: `now_ns` for a trace created now
/// (`meta.created_utc` within 2 s of it: a live recording, stamped with the precise clock), else the time
/// `created_utc` names (a trace whose creation time was set, e.g. to make two runs identical).
pub fn log_time_start_ns(meta: &TraceMeta, now_ns: u64) -> u64 {
    match parse_utc_seconds(&meta.created_utc) {
        Some(seconds) if seconds.saturating_mul(1_000_000_000).abs_diff(now_ns) > 2_000_000_000 => {
            seconds.saturating_mul(1_000_000_000)
        }
        _ => now_ns,
    }
}

/// Seconds since 1970 of `YYYY-MM-DDTHH:MM:SS[.fff]Z` (the fraction is ignored); `None` otherwise.
fn parse_utc_seconds(text: &str) -> Option<u64> {
    let text = text.strip_suffix('Z')?;
    let (date, time) = text.split_once('T')?;
    let mut date_parts = date.splitn(3, '-').map(|p| p.parse::<i64>().ok());
    let (year, month, day) = (
        date_parts.next()??,
        date_parts.next()??,
        date_parts.next()??,
    );
    let time = time.split('.').next()?;
    let mut time_parts = time.splitn(3, ':').map(|p| p.parse::<u64>().ok());
    let (hour, minute, second) = (
        time_parts.next()??,
        time_parts.next()??,
        time_parts.next()??,
    );
    if !(1..=12).contains(&month)
        || !(1..=31).contains(&day)
        || hour > 23
        || minute > 59
        || second > 60
    {
        return None;
    }
    // Days from the civil date (Howard Hinnant's algorithm).
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let year_of_era = y.rem_euclid(400);
    let month_shifted = (month + 9) % 12;
    let day_of_year = (153 * month_shifted + 2) / 5 + day - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    let days = u64::try_from(era * 146_097 + day_of_era - 719_468).ok()?;
    Some(days * 86_400 + hour * 3600 + minute * 60 + second)
}

/// Now, in ns since the Unix epoch.
pub fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl McapTraceWriter {
    /// Creates `path` and `path.json`; writes the header, the metadata record and a provisional sidecar.
    /// The schemas and channels follow with the first sample, in its chunk.
    pub fn create(path: &Path, meta: &TraceMeta) -> Result<Self, TraceError> {
        Self::create_at(path, meta, log_time_start_ns(meta, unix_now_ns()))
    }

    /// As [`McapTraceWriter::create`], the first sample logged at `wall_start_ns` (ns since the Unix
    /// epoch) and every later one at that plus its tick time since the first.
    pub fn create_at(
        path: &Path,
        meta: &TraceMeta,
        wall_start_ns: u64,
    ) -> Result<Self, TraceError> {
        meta.validate()?;
        let mcap_error = |source| TraceError::Mcap {
            path: path.to_path_buf(),
            source,
        };
        let stop = StopSwitch::default();
        let file = OutputFile::new(crate::output::create_new_file(path)?, &stop);
        // Chunks close only between ticks (on a flush, or past CHUNK_BYTES after a whole tick), so the
        // samples in closed chunks are exactly what a reader recovers from a file cut after one.
        let options = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(None)
            .profile("")
            .library(format!("voxhap {}", env!("CARGO_PKG_VERSION")));
        let mut writer = options.create(BufWriter::new(file)).map_err(mcap_error)?;
        // The metadata goes before any chunk: written later it would close the open chunk.
        writer
            .write_metadata(&mcap::records::Metadata {
                name: METADATA_NAME.to_string(),
                metadata: metadata_strings(meta)?,
            })
            .map_err(mcap_error)?;
        let sidecar = Sidecar::create(meta, TraceFormat::Mcap, path)?;
        Ok(McapTraceWriter {
            path: path.to_path_buf(),
            writer: Some(writer),
            stop,
            committed: 0,
            pending: 0,
            chunk_bytes: 0,
            channels: None,
            meta: meta.clone(),
            early_change: None,
            probe_transform: frame_transform(PROBE_FRAME, DVec3::ZERO, 0),
            proxy_transform: frame_transform(PROXY_FRAME, DVec3::ZERO, 0),
            mode_names: meta.mode_names.clone(),
            start_utc_ns: meta.start_utc_ns,
            message: Vec::with_capacity(512),
            checker: SampleChecker::new(meta.mode_names.len()),
            sidecar,
            frame: None,
            wall_start_ns,
            first_t_s: None,
        })
    }

    fn mcap_error(&self, source: mcap::McapError) -> TraceError {
        TraceError::Mcap {
            path: self.path.clone(),
            source,
        }
    }
}

/// Appends `data` to `channel_id` as one message at `time_ns`.
fn write_message(
    writer: &mut Option<mcap::Writer<BufWriter<OutputFile>>>,
    path: &Path,
    channel_id: u16,
    sequence: u32,
    time_ns: u64,
    data: &[u8],
) -> Result<(), TraceError> {
    let header = mcap::records::MessageHeader {
        channel_id,
        sequence,
        log_time: time_ns,
        publish_time: time_ns,
    };
    let writer = writer.as_mut().ok_or(TraceError::Finished)?;
    writer
        .write_to_known_channel(&header, data)
        .map_err(|source| TraceError::Mcap {
            path: path.to_path_buf(),
            source,
        })
}

fn encode_error(error: impl std::fmt::Display) -> TraceError {
    TraceError::Meta(format!("cannot encode a Foxglove message: {error}"))
}

/// Adds the Foxglove schemas (from the SDK) and the probe, proxy and force channels; returns their ids.
fn add_foxglove_channels<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
) -> Result<(u16, u16, u16), mcap::McapError> {
    let no_metadata = BTreeMap::new();
    let mut schema_of = |schema: Option<::foxglove::Schema>| match schema {
        Some(schema) => writer.add_schema(&schema.name, &schema.encoding, &schema.data),
        None => Ok(0),
    };
    let transform_schema = schema_of(FrameTransform::get_schema())?;
    let vector_schema = schema_of(Vector3::get_schema())?;
    let transform_encoding = FrameTransform::get_message_encoding();
    let probe = writer.add_channel(
        transform_schema,
        PROBE_TOPIC,
        &transform_encoding,
        &no_metadata,
    )?;
    let proxy = writer.add_channel(
        transform_schema,
        PROXY_TOPIC,
        &transform_encoding,
        &no_metadata,
    )?;
    let force = writer.add_channel(
        vector_schema,
        FORCE_TOPIC,
        &Vector3::get_message_encoding(),
        &no_metadata,
    )?;
    Ok((probe, proxy, force))
}

/// The metadata fields as MCAP's string map: strings as they are, everything else as JSON.
fn metadata_strings(meta: &TraceMeta) -> Result<BTreeMap<String, String>, TraceError> {
    let value = serde_json::to_value(meta)
        .map_err(|e| TraceError::Meta(format!("cannot encode the metadata: {e}")))?;
    let serde_json::Value::Object(fields) = value else {
        return Err(TraceError::Meta("metadata is not a JSON object".into()));
    };
    Ok(fields
        .into_iter()
        .map(|(key, value)| match value {
            serde_json::Value::String(text) => (key, text),
            other => (key, other.to_string()),
        })
        .collect())
}

impl TraceWriter for McapTraceWriter {
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        if self.writer.is_none() {
            return Err(TraceError::Finished);
        }
        let Some(sample) = self.checker.admit(sample)? else {
            return Ok(());
        };
        let sample = &sample;
        if self.channels.is_none() {
            let writer = self.writer.as_mut().ok_or(TraceError::Finished)?;
            let mut channels =
                Channels::add(writer, &self.meta).map_err(|source| TraceError::Mcap {
                    path: self.path.clone(),
                    source,
                })?;
            if let Some(change) = self.early_change.take() {
                channels.scene.scene_changed(&change);
            }
            self.channels = Some(channels);
        }
        let Some(channels) = self.channels.as_mut() else {
            return Err(TraceError::Finished);
        };
        let sequence = (self.checker.count - 1) as u32;
        // Log times are wall-clock UTC (the run's start plus the sample's time); a non-finite or negative time
        // (a sample flagged invalid) is logged at the start.
        let time_ns = if sample.t_s.is_finite() && sample.t_s >= 0.0 {
            let first_t_s = *self.first_t_s.get_or_insert(sample.t_s);
            self.wall_start_ns
                .saturating_add(((sample.t_s - first_t_s).max(0.0) * 1e9).round() as u64)
        } else {
            self.wall_start_ns
        };
        let state = StateMessage {
            tick: sample.tick,
            t_s: sample.t_s,
            utc_ns: match utc_cell(self.start_utc_ns, sample.t_s) {
                Cell::I64(v) => Some(v),
                _ => None,
            },
            probe_m: sample.probe_m.to_array(),
            probe_velocity_m_per_s: sample.probe_velocity_m_per_s.to_array(),
            proxy_m: sample.proxy_m.to_array(),
            rendered_force_n: sample.rendered_force_n.to_array(),
            force_n: sample.sent_force_n.to_array(),
        };
        let solver = SolverMessage {
            tick: sample.tick,
            t_s: sample.t_s,
            primitives: ByMode {
                names: &self.mode_names,
                values: sample.modes.primitives(),
                json: |count| *count,
            },
            mode_force_n: ByMode {
                names: &self.mode_names,
                values: sample.modes.forces_n(),
                json: DVec3::to_array,
            },
            solver_status: sample.solver_status.name(),
            sweeps: sample.sweeps,
            error_bound_m: sample
                .error_bound_m
                .is_finite()
                .then_some(sample.error_bound_m),
            device_sequence: sample.device_sequence,
            device_time_us: sample.device_time_us,
            flag_bits: sample.flags,
            truth: crate::truth_columns::TruthMessage::new(&sample.truth),
        };
        // Every channel's message is encoded into the one reusable buffer, then written.
        let (writer, path, message, chunk_bytes) = (
            &mut self.writer,
            &self.path,
            &mut self.message,
            &mut self.chunk_bytes,
        );
        let mut put = |channel_id: u16,
                       encode: &dyn Fn(&mut Vec<u8>) -> Result<(), TraceError>|
         -> Result<(), TraceError> {
            message.clear();
            encode(message)?;
            // The message record's header and its index entry.
            *chunk_bytes += message.len() as u64 + 47;
            write_message(writer, path, channel_id, sequence, time_ns, message)
        };
        let json_error =
            |e: serde_json::Error| TraceError::Meta(format!("cannot encode a message: {e}"));
        put(channels.state, &|m| {
            serde_json::to_writer(m, &state).map_err(json_error)
        })?;
        put(channels.solver, &|m| {
            serde_json::to_writer(m, &solver).map_err(json_error)
        })?;
        // The Foxglove topics: protobuf through the SDK's `Encode`.
        set_translation(&mut self.probe_transform, sample.probe_m, time_ns);
        set_translation(&mut self.proxy_transform, sample.proxy_m, time_ns);
        put(channels.probe, &|m| {
            self.probe_transform.encode(m).map_err(encode_error)
        })?;
        put(channels.proxy, &|m| {
            self.proxy_transform.encode(m).map_err(encode_error)
        })?;
        put(channels.force, &|m| {
            vector3(sample.sent_force_n).encode(m).map_err(encode_error)
        })?;
        let frame = self.frame.take_if(|frame| frame.tick <= sample.tick);
        channels
            .scene
            .write(sample, frame.as_ref(), time_ns, &mut |channel, encode| {
                put(channel, &|m| encode(m).map_err(encode_error))
            })?;
        self.pending += 1;
        if self.chunk_bytes >= CHUNK_BYTES {
            self.flush()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), TraceError> {
        let result = match self.writer.as_mut() {
            // No chunk is ever open without a sample in it (the channels come with the first sample), so
            // this never closes a chunk without messages.
            Some(writer) => writer.flush(),
            None => return Err(TraceError::Finished),
        };
        result.map_err(|e| self.mcap_error(e))?;
        // The chunk is closed and handed to the file.
        self.committed += std::mem::take(&mut self.pending);
        self.chunk_bytes = 0;
        Ok(())
    }

    fn finish(&mut self) -> Result<TraceSummary, TraceError> {
        let Some(mut writer) = self.writer.take() else {
            return Err(TraceError::Finished);
        };
        self.checker.finished = true;
        writer.finish().map_err(|e| self.mcap_error(e))?;
        let file = writer
            .into_inner()
            .into_inner()
            .map_err(|e| TraceError::Io {
                path: self.path.clone(),
                source: e.into_error(),
            })?;
        file.file().sync_all().map_err(|source| TraceError::Io {
            path: self.path.clone(),
            source,
        })?;
        self.committed += std::mem::take(&mut self.pending);
        self.sidecar.samples_rejected = self.checker.rejected;
        self.sidecar.complete(&self.path, self.committed)
    }

    fn fail(&mut self, error: &str) -> Result<(), TraceError> {
        // Nothing more reaches the file (not the open chunk, not a summary): the chunks already closed
        // stay readable, exactly `committed` samples, and `voxhap trace repair` adds the summary.
        self.stop.stop();
        self.writer = None;
        self.pending = 0;
        self.checker.finished = true;
        self.sidecar.samples_rejected = self.checker.rejected;
        self.sidecar.fail(&self.path, self.committed, error)
    }

    fn sample_count(&self) -> u64 {
        self.committed
    }

    fn scene_frame(&mut self, frame: &voxhap_api::Snapshot) {
        self.frame = Some(*frame);
    }

    fn scene_changed(&mut self, change: &crate::foxglove_scene::SceneChange) {
        match self.channels.as_mut() {
            Some(channels) => channels.scene.scene_changed(change),
            None => self.early_change = Some(change.clone()),
        }
    }
}

#[cfg(test)]
#[path = "mcap_trace_tests.rs"]
mod tests;
