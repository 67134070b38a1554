//! What a recording draws for Foxglove and Lichtblick besides its samples: the volume's picture and frames
//! ([`RecordedVolume`]), the scene markers, bound and operating state from the servo's snapshots
//! ([`RecordedScene`]), and the slices through the proxy, on the same topics, frames and schemas as the live
//! view ([`voxhap_view::topics`]) so a recorded session opens with the shipped layout.
//!
//! Rates are bounded ([`RECORDED_SCENE_HZ`], [`RECORDED_SLICE_INTERVAL_S`], [`RECORDED_MAX_TRIANGLES`]) so
//! the scene adds a known amount to a trace ([`recorded_scene_bytes`]). The servo thread hands the recorder a
//! snapshot every [`scene_frame_interval_ticks`] ticks through an SPSC ring; without one the markers are
//! drawn from the trace sample and counted (`scene_frames_missing`).

use ::foxglove::messages::{FrameTransform, Grid, SceneUpdate};
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
    worst_error_bound_m: Option<f64>,
    overruns: u64,
    solver_budget_hits: u64,
    force_clamped: u64,
    samples_dropped: u64,
    scene_frames_missing: u64,
}

fn trace_stats_schema() -> serde_json::Value {
    let count =
        |what: &str| serde_json::json!({"type": "integer", "minimum": 0, "description": what});
    serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "voxhap.TraceStats",
        "type": "object",
        "properties": {
            "t_s": {"type": "number", "description": "tick time of the latest tick counted (s)"},
            "ticks": count("ticks recorded so far"),
            "max_sweeps": count("most solver sweeps in one tick"),
            "worst_error_bound_m": {"type": ["number", "null"], "description": "worst certificate bound (m); null = a tick without one"},
            "overruns": count("ticks flagged overrun"),
            "solver_budget_hits": count("ticks flagged solver_budget_hit"),
            "force_clamped": count("ticks flagged force_clamped"),
            "samples_dropped": count("ticks flagged samples_dropped"),
            "scene_frames_missing": count("scene updates drawn from the trace sample because the servo's snapshot did not arrive (markers without the tick's primitives)")
        }
    })
}

/// Encodes one message into the buffer it is given.
pub type SceneEncode<'a> = dyn Fn(&mut Vec<u8>) -> Result<(), String> + 'a;
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
        use ::foxglove::Encode;
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
            put(self.primitives, &|m| {
                update.encode(m).map_err(|e| e.to_string())
            })?;
            let bound = BoundMessage::new(frame);
            put(self.bound, &|m| {
                serde_json::to_writer(m, &bound).map_err(|e| e.to_string())
            })?;
            let state = OperatingStateMessage::new(frame);
            put(self.operating_state, &|m| {
                serde_json::to_writer(m, &state).map_err(|e| e.to_string())
            })?;
        } else if from_sample {
            self.last_scene_ns = Some(time_ns);
            self.totals.scene_frames_missing += u64::from(self.frames_seen);
            self.write_from_sample(sample, time_ns, put)?;
        }
        self.write_slices(sample, time_ns, put)?;
        let due = self.next_stats_t_s.get_or_insert(sample.t_s + 1.0);
        if sample.t_s >= *due {
            *due = sample.t_s + 1.0;
            let totals = &self.totals;
            put(self.stats, &|m| {
                serde_json::to_writer(m, totals).map_err(|e| e.to_string())
            })?;
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
        use ::foxglove::Encode;
        let Some(picture) = &self.picture else {
            return Ok(());
        };
        let update = volume_scene(
            picture.min_m,
            picture.max_m,
            picture.surface.as_ref(),
            &picture.description,
            timestamp_from_ns(time_ns),
        );
        put(self.volume, &|m| {
            update.encode(m).map_err(|e| e.to_string())
        })?;
        for frame in volume_frames(picture.min_m, picture.max_m, time_ns) {
            put(self.volume_frame, &|m| {
                frame.encode(m).map_err(|e| e.to_string())
            })?;
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
        &mut self,
        sample: &crate::sample::TraceSample,
        time_ns: u64,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        use ::foxglove::Encode;
        let timestamp = timestamp_from_ns(time_ns);
        let update = replace_all(
            marker_entities(
                sample.probe_m,
                sample.proxy_m,
                None,
                sample.force_n,
                timestamp,
            ),
            timestamp,
        );
        put(self.primitives, &|m| {
            update.encode(m).map_err(|e| e.to_string())
        })?;
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
        put(self.bound, &|m| {
            serde_json::to_writer(m, &bound).map_err(|e| e.to_string())
        })?;
        let disabled =
            crate::flags::FLAG_DEVICE_DISCONNECTED | crate::flags::FLAG_DEVICE_NOT_ENABLED;
        let state = OperatingStateMessage {
            state: if sample.flags & disabled == 0 {
                "ENABLED"
            } else {
                "DISABLED"
            },
            is_homed: true,
            is_busy: false,
        };
        put(self.operating_state, &|m| {
            serde_json::to_writer(m, &state).map_err(|e| e.to_string())
        })
    }

    /// The three slices through the proxy, every [`RECORDED_SLICE_INTERVAL_S`] of tick time, when the
    /// recording has a volume picture and the proxy is a finite point.
    fn write_slices(
        &mut self,
        sample: &crate::sample::TraceSample,
        time_ns: u64,
        put: &mut ScenePut<'_>,
    ) -> Result<(), crate::error::TraceError> {
        use ::foxglove::Encode;
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
            put(channel, &|m| grid.encode(m).map_err(|e| e.to_string()))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ::foxglove::Decode;

    #[test]
    fn a_recording_of_a_builtin_sphere_gets_its_bounds_and_a_mesh_at_the_surface_threshold() {
        let mut meta = crate::test_support::meta(&["surface"]);
        meta.volume = "builtin:sphere".to_owned();
        meta.scenario = serde_json::json!({
            "modes": [{"kind": "surface", "volume": "v", "transfer": [[0.45, 0.0], [0.55, 2.0]]}]
        });
        let picture = RecordedVolume::from_meta(&meta).expect("a picture");
        assert!(
            picture.min_m.x < -0.03 && picture.max_m.x > 0.03,
            "{picture:?}"
        );
        let (mesh, colour, iso) = picture.surface.expect("a surface mesh");
        assert!((iso - 0.5).abs() < 1e-12);
        assert_eq!(colour, palette().mode(0));
        assert!(!mesh.triangles.is_empty() && mesh.triangles.len() <= RECORDED_MAX_TRIANGLES);
        // The half-density shell of the radius-3 cm ball.
        for v in &mesh.vertices {
            assert!(
                (v.length() - 0.03).abs() < 0.003,
                "vertex at {} m",
                v.length()
            );
        }
        meta.volume = "procedural:sphere, /no/such/file.nii".to_owned();
        assert_eq!(RecordedVolume::from_meta(&meta), None);
    }

    /// A one-mode sample of tick `tick` at 1 kHz.
    fn sample_at(tick: u64) -> crate::TraceSample {
        let mut sample = crate::TraceSample::zeroed(1);
        sample.tick = tick;
        sample.t_s = tick as f64 * 1e-3;
        sample
    }

    /// Writes 3 s of 1 kHz samples through a [`RecordedScene`], with the servo's snapshots every 17th tick
    /// for the first second only; returns how many messages each channel got and the last statistics.
    fn record_with_frames_for_one_second() -> (RecordedScene, Vec<u16>, serde_json::Value) {
        let mut meta = crate::test_support::meta(&["surface"]);
        meta.volume = "builtin:sphere".to_owned();
        let mut writer = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
        let mut scene = RecordedScene::add(&mut writer, &meta).unwrap();
        let mut channels = Vec::new();
        let mut last_stats = serde_json::Value::Null;
        let every = scene_frame_interval_ticks(1_000_000);
        for tick in 0..3000u64 {
            let sample = sample_at(tick);
            let frame = Snapshot {
                tick,
                t_s: sample.t_s,
                connected: true,
                engaged: true,
                ..Snapshot::example()
            };
            let frame = (tick < 1000 && tick % every == 0).then_some(&frame);
            let stats_channel = scene.stats;
            scene
                .write(&sample, frame, tick * 1_000_000, &mut |channel, encode| {
                    let mut bytes = Vec::new();
                    encode(&mut bytes).unwrap();
                    if channel == stats_channel {
                        last_stats = serde_json::from_slice(&bytes).unwrap();
                    }
                    channels.push(channel);
                    Ok(())
                })
                .unwrap();
        }
        (scene, channels, last_stats)
    }

    #[test]
    fn snapshots_drive_the_scene_updates_and_missing_ones_are_drawn_from_samples_and_counted() {
        let (scene, channels, stats) = record_with_frames_for_one_second();
        let count = |channel: u16| channels.iter().filter(|&&c| c == channel).count();
        // 59 snapshots in the first second (ticks 0, 17, ..., 986); then none: one update per 3 intervals
        // (50 ms) from the samples, 40 in the last two seconds.
        assert_eq!(count(scene.primitives), 59 + 40);
        assert_eq!(count(scene.bound), count(scene.primitives));
        assert_eq!(count(scene.operating_state), count(scene.primitives));
        // The last statistics (at 2 s) count the 20 updates drawn from samples by then (ticks 1036 ..= 1986).
        assert_eq!(stats["t_s"], 2.0);
        assert_eq!(stats["scene_frames_missing"], 20, "{stats}");
        // Slices every 0.25 s, the volume picture once, statistics once a second (at 1 s and 2 s).
        for channel in scene.slices {
            assert_eq!(count(channel), 12);
        }
        assert_eq!(count(scene.volume), 1);
        assert_eq!(
            count(scene.volume_frame),
            2,
            "frames volume and volume_view"
        );
        assert_eq!(count(scene.stats), 2);
    }

    /// A scene change while recording: the new volume's picture and frames are written with the first
    /// snapshot of the new generation, slices switch to it, and an unchanged scene draws nothing.
    #[test]
    fn a_scene_change_redraws_the_volume_with_the_first_snapshot_of_its_generation() {
        use voxhap_core::haptics::modes::ModeConfig;
        let mut meta = crate::test_support::meta(&["surface"]);
        meta.volume = "builtin:sphere".to_owned();
        let modes: Vec<ModeConfig> = serde_json::from_value(serde_json::json!([
            {"kind": "surface", "volume": "v", "transfer": [[0.45, 0.0], [0.55, 2.0]]}
        ]))
        .unwrap();
        meta.scenario = serde_json::json!({ "modes": modes });
        let mut writer = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
        let mut scene = RecordedScene::add(&mut writer, &meta).unwrap();
        // A 10 cm ball in a 40 cm cube.
        let big = voxhap_core::volume::procedural::sphere(0.1, [24; 3], 0.2).unwrap();
        let (big_min_m, big_max_m) = big.grid().bounds_world();
        assert!((big_max_m - big_min_m - DVec3::splat(0.4)).length() < 0.05);
        let sphere = NamedVolume {
            name: "v".to_owned(),
            source: "builtin:sphere".to_owned(),
            volume: voxhap_core::volume::AnyVolume::Scalar(
                voxhap_core::volume::procedural::builtin("sphere")
                    .unwrap()
                    .scalar
                    .unwrap(),
            ),
        };
        let ball = NamedVolume {
            name: "v".to_owned(),
            source: "big.mha".to_owned(),
            volume: voxhap_core::volume::AnyVolume::Scalar(big),
        };
        let before = (std::slice::from_ref(&sphere), &modes[..]);
        // The same scene draws nothing new.
        assert!(SceneChange::between(before, before, 2).is_none());
        let change =
            SceneChange::between(before, (std::slice::from_ref(&ball), &modes[..]), 2).unwrap();
        // A new iso-value redraws the same volume.
        let mut steeper = modes.clone();
        steeper[0].transfer =
            Some(voxhap_core::haptics::modes::TransferFunction::ramp(0.2, 0.3, 2.0).unwrap());
        let redrawn =
            SceneChange::between(before, (std::slice::from_ref(&sphere), &steeper[..]), 3);
        assert!((redrawn.unwrap().picture.surface.unwrap().2 - 0.25).abs() < 1e-12);
        let every = scene_frame_interval_ticks(1_000_000);
        let mut written: Vec<(u16, u64, Vec<u8>)> = Vec::new();
        for tick in 0..1000u64 {
            if tick == 400 {
                scene.scene_changed(&change);
            }
            let sample = sample_at(tick);
            // The servo took the change at tick 410.
            let frame = Snapshot {
                tick,
                t_s: sample.t_s,
                scene_generation: if tick >= 410 { 2 } else { 1 },
                ..Snapshot::example()
            };
            let frame = (tick % every == 0).then_some(&frame);
            let time_ns = tick * 1_000_000;
            scene
                .write(&sample, frame, time_ns, &mut |channel, encode| {
                    let mut bytes = Vec::new();
                    encode(&mut bytes).unwrap();
                    written.push((channel, time_ns, bytes));
                    Ok(())
                })
                .unwrap();
        }
        let pictures: Vec<_> = written.iter().filter(|m| m.0 == scene.volume).collect();
        assert_eq!(pictures.len(), 2);
        // The first snapshot of generation 2 is tick 425 (every 17th tick).
        assert_eq!((pictures[0].1, pictures[1].1), (0, 425_000_000));
        let second = SceneUpdate::decode(&pictures[1].2[..]).unwrap();
        let meta_of = |key: &str| {
            second.entities[0]
                .metadata
                .iter()
                .find(|kv| kv.key == key)
                .unwrap()
                .value
                .clone()
        };
        assert_eq!(meta_of("volume"), "big.mha");
        let expected = CameraFraming::of_bounds(big_min_m, big_max_m);
        let max_m: Vec<f64> = serde_json::from_str(&meta_of("max_m")).unwrap();
        assert_eq!(max_m, big_max_m.to_array());
        assert!(
            (meta_of("camera_distance_m").parse::<f64>().unwrap() - expected.distance_m).abs()
                < 1e-9
        );
        let mesh = &second.entities[1].triangles[0];
        let reach = mesh
            .points
            .iter()
            .map(|p| DVec3::new(p.x, p.y, p.z).length())
            .fold(0.0, f64::max);
        assert!(
            (reach - 0.1).abs() < 0.02,
            "the new ball's surface reaches {reach} m"
        );
        // Two frames per picture; the slices after the change sample the new 40 cm volume.
        assert_eq!(
            written.iter().filter(|m| m.0 == scene.volume_frame).count(),
            4
        );
        let slice = written
            .iter()
            .find(|m| m.0 == scene.slices[2] && m.1 >= 425_000_000)
            .unwrap();
        assert_eq!(slice.1, 425_000_000, "slices of the new volume at once");
        let grid = Grid::decode(&slice.2[..]).unwrap();
        let cell = grid.cell_size.unwrap().x;
        assert!(
            (cell * RECORDED_SLICE_SAMPLES as f64 - 0.4).abs() < 0.05,
            "cell {cell} m"
        );
    }
}
