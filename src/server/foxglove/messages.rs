//! What the Foxglove live view publishes besides the probe, proxy and force (those are shared with the MCAP
//! trace, in `crate::record::foxglove_topics`): the scene as a `foxglove.SceneUpdate`, the certificate
//! bound and the loop statistics as JSON messages with JSON schemas.
//!
//! Where it sits: the publisher task (`super`) turns each sampled [`Snapshot`] into these messages off the
//! servo thread; nothing here touches the session.
//!
//! The scene, in world coordinates (m), frame `world`, one entity per object so Foxglove's hover shows its
//! metadata (`kind`, `mode`, `strength_n`):
//!
//! | entity id | drawn as |
//! |---|---|
//! | `probe`, `proxy` | small spheres (grey, blue) |
//! | `hand_target` | small green sphere, when a client pulls the simulated arm's hand |
//! | `force` | red arrow from the proxy along the sent force, [`FORCE_ARROW_M_PER_N`] long per newton |
//! | `primitive/I` | the I-th primitive of the tick: point = orange sphere, line = magenta segment, plane = thin translucent cyan square, directed force = yellow arrow from the proxy |
//!
//! Every update first deletes all earlier entities, so primitives that went away disappear.

use crate::haptics::PrimitiveKind;
use crate::record::foxglove_topics::{vector3, WORLD_FRAME};
use crate::servo::{PrimitiveView, Snapshot, StatsReport};
use ::foxglove::bytes::BufMut;
use ::foxglove::messages::{
    scene_entity_deletion, ArrowPrimitive, Color, CubePrimitive, KeyValuePair, LinePrimitive,
    Point3, Pose, Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate, SpherePrimitive,
    Timestamp, Vector3,
};
use ::foxglove::{Encode, Schema};
use glam::{DQuat, DVec3};
use serde::Serialize;

/// Arrow length per newton of force (m/N): 1 N draws a 1 cm arrow.
pub const FORCE_ARROW_M_PER_N: f64 = 0.01;
/// Longest arrow drawn (m); stronger forces are drawn at this length.
pub const MAX_ARROW_M: f64 = 0.05;
/// Diameter of the probe and proxy spheres (m).
pub const MARKER_DIAMETER_M: f64 = 0.003;
/// Diameter of a point primitive's sphere (m).
pub const POINT_DIAMETER_M: f64 = 0.0025;
/// Half-length of a drawn line primitive (m).
pub const LINE_HALF_LENGTH_M: f64 = 0.02;
/// Side of a drawn plane primitive (m).
pub const PLANE_SIDE_M: f64 = 0.03;
/// Thickness of a drawn plane primitive (m).
pub const PLANE_THICKNESS_M: f64 = 0.0003;

const GREY: Color = rgba(0.6, 0.6, 0.6, 1.0);
const BLUE: Color = rgba(0.2, 0.45, 1.0, 1.0);
const GREEN: Color = rgba(0.2, 0.8, 0.3, 1.0);
const RED: Color = rgba(0.95, 0.15, 0.1, 1.0);
const ORANGE: Color = rgba(1.0, 0.55, 0.0, 1.0);
const MAGENTA: Color = rgba(0.85, 0.2, 0.85, 1.0);
const CYAN: Color = rgba(0.1, 0.8, 0.9, 0.35);
const YELLOW: Color = rgba(0.95, 0.85, 0.1, 1.0);

const fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

fn identity() -> Quaternion {
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    }
}

fn quaternion(q: DQuat) -> Quaternion {
    Quaternion {
        x: q.x,
        y: q.y,
        z: q.z,
        w: q.w,
    }
}

fn pose(position_m: DVec3, orientation: Quaternion) -> Option<Pose> {
    Some(Pose {
        position: Some(vector3(position_m)),
        orientation: Some(orientation),
    })
}

/// The rotation taking `from` to the unit vector `to` (identity when `to` is not a usable direction).
fn rotation_to(from: DVec3, to: DVec3) -> Quaternion {
    match to.try_normalize() {
        Some(to) => quaternion(DQuat::from_rotation_arc(from, to)),
        None => identity(),
    }
}

fn metadata(pairs: &[(&str, String)]) -> Vec<KeyValuePair> {
    pairs
        .iter()
        .map(|(key, value)| KeyValuePair {
            key: (*key).to_owned(),
            value: value.clone(),
        })
        .collect()
}

fn entity(id: String, timestamp: Timestamp, metadata: Vec<KeyValuePair>) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp),
        frame_id: WORLD_FRAME.to_owned(),
        id,
        metadata,
        ..SceneEntity::default()
    }
}

fn sphere(position_m: DVec3, diameter_m: f64, color: Color) -> SpherePrimitive {
    SpherePrimitive {
        pose: pose(position_m, identity()),
        size: Some(vector3(DVec3::splat(diameter_m))),
        color: Some(color),
    }
}

/// An arrow from `start_m` along `vector` (any length), `length_m` long; `None` for a zero length or a
/// direction that is not finite.
fn arrow(start_m: DVec3, vector: DVec3, length_m: f64, color: Color) -> Option<ArrowPrimitive> {
    let direction = vector.try_normalize()?;
    if !(length_m.is_finite() && length_m > 1e-6) {
        return None;
    }
    let length_m = length_m.min(MAX_ARROW_M);
    let head_length = (0.25 * length_m).min(0.003);
    Some(ArrowPrimitive {
        pose: pose(start_m, rotation_to(DVec3::X, direction)),
        shaft_length: length_m - head_length,
        shaft_diameter: 0.0006,
        head_length,
        head_diameter: 0.0018,
        color: Some(color),
    })
}

/// The entity for one primitive of the tick (`index` in the tick's list).
fn primitive_entity(
    index: usize,
    primitive: &PrimitiveView,
    proxy_m: DVec3,
    timestamp: Timestamp,
) -> SceneEntity {
    let mut entity = entity(
        format!("primitive/{index}"),
        timestamp,
        metadata(&[
            ("kind", primitive.kind.name().to_owned()),
            ("mode", primitive.mode.to_string()),
            ("strength_n", primitive.strength_n.to_string()),
        ]),
    );
    let at = primitive.position_m;
    let direction = primitive.direction;
    match primitive.kind {
        PrimitiveKind::Point => entity.spheres.push(sphere(at, POINT_DIAMETER_M, ORANGE)),
        PrimitiveKind::Line => entity.lines.push(LinePrimitive {
            r#type: ::foxglove::messages::line_primitive::Type::LineList as i32,
            pose: pose(DVec3::ZERO, identity()),
            thickness: 0.0005,
            scale_invariant: false,
            points: [-LINE_HALF_LENGTH_M, LINE_HALF_LENGTH_M]
                .map(|t| {
                    let p = at + t * direction;
                    Point3 {
                        x: p.x,
                        y: p.y,
                        z: p.z,
                    }
                })
                .to_vec(),
            color: Some(MAGENTA),
            colors: Vec::new(),
            indices: Vec::new(),
        }),
        PrimitiveKind::Plane => entity.cubes.push(CubePrimitive {
            pose: pose(at, rotation_to(DVec3::Z, direction)),
            size: Some(Vector3 {
                x: PLANE_SIDE_M,
                y: PLANE_SIDE_M,
                z: PLANE_THICKNESS_M,
            }),
            color: Some(CYAN),
        }),
        PrimitiveKind::Directed => entity.arrows.extend(arrow(
            proxy_m,
            direction,
            primitive.strength_n * FORCE_ARROW_M_PER_N,
            YELLOW,
        )),
    }
    entity
}

/// The scene of one snapshot: probe, proxy, hand target, force arrow and the tick's primitives, after a
/// deletion of everything drawn before.
pub fn scene_update(snapshot: &Snapshot, timestamp: Timestamp) -> SceneUpdate {
    let mut entities = Vec::with_capacity(4 + usize::from(snapshot.primitive_count));
    let mut probe = entity("probe".to_owned(), timestamp, Vec::new());
    probe
        .spheres
        .push(sphere(snapshot.probe_m, MARKER_DIAMETER_M, GREY));
    entities.push(probe);
    let mut proxy = entity("proxy".to_owned(), timestamp, Vec::new());
    proxy
        .spheres
        .push(sphere(snapshot.proxy_m, MARKER_DIAMETER_M, BLUE));
    entities.push(proxy);
    if let Some(target) = snapshot.hand_target_m {
        let mut hand = entity("hand_target".to_owned(), timestamp, Vec::new());
        hand.spheres.push(sphere(target, MARKER_DIAMETER_M, GREEN));
        entities.push(hand);
    }
    let force = snapshot.sent_force_n;
    let mut arrow_entity = entity(
        "force".to_owned(),
        timestamp,
        metadata(&[("force_n", force.length().to_string())]),
    );
    arrow_entity.arrows.extend(arrow(
        snapshot.proxy_m,
        force,
        force.length() * FORCE_ARROW_M_PER_N,
        RED,
    ));
    entities.push(arrow_entity);
    for (index, primitive) in snapshot.primitives().enumerate() {
        entities.push(primitive_entity(
            index,
            primitive,
            snapshot.proxy_m,
            timestamp,
        ));
    }
    SceneUpdate {
        deletions: vec![SceneEntityDeletion {
            timestamp: Some(timestamp),
            r#type: scene_entity_deletion::Type::All as i32,
            id: String::new(),
        }],
        entities,
    }
}

/// `/voxhap/bound`: the certificate of one tick (JSON, schema `voxhap.Bound`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoundMessage {
    pub tick: u64,
    /// Tick time since the session started (s).
    pub t_s: f64,
    /// Certified bound on the proxy's distance from the exact equilibrium (m); `null` without a certificate.
    pub error_bound_m: Option<f64>,
    /// Solver sweeps this tick.
    pub sweeps: u32,
    /// How the solve ended: `certified`, `budget_exhausted`, `stalled`, `uncertified`, `input_rejected`.
    pub status: crate::haptics::tick::TickStatus,
}

impl BoundMessage {
    pub fn new(snapshot: &Snapshot) -> Self {
        BoundMessage {
            tick: snapshot.tick,
            t_s: snapshot.t_s,
            error_bound_m: snapshot
                .error_bound_m
                .is_finite()
                .then_some(snapshot.error_bound_m),
            sweeps: snapshot.sweeps,
            status: snapshot.status,
        }
    }
}

/// The JSON schema of [`BoundMessage`].
pub fn bound_schema() -> serde_json::Value {
    serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "voxhap.Bound",
        "type": "object",
        "properties": {
            "tick": {"type": "integer", "minimum": 0, "description": "servo tick number"},
            "t_s": {"type": "number", "description": "tick time since the session started (s)"},
            "error_bound_m": {
                "type": ["number", "null"], "minimum": 0,
                "description": "certified bound on the proxy's distance from the exact equilibrium (m); null = no certificate"
            },
            "sweeps": {"type": "integer", "minimum": 0, "description": "solver sweeps this tick"},
            "status": {
                "type": "string",
                "enum": ["certified", "budget_exhausted", "stalled", "uncertified", "input_rejected"],
                "description": "how the solve ended"
            }
        },
        "required": ["tick", "t_s", "error_bound_m", "sweeps", "status"]
    })
}

/// `/voxhap/stats`: the servo loop's [`StatsReport`] (JSON, schema `voxhap.Stats`), once a second.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(transparent)]
pub struct StatsMessage(pub StatsReport);

/// The JSON schema of [`StatsMessage`] (the fields of [`StatsReport`]).
pub fn stats_schema() -> serde_json::Value {
    let histogram = |what: &str| {
        serde_json::json!({
            "type": "object",
            "description": what,
            "properties": {
                "count": {"type": "integer"},
                "p50_us": {"type": "number"},
                "p99_us": {"type": "number"},
                "p999_us": {"type": "number"},
                "max_us": {"type": "number"}
            }
        })
    };
    let count =
        |what: &str| serde_json::json!({"type": "integer", "minimum": 0, "description": what});
    serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "voxhap.Stats",
        "type": "object",
        "properties": {
            "rate_hz": {"type": "number", "description": "servo loop rate (Hz)"},
            "ticks": count("ticks run"),
            "lateness": histogram("how late each tick started after its deadline (µs)"),
            "compute": histogram("compute time of each tick: modes, solve, coupling force (µs)"),
            "device": histogram("time of each tick's device exchange (µs)"),
            "overruns": count("ticks that started after the next deadline had passed"),
            "skipped_ticks": count("ticks skipped by those overruns"),
            "budget_overruns": count("ticks whose compute exceeded its budget"),
            "max_sweeps": count("most solver sweeps in one tick"),
            "worst_error_bound_m": {
                "type": ["number", "null"],
                "description": "worst certificate bound of a tick (m); null = a tick without a certificate"
            },
            "device_errors": count("device errors"),
            "disconnects": count("device disconnects"),
            "recorder_drops": count("samples the recorder ring had no room for"),
            "recorder_errors": count("trace write errors (each stops the recording)"),
            "commands_applied": count("control commands applied"),
            "realtime": {
                "type": "object",
                "description": "real-time features the servo thread got",
                "properties": {
                    "sched_fifo": {"type": "boolean"},
                    "memory_locked": {"type": "boolean"},
                    "pinned_cpu": {"type": ["integer", "null"]}
                }
            }
        }
    })
}

/// A JSON message type with a JSON schema, published through the SDK's typed channels.
macro_rules! json_encode {
    ($type:ty, $name:literal, $schema:expr) => {
        impl Encode for $type {
            type Error = serde_json::Error;

            fn get_schema() -> Option<Schema> {
                Some(Schema::new(
                    $name,
                    "jsonschema",
                    $schema.to_string().into_bytes(),
                ))
            }

            fn get_message_encoding() -> String {
                "json".to_owned()
            }

            fn encode(&self, buf: &mut impl BufMut) -> Result<(), Self::Error> {
                serde_json::to_writer(buf.writer(), self)
            }
        }
    };
}

json_encode!(BoundMessage, "voxhap.Bound", bound_schema());
json_encode!(StatsMessage, "voxhap.Stats", stats_schema());

#[cfg(test)]
mod tests {
    use super::*;
    use crate::haptics::tick::TickStatus;
    use crate::haptics::Primitive;
    use ::foxglove::Decode;

    fn snapshot() -> Snapshot {
        let mut slots = [None; crate::haptics::modes::MAX_MODES];
        let primitives = [
            Primitive::point(DVec3::new(0.01, 0.0, 0.0), 0.5).unwrap(),
            Primitive::line(DVec3::ZERO, DVec3::Y, 0.2).unwrap(),
            Primitive::plane(DVec3::new(0.0, 0.0, 0.01), DVec3::Z, 1.0).unwrap(),
            Primitive::directed(DVec3::X, 0.3).unwrap(),
        ];
        for (slot, primitive) in slots.iter_mut().zip(&primitives) {
            *slot = Some(PrimitiveView::new(primitive, 0));
        }
        Snapshot {
            tick: 42,
            t_s: 0.042,
            probe_m: DVec3::new(0.0, 0.0, 0.005),
            proxy_m: DVec3::new(0.0, 0.0, 0.01),
            rendered_force_n: DVec3::new(0.0, 0.0, 2.5),
            sent_force_n: DVec3::new(0.0, 0.0, 2.5),
            primitive_slots: slots,
            primitive_count: primitives.len() as u8,
            error_bound_m: f64::INFINITY,
            status: TickStatus::BudgetExhausted,
            sweeps: 7,
            hand_target_m: Some(DVec3::ONE * 0.01),
            ..Snapshot::example()
        }
    }

    #[test]
    fn the_scene_has_one_entity_per_object_and_clears_the_old_ones() {
        let update = scene_update(&snapshot(), Timestamp::new(1, 2));
        let mut bytes = Vec::new();
        update.encode(&mut bytes).unwrap();
        let update = SceneUpdate::decode(&bytes[..]).unwrap();
        assert_eq!(update.deletions.len(), 1);
        assert_eq!(
            update.deletions[0].r#type,
            scene_entity_deletion::Type::All as i32
        );
        let ids: Vec<&str> = update.entities.iter().map(|e| e.id.as_str()).collect();
        assert_eq!(
            ids,
            [
                "probe",
                "proxy",
                "hand_target",
                "force",
                "primitive/0",
                "primitive/1",
                "primitive/2",
                "primitive/3"
            ]
        );
        assert!(update.entities.iter().all(|e| e.frame_id == "world"));
        let by_id = |id: &str| update.entities.iter().find(|e| e.id == id).unwrap();
        // 2.5 N up from the proxy: a 2.5 cm arrow along +z.
        let force = &by_id("force").arrows[0];
        let length = force.shaft_length + force.head_length;
        assert!((length - 0.025).abs() < 1e-12, "{length}");
        let q = force.pose.as_ref().unwrap().orientation.as_ref().unwrap();
        let along = DQuat::from_xyzw(q.x, q.y, q.z, q.w) * DVec3::X;
        assert!((along - DVec3::Z).length() < 1e-12, "{along}");
        assert_eq!(by_id("primitive/0").spheres.len(), 1);
        assert_eq!(by_id("primitive/1").lines[0].points.len(), 2);
        let plane = &by_id("primitive/2").cubes[0];
        assert_eq!(plane.size.as_ref().unwrap().z, PLANE_THICKNESS_M);
        assert_eq!(by_id("primitive/3").arrows.len(), 1);
        let kinds: Vec<&str> = update.entities[4..]
            .iter()
            .map(|e| e.metadata[0].value.as_str())
            .collect();
        assert_eq!(kinds, ["point", "line", "plane", "directed"]);
    }

    #[test]
    fn no_force_draws_no_arrow_and_huge_forces_are_capped() {
        let mut snap = snapshot();
        snap.sent_force_n = DVec3::ZERO;
        let update = scene_update(&snap, Timestamp::new(0, 0));
        let force = update.entities.iter().find(|e| e.id == "force").unwrap();
        assert!(force.arrows.is_empty());
        snap.sent_force_n = DVec3::new(1e6, 0.0, 0.0);
        let update = scene_update(&snap, Timestamp::new(0, 0));
        let arrow = &update
            .entities
            .iter()
            .find(|e| e.id == "force")
            .unwrap()
            .arrows[0];
        assert!((arrow.shaft_length + arrow.head_length - MAX_ARROW_M).abs() < 1e-12);
    }

    #[test]
    fn bound_and_stats_are_json_matching_their_schemas() {
        let bound = BoundMessage::new(&snapshot());
        let mut bytes = Vec::new();
        bound.encode(&mut bytes).unwrap();
        let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        assert_eq!(value["error_bound_m"], serde_json::Value::Null);
        assert_eq!(value["status"], "budget_exhausted");
        assert_eq!(value["sweeps"], 7);
        let schema = BoundMessage::get_schema().unwrap();
        assert_eq!(
            (schema.name.as_str(), schema.encoding.as_str()),
            ("voxhap.Bound", "jsonschema")
        );
        let required = bound_schema()["required"].clone();
        for key in required.as_array().unwrap() {
            assert!(value.get(key.as_str().unwrap()).is_some(), "{key}");
        }

        let stats = StatsMessage(StatsReport::default());
        let mut bytes = Vec::new();
        stats.encode(&mut bytes).unwrap();
        let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        let schema = stats_schema();
        let properties = schema["properties"].as_object().unwrap();
        let keys = value.as_object().unwrap();
        // The schema documents every field of StatsReport, no more.
        assert_eq!(
            keys.keys().collect::<Vec<_>>(),
            properties.keys().collect::<Vec<_>>()
        );
    }
}
