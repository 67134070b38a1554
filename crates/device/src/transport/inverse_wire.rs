//! The Haply Inverse Service's JSON messages as voxhap reads and writes them. No I/O:
//! [`super::inverse_service`] moves them over the WebSocket.
//!
//! Reading is tolerant where Haply's own client is ([`parse_frame_text`]): unknown keys are ignored, absent
//! fields keep their previous value (the service's partial-update semantics, docs.haply.co "01. Print
//! Inverse3": sub-fields equal to their identity default are omitted), and identifiers (`session_id`,
//! `device_id`, `config.device_info.id`) are taken as a string or a number (Haply's Rust client, crate `haply`
//! 1.3.1, src/state.rs:561-572 `parse_session_id_best_effort`, parses `session_id` apart from the rest so a
//! bad one never hides the devices). A field voxhap uses that has another JSON type than the documented one
//! (a position that is a string, a permutation that is a number) is a [`WireError::TypeDrift`] naming the
//! field, what was expected and what came, never a silent drop that would later look like a timeout.
//!
//! Writing: [`setup_message`] (the first message of a session: profile, basis, preset, a request for the full
//! state so the configuration can be read back, and a zero force) and [`force_message`] (one per tick).

use glam::{DQuat, DVec3};
use serde_json::{json, Map, Value};

/// The preset voxhap asks for: Haply's default frame (origin on the mounting plate; the documented inventory
/// example, docs.haply.co "WebSocket Protocol", step 1, lists `"preset": "defaults"`).
pub const SESSION_PRESET: &str = "defaults";
/// The basis voxhap asks for: the identity permutation (docs.haply.co "Basis Permutation").
pub const SESSION_BASIS: &str = "XYZ";

/// A field of a service message that voxhap uses and cannot read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// Not JSON at all.
    #[error("the message is not JSON ({reason})")]
    NotJson {
        /// serde_json's description.
        reason: String,
    },
    /// A field has another type than Haply documents.
    #[error("field `{field}` is {got}, where Haply's documentation has {expected}")]
    TypeDrift {
        /// The field's path in the message, e.g. `inverse3[0].state.cursor_position.x`.
        field: String,
        /// The documented type.
        expected: &'static str,
        /// The JSON type that came.
        got: &'static str,
    },
}

/// A transform as the service writes it (`config.mount`, `state.transform`): absent parts are the identity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WireTransform {
    /// Translation (m).
    pub position: DVec3,
    /// Rotation.
    pub rotation: DQuat,
    /// Scale per axis.
    pub scale: DVec3,
}

impl Default for WireTransform {
    fn default() -> Self {
        WireTransform {
            position: DVec3::ZERO,
            rotation: DQuat::IDENTITY,
            scale: DVec3::ONE,
        }
    }
}

impl WireTransform {
    /// True when it moves, turns or scales nothing (to 1e-9).
    pub fn is_identity(&self) -> bool {
        self.position.abs().max_element() < 1e-9
            && (self.scale - DVec3::ONE).abs().max_element() < 1e-9
            && self.rotation.dot(DQuat::IDENTITY).abs() > 1.0 - 1e-9
    }
}

impl std::fmt::Display for WireTransform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (p, r, s) = (self.position, self.rotation, self.scale);
        write!(
            f,
            "position ({}, {}, {}) m, rotation (w {}, x {}, y {}, z {}), scale ({}, {}, {})",
            p.x, p.y, p.z, r.w, r.x, r.y, r.z, s.x, s.y, s.z
        )
    }
}

/// The part of an Inverse3's `state` voxhap reads; `None` where the message left the field out.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WireState {
    /// Handle position (m).
    pub cursor_position: Option<DVec3>,
    /// Handle velocity (m/s).
    pub cursor_velocity: Option<DVec3>,
    /// The force that reached the arm after the service's filters (N).
    pub current_cursor_force: Option<DVec3>,
    /// The workspace transform the service applies.
    pub transform: Option<WireTransform>,
}

/// The part of an Inverse3's `config` voxhap reads (inventory, full state).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WireConfig {
    /// "inverse3", "inverse3x", "minverse".
    pub device_type: Option<String>,
    /// Firmware version "major.minor".
    pub firmware: Option<String>,
    /// "left" or "right".
    pub handedness: Option<String>,
    /// The named preset in force.
    pub preset: Option<String>,
    /// The basis permutation in force.
    pub basis: Option<String>,
    /// The mount transform in force (`Some(identity)` when the service wrote an empty object).
    pub mount: Option<WireTransform>,
    /// The service's filters (force gate, damping), as the service reports them.
    pub filters: Option<String>,
}

/// One Inverse3 in a message.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WireInverse3 {
    /// The id commands are addressed to (a number in the message is written in decimal).
    pub device_id: String,
    /// Configuration (inventory and full state only).
    pub config: Option<WireConfig>,
    /// State.
    pub state: Option<WireState>,
}

/// A message from the service (inventory or state update).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WireFrame {
    /// Session id (inventory), as a string whatever its JSON type.
    pub session_id: Option<String>,
    /// Inverse3 devices (absent: none).
    pub inverse3: Vec<WireInverse3>,
}

/// The JSON type of a value, for [`WireError::TypeDrift`].
fn kind(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

fn drift(field: impl Into<String>, expected: &'static str, value: &Value) -> WireError {
    WireError::TypeDrift {
        field: field.into(),
        expected,
        got: kind(value),
    }
}

/// An identifier: a string, or a number written in decimal.
fn identifier(value: &Value, field: &str) -> Result<String, WireError> {
    match value {
        Value::String(s) => Ok(s.clone()),
        Value::Number(n) => Ok(n.to_string()),
        other => Err(drift(field, "a string or a number", other)),
    }
}

fn object<'a>(value: &'a Value, field: &str) -> Result<&'a Map<String, Value>, WireError> {
    value
        .as_object()
        .ok_or_else(|| drift(field, "an object", value))
}

/// `key` of `map`, unless absent or null.
fn present<'a>(map: &'a Map<String, Value>, key: &str) -> Option<&'a Value> {
    map.get(key).filter(|v| !v.is_null())
}

fn string(value: &Value, field: &str) -> Result<String, WireError> {
    value
        .as_str()
        .map(str::to_owned)
        .ok_or_else(|| drift(field, "a string", value))
}

/// Components of an object `{names[0]: number, ...}`; absent ones keep `default`.
fn components<const N: usize>(
    value: &Value,
    field: &str,
    names: [&str; N],
    default: [f64; N],
) -> Result<[f64; N], WireError> {
    let map = object(value, field)?;
    let mut out = default;
    for (slot, name) in out.iter_mut().zip(names) {
        if let Some(v) = map.get(name) {
            *slot = v
                .as_f64()
                .ok_or_else(|| drift(format!("{field}.{name}"), "a number", v))?;
        }
    }
    Ok(out)
}

fn vec3(value: &Value, field: &str, default: DVec3) -> Result<DVec3, WireError> {
    components(value, field, ["x", "y", "z"], default.to_array()).map(DVec3::from_array)
}

fn transform(value: &Value, field: &str) -> Result<WireTransform, WireError> {
    let map = object(value, field)?;
    let mut t = WireTransform::default();
    if let Some(p) = present(map, "position") {
        t.position = vec3(p, &format!("{field}.position"), DVec3::ZERO)?;
    }
    if let Some(r) = present(map, "rotation") {
        let [w, x, y, z] = components(
            r,
            &format!("{field}.rotation"),
            ["w", "x", "y", "z"],
            [1.0, 0.0, 0.0, 0.0],
        )?;
        t.rotation = DQuat::from_xyzw(x, y, z, w);
    }
    if let Some(s) = present(map, "scale") {
        t.scale = vec3(s, &format!("{field}.scale"), DVec3::ONE)?;
    }
    Ok(t)
}

fn state(value: &Value, at: &str) -> Result<WireState, WireError> {
    let map = object(value, at)?;
    let v3 = |key: &str| -> Result<Option<DVec3>, WireError> {
        present(map, key)
            .map(|v| vec3(v, &format!("{at}.{key}"), DVec3::ZERO))
            .transpose()
    };
    Ok(WireState {
        cursor_position: v3("cursor_position")?,
        cursor_velocity: v3("cursor_velocity")?,
        current_cursor_force: v3("current_cursor_force")?,
        transform: present(map, "transform")
            .map(|v| transform(v, &format!("{at}.transform")))
            .transpose()?,
    })
}

fn config(value: &Value, at: &str) -> Result<WireConfig, WireError> {
    let map = object(value, at)?;
    let text = |key: &str| -> Result<Option<String>, WireError> {
        present(map, key)
            .map(|v| string(v, &format!("{at}.{key}")))
            .transpose()
    };
    let firmware = match present(map, "device_info") {
        Some(info) => {
            let info = object(info, &format!("{at}.device_info"))?;
            let version = |key: &str| {
                present(info, key).map(|v| match v {
                    Value::Number(n) => n.to_string(),
                    Value::String(s) => s.clone(),
                    other => kind(other).to_owned(),
                })
            };
            version("major_version").map(|major| {
                format!(
                    "{major}.{}",
                    version("minor_version").unwrap_or_else(|| "0".to_owned())
                )
            })
        }
        None => None,
    };
    // Haply's client reads `basis` or its older name `coordinate_system` (crate `haply` 1.3.1,
    // src/device_model/devices.rs:123-124).
    let basis = match present(map, "basis").or_else(|| present(map, "coordinate_system")) {
        Some(b) => {
            let b = object(b, &format!("{at}.basis"))?;
            present(b, "permutation")
                .map(|p| string(p, &format!("{at}.basis.permutation")))
                .transpose()?
        }
        None => None,
    };
    Ok(WireConfig {
        device_type: text("type")?,
        firmware,
        handedness: text("handedness")?,
        preset: text("preset")?,
        basis,
        mount: present(map, "mount")
            .map(|v| transform(v, &format!("{at}.mount")))
            .transpose()?,
        filters: present(map, "filters").map(Value::to_string),
    })
}

/// Parses one text message of the simulation channel (module docs for what is tolerated).
pub fn parse_frame_text(text: &str) -> Result<WireFrame, WireError> {
    let root: Value = serde_json::from_str(text).map_err(|e| WireError::NotJson {
        reason: e.to_string(),
    })?;
    let map = object(&root, "the message")?;
    // The session id is only shown to the user: any other type is ignored, as Haply's client does.
    let session_id = present(map, "session_id").and_then(|v| identifier(v, "session_id").ok());
    let mut inverse3 = Vec::new();
    if let Some(devices) = present(map, "inverse3") {
        let devices = devices
            .as_array()
            .ok_or_else(|| drift("inverse3", "an array", devices))?;
        for (i, device) in devices.iter().enumerate() {
            let at = format!("inverse3[{i}]");
            let entry = object(device, &at)?;
            let Some(id) = present(entry, "device_id") else {
                // An entry without an id cannot be ours; Haply's client skips it too.
                continue;
            };
            inverse3.push(WireInverse3 {
                device_id: identifier(id, &format!("{at}.device_id"))?,
                config: present(entry, "config")
                    .map(|v| config(v, &format!("{at}.config")))
                    .transpose()?,
                state: present(entry, "state")
                    .map(|v| state(v, &format!("{at}.state")))
                    .transpose()?,
            });
        }
    }
    Ok(WireFrame {
        session_id,
        inverse3,
    })
}

fn vector(v: DVec3) -> Value {
    json!({"x": v.x, "y": v.y, "z": v.z})
}

/// The JSON of one force command (docs.haply.co "Control Commands": `set_cursor_force`, per tick, N).
pub fn force_message(device_id: &str, force_n: DVec3) -> String {
    json!({
        "inverse3": [{
            "device_id": device_id,
            "commands": {"set_cursor_force": {"vector": vector(force_n)}}
        }]
    })
    .to_string()
}

/// The first message of a session: the profile and the identity basis for the session, the device's preset
/// [`SESSION_PRESET`] and basis [`SESSION_BASIS`] (a preset replaces any mount another program left: mount and
/// preset are exclusive, docs.haply.co tutorial "07. Basis & Mount Playground"), a request for the full state
/// so the answer carries the configuration now in force (`force_render_full_state`, crate `haply` 1.3.1,
/// src/device_model/commands.rs:392-398), and a zero force.
pub fn setup_message(device_id: &str, profile: &str) -> String {
    json!({
        "session": {
            "configure": {"profile": {"name": profile}, "basis": {"permutation": SESSION_BASIS}},
            "force_render_full_state": {}
        },
        "inverse3": [{
            "device_id": device_id,
            "configure": {
                "preset": {"preset": SESSION_PRESET},
                "basis": {"permutation": SESSION_BASIS}
            },
            "commands": {"set_cursor_force": {"vector": vector(DVec3::ZERO)}}
        }]
    })
    .to_string()
}

#[cfg(test)]
#[path = "inverse_wire_tests.rs"]
mod tests;
