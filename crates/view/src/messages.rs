//! What the Foxglove live view publishes besides the probe, proxy and force (those are shared with the MCAP
//! trace, in `crate::topics`): the scene as a `foxglove.SceneUpdate`, the certificate
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
//! | `probe`, `proxy` | small spheres |
//! | `hand_target` | small sphere, when a client pulls the simulated arm's hand |
//! | `force` | arrow from the proxy along the sent force, [`FORCE_ARROW_M_PER_N`] long per newton |
//! | `primitive/I` | the I-th primitive of the tick in its mode's colour: point = sphere, line = segment, plane = thin translucent square, directed force = arrow from the proxy |
//!
//! Colours come from the one palette ([`crate::palette`], web/style.css), so Foxglove and the
//! built-in page draw each object in the same colour.
//!
//! Every update first deletes all earlier entities, so primitives that went away disappear.

use crate::palette::palette;
use crate::topics::{
    arrow, color, entity, identity, marker_entities, metadata, pose, replace_all, rotation_to,
    sphere, FORCE_ARROW_M_PER_N,
};
use ::foxglove::bytes::BufMut;
use ::foxglove::messages::{
    CubePrimitive, LinePrimitive, Point3, SceneEntity, SceneUpdate, Timestamp, Vector3,
};
use ::foxglove::{Encode, Schema};
use glam::DVec3;
use serde::Serialize;
#[cfg(doc)]
use voxhap_api::EnergyReport;
use voxhap_api::{
    crtk_operating_state, ForceOffCause, PrimitiveView, Snapshot, StatsReport, TickEnergy,
    TickTruth,
};
use voxhap_core::haptics::PrimitiveKind;

pub use crate::topics::{MARKER_DIAMETER_M, MAX_ARROW_M};

/// Diameter of a point primitive's sphere (m).
pub const POINT_DIAMETER_M: f64 = 0.0025;
/// Half-length of a drawn line primitive (m).
pub const LINE_HALF_LENGTH_M: f64 = 0.02;
/// Side of a drawn plane primitive (m).
pub const PLANE_SIDE_M: f64 = 0.03;
/// Thickness of a drawn plane primitive (m).
pub const PLANE_THICKNESS_M: f64 = 0.0003;
/// Opacity of a drawn plane primitive.
pub const PLANE_ALPHA: f64 = 0.35;

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
    let mode_colour = palette().mode(usize::from(primitive.mode));
    match primitive.kind {
        PrimitiveKind::Point => {
            entity
                .spheres
                .push(sphere(at, POINT_DIAMETER_M, color(mode_colour, 1.0)))
        }
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
            color: Some(color(mode_colour, 1.0)),
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
            color: Some(color(mode_colour, PLANE_ALPHA)),
        }),
        PrimitiveKind::Directed => entity.arrows.extend(arrow(
            proxy_m,
            direction,
            primitive.strength_n * FORCE_ARROW_M_PER_N,
            color(mode_colour, 1.0),
        )),
    }
    entity
}

/// The scene of one snapshot: probe, proxy, hand target, force arrow and the tick's primitives, after a
/// deletion of everything drawn before.
pub fn scene_update(snapshot: &Snapshot, timestamp: Timestamp) -> SceneUpdate {
    let mut entities: Vec<SceneEntity> = marker_entities(
        snapshot.probe_m,
        snapshot.proxy_m,
        snapshot.hand_target_m,
        snapshot.sent_force_n,
        timestamp,
    );
    entities.reserve(usize::from(snapshot.primitive_count));
    for (index, primitive) in snapshot.primitives().enumerate() {
        entities.push(primitive_entity(
            index,
            primitive,
            snapshot.proxy_m,
            timestamp,
        ));
    }
    replace_all(entities, timestamp)
}

/// `/voxhap/bound`: the certificate of one tick (JSON, schema `voxhap.Bound`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoundMessage {
    pub tick: u64,
    /// Tick time since the session started (s).
    pub t_s: f64,
    /// Certified bound on the proxy's distance from the exact equilibrium (m); omitted without a certificate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_bound_m: Option<f64>,
    /// Solver sweeps this tick.
    pub sweeps: u32,
    /// How the solve ended: `certified`, `budget_exhausted`, `stalled`, `uncertified`, `input_rejected`.
    pub status: voxhap_core::haptics::tick::TickStatus,
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

/// The JSON schema (draft 2020-12) of a voxhap JSON message titled `title` (`voxhap.Stats`): an object with
/// `properties`. Keywords such as `required` are the caller's to add.
pub fn message_schema(title: &str, properties: serde_json::Value) -> serde_json::Value {
    serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": properties
    })
}

/// The JSON schema of a count: a whole number >= 0, described as `what`.
pub fn count_schema(what: &str) -> serde_json::Value {
    serde_json::json!({"type": "integer", "minimum": 0, "description": what})
}

/// The JSON schema of [`BoundMessage`].
pub fn bound_schema() -> serde_json::Value {
    let mut schema = message_schema(
        "voxhap.Bound",
        serde_json::json!({
            "tick": {"type": "integer", "minimum": 0, "description": "servo tick number"},
            "t_s": {"type": "number", "description": "tick time since the session started (s)"},
            "error_bound_m": {
                "type": "number", "minimum": 0,
                "description": "certified bound on the proxy's distance from the exact equilibrium (m); omitted = no certificate"
            },
            "sweeps": {"type": "integer", "minimum": 0, "description": "solver sweeps this tick"},
            "status": {
                "type": "string",
                "enum": ["certified", "budget_exhausted", "stalled", "uncertified", "input_rejected"],
                "description": "how the solve ended"
            }
        }),
    );
    schema["required"] = serde_json::json!(["tick", "t_s", "sweeps", "status"]);
    schema
}

/// `/voxhap/operating_state`: the CRTK operating state (JSON, schema `voxhap.OperatingState`) as the ROS 2
/// output computes it ([`crtk_operating_state`]: `FAULT` whenever the safety pipeline is faulted,
/// `ENABLED` while force reaches the hand or is about to, else `DISABLED`; `is_busy` while voxhap is bringing
/// the device up or forces ramp in; `is_homed` while a device is connected), and the tick's truth:
/// `force_off_cause`, `device_fault_bits`, `sample_age_ticks`, the energy ledger's totals (`energy`, J), and
/// what a local-model device reported of its own loop (`device_local`, left out on ticks without one).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OperatingStateMessage {
    pub state: &'static str,
    pub is_homed: bool,
    pub is_busy: bool,
    pub force_off_cause: &'static str,
    pub device_fault_bits: u16,
    pub sample_age_ticks: u32,
    pub energy: TickEnergy,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device_local: Option<voxhap_api::DeviceLocal>,
}

impl OperatingStateMessage {
    pub fn new(snapshot: &Snapshot) -> Self {
        let (state, is_homed, is_busy) = crtk_operating_state(Some((
            snapshot.output_state,
            snapshot.truth.force_off_cause,
        )));
        Self::with_state((state, is_homed, is_busy), &snapshot.truth)
    }

    /// The message for a recorded tick without a snapshot (a sim's trace): the CRTK state from whether the
    /// device was `enabled` and the tick's force-off cause.
    pub fn from_truth(enabled: bool, truth: &TickTruth) -> Self {
        let crtk = if truth.force_off_cause.is_fault() {
            ("FAULT", true, false)
        } else if enabled {
            ("ENABLED", true, false)
        } else {
            ("DISABLED", true, false)
        };
        Self::with_state(crtk, truth)
    }

    fn with_state(
        (state, is_homed, is_busy): (&'static str, bool, bool),
        truth: &TickTruth,
    ) -> Self {
        OperatingStateMessage {
            state,
            is_homed,
            is_busy,
            force_off_cause: truth.force_off_cause.name(),
            device_fault_bits: truth.device_fault_bits,
            sample_age_ticks: truth.sample_age_ticks,
            energy: truth.energy,
            device_local: truth.device_local,
        }
    }
}

/// The JSON schema of [`OperatingStateMessage`].
pub fn operating_state_schema() -> serde_json::Value {
    let mut schema = message_schema(
        "voxhap.OperatingState",
        serde_json::json!({
            "state": {"type": "string", "enum": ["ENABLED", "DISABLED", "PAUSED", "FAULT"]},
            "is_homed": {"type": "boolean", "description": "a device is connected"},
            "is_busy": {"type": "boolean", "description": "voxhap is bringing the device up, or forces ramp in"},
            "force_off_cause": {
                "type": "string",
                "enum": ForceOffCause::ALL.iter().map(|c| c.name()).collect::<Vec<_>>(),
                "description": "why the force is off (none: the safety pipeline passes it)"
            },
            "device_fault_bits": {"type": "integer", "minimum": 0, "maximum": 65535, "description": "the device's latched faults, bit n = fault code n"},
            "sample_age_ticks": {"type": "integer", "minimum": 0, "description": "age of the device state the tick rendered from (servo periods)"},
            "energy": energy_schema(),
            "device_local": {
                "type": "object",
                "description": "what a device with the local-model capability reported of its own loop (scene frame); left out on ticks that sent no local model",
                "properties": {
                    "proxy_m": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3, "description": "the proxy the device solved [x, y, z] (m)"},
                    "proxy_bound_m": {"type": "number", "description": "certified error bound of that proxy (m)"},
                    "model_sequence": {"type": "integer", "minimum": 0, "description": "sequence of the model it rendered"},
                    "model_age_s": {"type": "number", "description": "device time since that model arrived (s)"}
                }
            }
        }),
    );
    schema["description"] = serde_json::json!("CRTK operating_state");
    schema["required"] = serde_json::json!([
        "state",
        "is_homed",
        "is_busy",
        "force_off_cause",
        "device_fault_bits",
        "sample_age_ticks",
        "energy"
    ]);
    schema
}

/// The JSON schema of the energy ledger's totals ([`TickEnergy`]; in [`EnergyReport`] with its verdicts).
fn energy_schema() -> serde_json::Value {
    let joules =
        |what: &str| serde_json::json!({"type": "number", "description": format!("{what} (J)")});
    serde_json::json!({
        "type": "object",
        "description": "the energy ledger's totals (zero-order hold, from what the device reported and what was sent)",
        "properties": {
            "work_on_probe_j": joules("work the sent force did on the probe"),
            "coupling_energy_j": joules("energy the coupling spring holds now"),
            "generated_j": joules("energy the renderer generated"),
            "active_work_j": joules("work of the directed-force modes"),
            "device_dissipation_j": joules("the least the device's damping dissipated"),
            "net_generated_j": joules("generated less active work and device dissipation"),
            "passivity_dissipated_j": joules("work the passivity controller's damping took from the probe")
        }
    })
}

/// The JSON schema of [`EnergyReport`]: the totals and the `--fail-on` verdicts.
fn energy_report_schema() -> serde_json::Value {
    let mut schema = energy_schema();
    let properties = &mut schema["properties"];
    properties["largest_rise_j"] = serde_json::json!({"type": "number", "description": "largest rise of the net generated energy over any window (J)"});
    properties["contacts"] =
        serde_json::json!({"type": "integer", "minimum": 0, "description": "contacts begun"});
    properties["longest_cycle_run"] = serde_json::json!({"type": "integer", "minimum": 0, "description": "longest run of undecaying contacts in quick succession"});
    properties["active"] =
        serde_json::json!({"type": "boolean", "description": "--fail-on active would be met"});
    properties["oscillating"] =
        serde_json::json!({"type": "boolean", "description": "--fail-on oscillation would be met"});
    schema
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
    let count = count_schema;
    message_schema(
        "voxhap.Stats",
        serde_json::json!({
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
                "type": "number",
                "description": "worst certificate bound of a tick (m); omitted = a tick without a certificate"
            },
            "device_errors": count("device errors"),
            "disconnects": count("device disconnects"),
            "recorder_drops": count("samples the recorder ring had no room for"),
            "recorder_errors": count("trace write errors (each stops the recording)"),
            "commands_applied": count("control commands applied"),
            "safety": {
                "type": "object",
                "description": "where the output stands and what every safety rule did (README, Safety)",
                "properties": {
                    "output_state": {"type": "string", "description": "disconnected, starting, waiting_to_engage, ramping_in, engaged, recovering, faulted, enable_refused or stale_state"},
                    "output_state_explanation": {"type": "string"},
                    "active_faults": count("latched device faults, bit n = fault code n"),
                    "device_faults": count("faults the device reported"),
                    "device_watchdog_trips": count("device watchdog trips"),
                    "device_rejections": count("commands the device refused"),
                    "enables": count("enables sent"),
                    "not_enabled_ticks": count("ticks with the device not accepting force"),
                    "stale_ticks": count("ticks with zero sent for a stale state"),
                    "positions_rejected": count("implausible positions held"),
                    "velocities_replaced": count("reported velocities replaced by the estimate"),
                    "slew_limited_ticks": count("ticks whose force rise was slew-limited"),
                    "forces_clamped": count("forces clamped to the device maximum"),
                    "monitor_stops": count("stops by the stall monitor"),
                    "events_dropped": count("device events the reporter ring had no room for"),
                    "device_surplus": count("messages the device sent beyond its answers (the newest used)")
                }
            },
            "energy": energy_report_schema(),
            "link_delay": {
                "type": "object",
                "description": "the device link's delay: declared at open, timed every tick, the passivity observer's pairing",
                "properties": {
                    "observer_ticks": count("ticks the passivity observer pairs each force with the motion it meets"),
                    "observer_changes": count("times that pairing changed (following the median round trip plus a period, or a reconnect's measurement)"),
                    "last_change_t_s": {"type": "number", "description": "when it last changed (s); 0 while it never did"},
                    "declared_ms": {"type": "number", "description": "worst case the driver declared at its last open (ms); 0 = none"},
                    "round_trips": count("round trips the driver timed on every tick since its last open"),
                    "typical_ms": {"type": "number", "description": "their median (ms)"},
                    "worst_ms": {"type": "number", "description": "longest round trip timed on any connection (ms)"},
                    "worst_ticks": count("that, in whole servo ticks")
                }
            },
            "realtime": {
                "type": "object",
                "description": "real-time features the servo thread got",
                "properties": {
                    "sched_fifo": {"type": "boolean"},
                    "memory_locked": {"type": "boolean"},
                    "pinned_cpu": {"type": "integer", "description": "omitted = not pinned"}
                }
            }
        }),
    )
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

impl Encode for StatsMessage {
    type Error = serde_json::Error;

    fn get_schema() -> Option<Schema> {
        Some(Schema::new(
            "voxhap.Stats",
            "jsonschema",
            stats_schema().to_string().into_bytes(),
        ))
    }

    fn get_message_encoding() -> String {
        "json".to_owned()
    }

    /// The report as JSON with every `null` field left out (an infinite worst bound, no pinned core): the
    /// schema's types are plain, as Foxglove and Lichtblick require.
    fn encode(&self, buf: &mut impl BufMut) -> Result<(), Self::Error> {
        let mut value = serde_json::to_value(self.0)?;
        drop_null_fields(&mut value);
        serde_json::to_writer(buf.writer(), &value)
    }
}

/// Removes the fields whose value is `null` from every object in `value`.
fn drop_null_fields(value: &mut serde_json::Value) {
    match value {
        serde_json::Value::Object(fields) => {
            fields.retain(|_, field| !field.is_null());
            fields.values_mut().for_each(drop_null_fields);
        }
        serde_json::Value::Array(items) => items.iter_mut().for_each(drop_null_fields),
        _ => {}
    }
}
json_encode!(
    OperatingStateMessage,
    "voxhap.OperatingState",
    operating_state_schema()
);

#[cfg(test)]
mod tests {
    use super::*;
    use ::foxglove::messages::scene_entity_deletion;
    use ::foxglove::Decode;
    use glam::DQuat;
    use voxhap_core::haptics::tick::TickStatus;
    use voxhap_core::haptics::Primitive;

    fn snapshot() -> Snapshot {
        let mut slots = [None; voxhap_core::haptics::modes::MAX_MODES];
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
        assert!(value.get("error_bound_m").is_none(), "{value}");
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

    /// The Foxglove view's operating state is CRTK's, as the ROS 2 output publishes it: FAULT whenever the
    /// safety pipeline is faulted (the supervisor's faulted state, or a tick whose force is off for a device
    /// fault), never ENABLED then; it carries the tick's truth under the names its schema requires.
    #[test]
    fn the_operating_state_is_fault_whenever_the_safety_pipeline_is_faulted() {
        use voxhap_core::status::OutputState;
        let faulted = Snapshot {
            output_state: OutputState::Faulted,
            connected: true,
            engaged: false,
            ..snapshot()
        };
        assert_eq!(OperatingStateMessage::new(&faulted).state, "FAULT");
        for output in OutputState::ALL {
            let snap = Snapshot {
                output_state: output,
                connected: true,
                truth: TickTruth {
                    force_off_cause: ForceOffCause::DeviceFault,
                    device_fault_bits: 0b100,
                    ..TickTruth::default()
                },
                ..snapshot()
            };
            let message = OperatingStateMessage::new(&snap);
            assert_eq!(message.state, "FAULT", "{output:?}");
            let mut bytes = Vec::new();
            message.encode(&mut bytes).unwrap();
            let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
            assert_eq!(value["force_off_cause"], "device_fault");
            assert_eq!(value["device_fault_bits"], 4);
            for key in operating_state_schema()["required"].as_array().unwrap() {
                assert!(value.get(key.as_str().unwrap()).is_some(), "{key}");
            }
        }
        let engaged = Snapshot {
            output_state: OutputState::Engaged,
            ..snapshot()
        };
        assert_eq!(OperatingStateMessage::new(&engaged).state, "ENABLED");
    }

    /// A local-model device's own proxy, bound and model age reach the operating state under the schema's
    /// names, and are left out on a tick without a local model.
    #[test]
    fn the_operating_state_carries_a_local_model_devices_proxy_when_there_is_one() {
        let local = voxhap_api::DeviceLocal {
            proxy_m: glam::DVec3::new(0.01, -0.02, 0.03),
            proxy_bound_m: 2e-9,
            model_sequence: 7,
            model_age_s: 3e-4,
        };
        let snap = Snapshot {
            truth: TickTruth {
                device_local: Some(local),
                ..TickTruth::default()
            },
            ..snapshot()
        };
        let mut bytes = Vec::new();
        OperatingStateMessage::new(&snap)
            .encode(&mut bytes)
            .unwrap();
        let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        let schema = operating_state_schema();
        let fields = schema["properties"]["device_local"]["properties"]
            .as_object()
            .unwrap();
        assert_eq!(
            value["device_local"],
            serde_json::json!({"proxy_m": [0.01, -0.02, 0.03], "proxy_bound_m": 2e-9, "model_sequence": 7, "model_age_s": 3e-4})
        );
        for key in value["device_local"].as_object().unwrap().keys() {
            assert!(fields.contains_key(key), "{key} is not in the schema");
        }
        let mut bytes = Vec::new();
        OperatingStateMessage::new(&snapshot())
            .encode(&mut bytes)
            .unwrap();
        let value: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        assert!(value.get("device_local").is_none(), "{value}");
    }

    /// Every field of the live view's JSON schemas has one plain type: Foxglove Studio and Lichtblick
    /// (`parseJsonSchema`) refuse a type list such as `["number", "null"]` or a field without a type, and
    /// drop the topic. (The recorded schemas are checked rule for rule in the record crate.)
    #[test]
    fn live_json_schemas_use_only_types_the_viewers_accept() {
        fn check(schema: &serde_json::Value, path: &str) {
            assert_eq!(schema["type"], "object", "{path}");
            for (name, field) in schema["properties"].as_object().unwrap() {
                let at = format!("{path}.{name}");
                let kind = field["type"]
                    .as_str()
                    .unwrap_or_else(|| panic!("{at}: {field}"));
                match kind {
                    "object" => check(field, &at),
                    "array" => assert!(field["items"]["type"].is_string(), "{at}"),
                    _ => assert!(
                        ["boolean", "string", "number", "integer"].contains(&kind),
                        "{at}"
                    ),
                }
            }
        }
        check(&bound_schema(), "voxhap.Bound");
        check(&stats_schema(), "voxhap.Stats");
        check(&operating_state_schema(), "voxhap.OperatingState");
        let stats = StatsMessage(StatsReport {
            worst_error_bound_m: f64::INFINITY,
            ..StatsReport::default()
        });
        let mut bytes = Vec::new();
        stats.encode(&mut bytes).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        assert!(!text.contains("null"), "{text}");
    }
}
