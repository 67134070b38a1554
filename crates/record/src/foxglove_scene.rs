//! What a recording draws for Foxglove and Lichtblick besides its samples: the volume's picture and frames
//! ([`RecordedVolume`]), the scene markers, bound and operating state from the servo's snapshots
//! ([`RecordedScene`]), and the slices through the proxy, on the same topics, frames and schemas as the live
//! view ([`voxhap_view::topics`]) so a recorded session opens with the shipped layout.
//!
//! Rates are bounded ([`RECORDED_SCENE_HZ`], [`RECORDED_SLICE_INTERVAL_S`], [`RECORDED_MAX_TRIANGLES`]) so
//! the scene adds a known amount to a trace ([`recorded_scene_bytes`]). The servo thread hands the recorder a
//! snapshot every [`scene_frame_interval_ticks`] ticks through an SPSC ring; without one the markers are
//! drawn from the trace sample and counted (`scene_frames_missing`).

use ::foxglove::messages::{FrameTransform, Grid, SceneUpdate, Timestamp};
use glam::DVec3;
use voxhap_api::slice::sample_slice;
use voxhap_api::{NamedVolume, Snapshot};
use voxhap_core::volume::isosurface::Mesh;
use voxhap_view::messages::{scene_update, BoundMessage, OperatingStateMessage};
use voxhap_view::palette::{palette, Rgb};
use voxhap_view::topics::*;
use voxhap_view::volume::slice_grid;

/// Largest iso-surface mesh recorded (triangles).
pub const RECORDED_MAX_TRIANGLES: usize = 60_000;
/// Most scene updates (markers and the tick's primitives), bounds and operating states recorded per second
/// of tick time. The servo thread hands the recorder a snapshot every [`scene_frame_interval_ticks`] ticks,
/// which keeps under this rate.
pub const RECORDED_SCENE_HZ: f64 = 60.0;
/// Samples per side of a recorded slice (the live view sends 128; a recording keeps a quarter of the bytes).
pub const RECORDED_SLICE_SAMPLES: usize = 64;
/// Tick time between two recorded sets of slices (s), as often as the live view sends them.
pub const RECORDED_SLICE_INTERVAL_S: f64 = 0.25;
/// A generous estimate of the bytes the scene topics add to a recording of `duration_s` seconds of tick
/// time with `mode_count` modes: the volume picture (a 60 000-triangle mesh takes about 1.6 MB), the slices
/// (3 x 32.8 kB, 4 times a second) and the scene updates, bounds and operating states (measured about 500
/// bytes plus 150 per primitive, 60 times a second), with a quarter of margin and the record headers.
pub fn recorded_scene_bytes(duration_s: f64, mode_count: usize) -> u64 {
    const PICTURE_BYTES: f64 = 2.5e6;
    let slices_per_s = (3 * (RECORDED_SLICE_SAMPLES * RECORDED_SLICE_SAMPLES * 8 + 300)) as f64
        / RECORDED_SLICE_INTERVAL_S;
    let updates_per_s = RECORDED_SCENE_HZ * (700.0 + 190.0 * mode_count as f64);
    // `as` saturates: an enormous duration gives u64::MAX.
    (PICTURE_BYTES + 1.25 * duration_s.max(0.0) * (slices_per_s + updates_per_s)) as u64
}

/// Without a snapshot from the servo for this many scene intervals, a recording draws the markers from the
/// trace sample instead (and counts `scene_frames_missing`).
const MISSING_FRAME_INTERVALS: u64 = 3;

/// Ticks between two snapshots the servo thread hands the recorder for the scene topics: the fewest ticks
/// that last at least `1 / RECORDED_SCENE_HZ` (17 at 1 kHz, so 58.8 Hz).
pub fn scene_frame_interval_ticks(period_ns: u64) -> u64 {
    let interval_ns = (1e9 / RECORDED_SCENE_HZ).ceil() as u64;
    interval_ns.div_ceil(period_ns.max(1)).max(1)
}

/// The volume picture's messages at `time_ns`, for the live view and recordings alike: the scene update on
/// [`VOLUME_TOPIC`] (bounding box, iso-surface; [`volume_scene`]) and the `volume` and `volume_view` frames on
/// [`VOLUME_FRAME_TOPIC`] ([`volume_frames`]).
pub fn volume_messages(
    description: &str,
    min_m: DVec3,
    max_m: DVec3,
    surface: Option<&(Mesh, Rgb, f64)>,
    time_ns: u64,
) -> (SceneUpdate, [FrameTransform; 2]) {
    let update = volume_scene(
        min_m,
        max_m,
        surface,
        description,
        timestamp_from_ns(time_ns),
    );
    (update, volume_frames(min_m, max_m, time_ns))
}

/// The volume picture of a recording: bounds and the surface mode's iso-surface, built from the trace's
/// metadata when the recording starts (the volumes are loaded again from their sources; the first one that
/// loads as a scalar volume is drawn, meshed at the iso-value of the first surface mode:
/// `voxhap_view::volume::half_strength_value`).
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedVolume {
    pub description: String,
    pub min_m: DVec3,
    pub max_m: DVec3,
    pub surface: Option<(Mesh, Rgb, f64)>,
}

impl RecordedVolume {
    /// The picture of `meta`'s volumes; `None` when none of them loads as a scalar volume (then a
    /// recording simply has no volume topic messages).
    pub fn from_meta(meta: &crate::meta::TraceMeta) -> Option<RecordedVolume> {
        Self::load(meta).map(|(picture, _)| picture)
    }

    /// The picture and the volume it shows (which the recorded slices sample).
    fn load(meta: &crate::meta::TraceMeta) -> Option<(RecordedVolume, NamedVolume)> {
        use voxhap_core::haptics::modes::ModeConfig;
        let volume = meta.volume.split(", ").find_map(|source| {
            let loaded = match source.strip_prefix("builtin:") {
                Some(name) => {
                    voxhap_core::volume::procedural::builtin(name)
                        .ok()?
                        .scalar?
                }
                None => match voxhap_io::load(std::path::Path::new(source)).ok()?.volume {
                    voxhap_core::volume::AnyVolume::Scalar(volume) => volume,
                    voxhap_core::volume::AnyVolume::Vector(_) => return None,
                },
            };
            Some((source.to_owned(), loaded))
        });
        let (source, volume) = volume?;
        let modes: Vec<ModeConfig> = meta
            .scenario
            .get("modes")
            .and_then(|m| serde_json::from_value(m.clone()).ok())
            .unwrap_or_default();
        let named = NamedVolume {
            name: source.clone(),
            source,
            volume: voxhap_core::volume::AnyVolume::Scalar(volume),
        };
        Some(Self::of_volume(named, &modes))
    }

    /// The picture of a scene's first scalar volume among `volumes`, meshed at the iso-value of the first
    /// surface mode of `modes`; `None` without a scalar volume.
    pub fn of_scene(
        volumes: &[NamedVolume],
        modes: &[voxhap_core::haptics::modes::ModeConfig],
    ) -> Option<(RecordedVolume, NamedVolume)> {
        Some(Self::of_volume(first_scalar(volumes)?.clone(), modes))
    }

    /// The picture of `named` (a scalar volume; any other kind gets bounds only).
    fn of_volume(
        named: NamedVolume,
        modes: &[voxhap_core::haptics::modes::ModeConfig],
    ) -> (RecordedVolume, NamedVolume) {
        use voxhap_core::volume::isosurface::{bounded_isosurface, SampledGrid};
        let (min_m, max_m) = named.volume.grid().bounds_world();
        let surface = match (&named.volume, surface_iso(modes)) {
            (voxhap_core::volume::AnyVolume::Scalar(volume), Some((rgb, iso))) => {
                let sample = |n: usize| {
                    Ok::<_, ()>(SampledGrid::from_fn(min_m, max_m, [n, n, n], |p| {
                        volume.sample(p) as f32
                    }))
                };
                bounded_isosurface(iso as f32, 64, RECORDED_MAX_TRIANGLES, sample)
                    .ok()
                    .map(|(mesh, _)| (mesh, rgb, iso))
            }
            _ => None,
        };
        let picture = RecordedVolume {
            description: named.source.clone(),
            min_m,
            max_m,
            surface,
        };
        (picture, named)
    }
}

/// The first scalar volume of `volumes`: the one a recording draws.
fn first_scalar(volumes: &[NamedVolume]) -> Option<&NamedVolume> {
    volumes
        .iter()
        .find(|v| matches!(v.volume, voxhap_core::volume::AnyVolume::Scalar(_)))
}

/// The colour and iso-value of the first surface mode of `modes` (its transfer function's half-strength
/// value), `None` without one.
fn surface_iso(modes: &[voxhap_core::haptics::modes::ModeConfig]) -> Option<(Rgb, f64)> {
    use voxhap_core::haptics::modes::ModeKind;
    let (index, mode) = modes
        .iter()
        .enumerate()
        .find(|(_, m)| m.kind == ModeKind::Surface)?;
    let iso = voxhap_view::volume::half_strength_value(mode.transfer.as_ref()?)?;
    Some((palette().mode(index), iso))
}

/// A scene change during a recording, ready to draw: the new volume picture, the volume its slices sample,
/// and the scene generation that brought it (the servo's snapshots show it from the tick the change took
/// effect). The control side builds it ([`SceneChange::between`], so neither the servo nor the recorder
/// thread meshes) and sends it to the recorder thread
/// (`voxhap_servo::recorder::RecorderRequest::SceneChanged`), which hands it to the trace writer
/// ([`crate::writer::TraceWriter::scene_changed`]).
#[derive(Debug, Clone)]
pub struct SceneChange {
    pub generation: u64,
    pub picture: RecordedVolume,
    pub volume: NamedVolume,
}

impl SceneChange {
    /// The redraw for a change of the scene from (`old_volumes`, `old_modes`) to (`volumes`, `modes`),
    /// meshed on the caller's thread; `None` when the picture stays the same (the same first scalar volume,
    /// the same surface colour and iso-value) or the new scene has no scalar volume (the old picture stays).
    pub fn between(
        (old_volumes, old_modes): (&[NamedVolume], &[voxhap_core::haptics::modes::ModeConfig]),
        (volumes, modes): (&[NamedVolume], &[voxhap_core::haptics::modes::ModeConfig]),
        generation: u64,
    ) -> Option<SceneChange> {
        let chosen = first_scalar(volumes)?;
        let unchanged = first_scalar(old_volumes).is_some_and(|old| old.volume == chosen.volume)
            && surface_iso(old_modes) == surface_iso(modes);
        if unchanged {
            return None;
        }
        let (picture, volume) = RecordedVolume::of_volume(chosen.clone(), modes);
        Some(SceneChange {
            generation,
            picture,
            volume,
        })
    }
}

/// `/voxhap/bound` in a recording without servo snapshots (`voxhap sim`): the live view's schema, with
/// `status` derived from the trace sample: `budget_exhausted` when the tick's solver-budget flag is set,
/// `uncertified` without a certificate, else `certified`.
#[derive(serde::Serialize)]
struct RecordedBound {
    tick: u64,
    t_s: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    error_bound_m: Option<f64>,
    sweeps: u32,
    status: &'static str,
}

/// `/voxhap/stats` in a recording (JSON `voxhap.TraceStats`): totals from the first recorded tick, once a
/// second of tick time.
#[derive(serde::Serialize, Default)]
struct RecordedStats {
    t_s: f64,
    ticks: u64,
    max_sweeps: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    worst_error_bound_m: Option<f64>,
    overruns: u64,
    solver_budget_hits: u64,
    force_clamped: u64,
    samples_dropped: u64,
    scene_frames_missing: u64,
}

fn trace_stats_schema() -> serde_json::Value {
    let count = voxhap_view::messages::count_schema;
    voxhap_view::messages::message_schema(
        "voxhap.TraceStats",
        serde_json::json!({
            "t_s": {"type": "number", "description": "tick time of the latest tick counted (s)"},
            "ticks": count("ticks recorded so far"),
            "max_sweeps": count("most solver sweeps in one tick"),
            "worst_error_bound_m": {"type": "number", "description": "worst certificate bound (m); omitted = a tick without one"},
            "overruns": count("ticks flagged overrun"),
            "solver_budget_hits": count("ticks flagged solver_budget_hit"),
            "force_clamped": count("ticks flagged force_clamped"),
            "samples_dropped": count("ticks flagged samples_dropped"),
            "scene_frames_missing": count("scene updates drawn from the trace sample because the servo's snapshot did not arrive (markers without the tick's primitives)")
        }),
    )
}

/// Why a scene message could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum SceneEncodeError {
    /// A Foxglove protobuf message.
    #[error("{0}")]
    Protobuf(Box<dyn std::error::Error + Send + Sync>),
    /// A JSON message.
    #[error("{0}")]
    Json(#[from] serde_json::Error),
}

impl SceneEncodeError {
    fn protobuf(error: impl std::error::Error + Send + Sync + 'static) -> Self {
        SceneEncodeError::Protobuf(Box::new(error))
    }
}

/// Writes `message` on `channel` through `put`, encoded as protobuf.
fn put_protobuf(
    put: &mut ScenePut<'_>,
    channel: u16,
    message: &(impl ::foxglove::Encode<Error: Send + Sync + 'static> + ?Sized),
) -> Result<(), crate::error::TraceError> {
    put(channel, &|m| {
        message.encode(m).map_err(SceneEncodeError::protobuf)
    })
}

/// Writes `message` on `channel` through `put`, encoded as JSON.
fn put_json(
    put: &mut ScenePut<'_>,
    channel: u16,
    message: &(impl serde::Serialize + ?Sized),
) -> Result<(), crate::error::TraceError> {
    put(channel, &|m| {
        serde_json::to_writer(m, message).map_err(SceneEncodeError::Json)
    })
}

/// Encodes one message into the buffer it is given.
pub type SceneEncode<'a> = dyn Fn(&mut Vec<u8>) -> Result<(), SceneEncodeError> + 'a;
/// Writes one message: the channel and its encoder.
pub type ScenePut<'a> =
    dyn FnMut(u16, &SceneEncode<'_>) -> Result<(), crate::error::TraceError> + 'a;

/// The scene channels of an MCAP trace and what they need between samples.
pub struct RecordedScene {
    primitives: u16,
    volume: u16,
    volume_frame: u16,
    bound: u16,
    stats: u16,
    operating_state: u16,
    slices: [u16; 3],
    picture: Option<RecordedVolume>,
    /// The volume the slices sample (the picture's).
    slice_volume: Option<NamedVolume>,
    picture_written: bool,
    /// The picture of a scene change ([`RecordedScene::scene_changed`]) and the volume its slices sample,
    /// waiting for the first snapshot of its scene generation.
    pending: Option<(u64, RecordedVolume, NamedVolume)>,
    /// Log time of the last scene update written.
    last_scene_ns: Option<u64>,
    /// True once the servo handed over a snapshot: from then on scene updates follow the snapshots.
    frames_seen: bool,
    next_slice_t_s: Option<f64>,
    next_stats_t_s: Option<f64>,
    totals: RecordedStats,
    worst_bound_m: f64,
}

impl RecordedScene {
    /// Adds the schemas and channels ([`PRIMITIVES_TOPIC`], [`VOLUME_TOPIC`], [`VOLUME_FRAME_TOPIC`],
    /// [`BOUND_TOPIC`], [`STATS_TOPIC`], [`OPERATING_STATE_TOPIC`], the slice topics) and builds the volume
    /// picture of `meta`.
    pub fn add<W: std::io::Write + std::io::Seek>(
        writer: &mut mcap::Writer<W>,
        meta: &crate::meta::TraceMeta,
    ) -> Result<RecordedScene, mcap::McapError> {
        use ::foxglove::Encode;
        use voxhap_view::messages::{bound_schema, operating_state_schema};
        use voxhap_view::topics::SLICE_TOPICS;
        let none = std::collections::BTreeMap::new();
        let mut schema_of = |schema: Option<::foxglove::Schema>| match schema {
            Some(schema) => writer.add_schema(&schema.name, &schema.encoding, &schema.data),
            None => Ok(0),
        };
        let scene_schema = schema_of(SceneUpdate::get_schema())?;
        let transform_schema = schema_of(FrameTransform::get_schema())?;
        let grid_schema = schema_of(Grid::get_schema())?;
        let mut json_schema = |name: &str, schema: serde_json::Value| {
            writer.add_schema(name, "jsonschema", schema.to_string().as_bytes())
        };
        let bound_schema = json_schema("voxhap.Bound", bound_schema())?;
        let stats_schema = json_schema("voxhap.TraceStats", trace_stats_schema())?;
        let state_schema = json_schema("voxhap.OperatingState", operating_state_schema())?;
        let protobuf = SceneUpdate::get_message_encoding();
        let mut slices = [0; 3];
        for (channel, topic) in slices.iter_mut().zip(SLICE_TOPICS) {
            *channel = writer.add_channel(grid_schema, topic, &protobuf, &none)?;
        }
        let loaded = RecordedVolume::load(meta);
        let (picture, slice_volume) = match loaded {
            Some((picture, volume)) => (Some(picture), Some(volume)),
            None => (None, None),
        };
        Ok(RecordedScene {
            primitives: writer.add_channel(scene_schema, PRIMITIVES_TOPIC, &protobuf, &none)?,
            volume: writer.add_channel(scene_schema, VOLUME_TOPIC, &protobuf, &none)?,
            volume_frame: writer.add_channel(
                transform_schema,
                VOLUME_FRAME_TOPIC,
                &protobuf,
                &none,
            )?,
            bound: writer.add_channel(bound_schema, BOUND_TOPIC, "json", &none)?,
            stats: writer.add_channel(stats_schema, STATS_TOPIC, "json", &none)?,
            operating_state: writer.add_channel(
                state_schema,
                OPERATING_STATE_TOPIC,
                "json",
                &none,
            )?,
            slices,
            picture,
            slice_volume,
            picture_written: false,
            pending: None,
            last_scene_ns: None,
            frames_seen: false,
            next_slice_t_s: None,
            next_stats_t_s: None,
            totals: RecordedStats::default(),
            worst_bound_m: 0.0,
        })
    }

    /// The scene messages due with `sample` (logged at `time_ns`): the volume picture and frames with the
    /// first sample, and again with the first snapshot of a scene change's generation
    /// ([`RecordedScene::scene_changed`]); the scene update (markers and the tick's primitives), bound and operating state from `frame`,
    /// the servo's snapshot of this tick, when there is one (at most [`RECORDED_SCENE_HZ`]), else from the
    /// sample at that rate (`voxhap sim`, or a snapshot that did not arrive); slices through the proxy every
    /// [`RECORDED_SLICE_INTERVAL_S`]; statistics once a second. `put(channel, encode)` writes one message.
    pub fn write(
        &mut self,
        sample: &crate::sample::TraceSample,
        frame: Option<&Snapshot>,
        time_ns: u64,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        let timestamp = timestamp_from_ns(time_ns);
        let interval_ns = (1e9 / RECORDED_SCENE_HZ) as u64;
        let since_ns = self
            .last_scene_ns
            .map_or(u64::MAX, |last| time_ns.saturating_sub(last));
        if !self.picture_written {
            self.picture_written = true;
            self.write_picture(time_ns, put)?;
        }
        // A scene change is drawn with the first snapshot of its generation (or at once without
        // snapshots: `voxhap sim`, or when they stopped coming).
        let change_due = self.pending.as_ref().is_some_and(|(generation, _, _)| {
            frame.is_some_and(|f| f.scene_generation >= *generation)
                || !self.frames_seen
                || since_ns >= MISSING_FRAME_INTERVALS * interval_ns
        });
        if change_due {
            if let Some((_, picture, volume)) = self.pending.take() {
                self.picture = Some(picture);
                self.slice_volume = Some(volume);
                // Slices of the new volume at once.
                self.next_slice_t_s = None;
                self.write_picture(time_ns, put)?;
            }
        }
        self.count(sample);
        let frame = frame.filter(|f| f.tick == sample.tick);
        self.frames_seen |= frame.is_some();
        // A snapshot is taken when at least 0.9 interval passed (the servo spaces them by whole ticks, a
        // little over one interval); without snapshots, the sample is, once per interval (or, when the
        // snapshots stopped coming, once they are overdue).
        let from_frame = frame.filter(|_| since_ns >= interval_ns / 10 * 9);
        let from_sample = frame.is_none()
            && if self.frames_seen {
                since_ns >= MISSING_FRAME_INTERVALS * interval_ns
            } else {
                since_ns >= interval_ns
            };
        if let Some(frame) = from_frame {
            self.last_scene_ns = Some(time_ns);
            let update = scene_update(frame, timestamp);
            put_protobuf(put, self.primitives, &update)?;
            let bound = BoundMessage::new(frame);
            put_json(put, self.bound, &bound)?;
            let state = OperatingStateMessage::new(frame);
            put_json(put, self.operating_state, &state)?;
        } else if from_sample {
            self.last_scene_ns = Some(time_ns);
            self.totals.scene_frames_missing += u64::from(self.frames_seen);
            self.write_from_sample(sample, timestamp, put)?;
        }
        self.write_slices(sample, time_ns, put)?;
        let due = self.next_stats_t_s.get_or_insert(sample.t_s + 1.0);
        if sample.t_s >= *due {
            *due = sample.t_s + 1.0;
            let totals = &self.totals;
            put_json(put, self.stats, totals)?;
        }
        Ok(())
    }

    /// Takes in a scene change, to be written by [`RecordedScene::write`] with the first snapshot of
    /// `change.generation` (a later change replaces one not yet written).
    pub fn scene_changed(&mut self, change: &SceneChange) {
        self.pending = Some((
            change.generation,
            change.picture.clone(),
            change.volume.clone(),
        ));
    }

    /// Writes the volume picture (bounds, iso-surface) and the volume's frames ([`volume_frames`]), when
    /// there is a picture.
    fn write_picture(
        &self,
        time_ns: u64,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        let Some(picture) = &self.picture else {
            return Ok(());
        };
        let (update, frames) = volume_messages(
            &picture.description,
            picture.min_m,
            picture.max_m,
            picture.surface.as_ref(),
            time_ns,
        );
        put_protobuf(put, self.volume, &update)?;
        for frame in frames {
            put_protobuf(put, self.volume_frame, &frame)?;
        }
        Ok(())
    }

    /// Adds `sample` to the statistics.
    fn count(&mut self, sample: &crate::sample::TraceSample) {
        let t = &mut self.totals;
        t.t_s = sample.t_s;
        t.ticks += 1;
        t.max_sweeps = t.max_sweeps.max(sample.sweeps);
        self.worst_bound_m = self.worst_bound_m.max(sample.error_bound_m);
        t.worst_error_bound_m = self.worst_bound_m.is_finite().then_some(self.worst_bound_m);
        let flag = |bit: u32| u64::from(sample.flags & bit != 0);
        t.overruns += flag(crate::flags::FLAG_OVERRUN);
        t.solver_budget_hits += flag(crate::flags::FLAG_SOLVER_BUDGET_HIT);
        t.force_clamped += flag(crate::flags::FLAG_FORCE_CLAMPED);
        t.samples_dropped += flag(crate::flags::FLAG_SAMPLES_DROPPED);
    }

    /// The scene update, bound and operating state as far as the trace sample tells them: markers without
    /// the tick's primitives, the bound's status from the flags, `DISABLED` when the device was
    /// disconnected or not enabled.
    fn write_from_sample(
        &self,
        sample: &crate::sample::TraceSample,
        timestamp: Timestamp,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        let update = replace_all(
            marker_entities(
                sample.probe_m,
                sample.proxy_m,
                None,
                sample.sent_force_n,
                timestamp,
            ),
            timestamp,
        );
        put_protobuf(put, self.primitives, &update)?;
        let bound = RecordedBound {
            tick: sample.tick,
            t_s: sample.t_s,
            error_bound_m: sample
                .error_bound_m
                .is_finite()
                .then_some(sample.error_bound_m),
            sweeps: sample.sweeps,
            status: if sample.flags & crate::flags::FLAG_SOLVER_BUDGET_HIT != 0 {
                "budget_exhausted"
            } else if sample.error_bound_m.is_finite() {
                "certified"
            } else {
                "uncertified"
            },
        };
        put_json(put, self.bound, &bound)?;
        let disabled =
            crate::flags::FLAG_DEVICE_DISCONNECTED | crate::flags::FLAG_DEVICE_NOT_ENABLED;
        let state = OperatingStateMessage::from_truth(sample.flags & disabled == 0, &sample.truth);
        put_json(put, self.operating_state, &state)
    }

    /// The three slices through the proxy, every [`RECORDED_SLICE_INTERVAL_S`] of tick time, when the
    /// recording has a volume picture and the proxy is a finite point.
    fn write_slices(
        &mut self,
        sample: &crate::sample::TraceSample,
        time_ns: u64,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        use voxhap_api::{SliceAxis, SliceRequest};
        let Some(volume) = &self.slice_volume else {
            return Ok(());
        };
        let due = self.next_slice_t_s.get_or_insert(sample.t_s);
        if !(sample.t_s >= *due && sample.proxy_m.is_finite()) {
            return Ok(());
        }
        *due = sample.t_s + RECORDED_SLICE_INTERVAL_S;
        for (channel, axis) in
            self.slices
                .into_iter()
                .zip([SliceAxis::X, SliceAxis::Y, SliceAxis::Z])
        {
            let request = SliceRequest {
                axis,
                size: RECORDED_SLICE_SAMPLES,
                at_m: Some(sample.proxy_m),
                volume: None,
            };
            // The request is valid by construction (size in range, finite point); a refusal would only
            // leave this slice out.
            let Ok(slice) = sample_slice(volume, &request, sample.proxy_m) else {
                continue;
            };
            let grid = slice_grid(&slice, time_ns);
            put_protobuf(put, channel, &grid)?;
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "foxglove_scene_tests.rs"]
mod tests;
