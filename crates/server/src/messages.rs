//! The JSON of the visualiser protocol `voxhap.visualiser.v1` (protocol/VISUALISER.md): what the server sends
//! over the WebSocket and REST API, what clients may send, and decoders that name the problem in a bad message.
//!
//! Outgoing messages borrow the session's data ([`State::new`] reads a [`Snapshot`] in place, primitives
//! included). Incoming messages are decoded in two steps: the text to a JSON value (a syntax
//! error is "malformed JSON"), then the value to a typed message with the path of a bad field
//! (`serde_path_to_error`), so `{"command":"set_stiffness","k":"NaN"}` is refused with
//! `k: invalid type: string "NaN", expected f64`. Tagged messages (`"type"`, `"command"`) are re-tagged
//! externally before decoding, because serde loses the field path inside internally tagged enums.

use base64::Engine as _;
use glam::DVec3;
use serde::de::DeserializeOwned;
use serde::ser::SerializeMap as _;
use serde::{Deserialize, Serialize, Serializer};
use serde_json::Value;
use std::path::PathBuf;
use voxhap_api::{
    ControlCommand, ControlReply, SceneReport, Slice, SliceAxis, SliceRequest, Snapshot,
    StatsReport, TickTruth,
};
use voxhap_core::haptics::modes::{ModeConfig, TransferFunction};
use voxhap_record::TraceFormat;

/// The protocol's name and version, sent in `hello`.
pub const SCHEMA: &str = "voxhap.visualiser.v1";
/// Largest message a client may send (WebSocket; larger closes with 1009) and largest REST body (413).
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;
/// State stream rates a client may ask for (Hz).
pub const RATE_RANGE_HZ: (f64, f64) = (1.0, 1000.0);
/// State stream rate without `?rate=` (Hz).
pub const DEFAULT_RATE_HZ: f64 = 60.0;

/// Why a client's message, request body or query was refused: the part at fault and what was wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MessageError {
    /// The body has no JSON at all.
    #[error("the body is empty; expected a JSON object")]
    Empty,
    /// The text is not JSON (serde_json's message, with line and column).
    #[error("malformed JSON: {0}")]
    Malformed(String),
    /// A field does not decode: where it is (empty for the whole message) and serde's message.
    #[error("{}", located(.at, .message))]
    Field {
        /// The path of the field, e.g. `k` or `command "set_stiffness": k`.
        at: String,
        /// What is wrong with it.
        message: String,
    },
    /// A tagged message that is not a JSON object.
    #[error("expected a JSON object with a {0:?} field")]
    NotAnObject(&'static str),
    /// The tag (`"type"`, `"command"`) is not a string.
    #[error("{tag_key:?} must be a string, got {got}")]
    TagNotString {
        /// The tag's key.
        tag_key: &'static str,
        /// The value given.
        got: Value,
    },
    /// The tag is missing.
    #[error("missing field `{0}`")]
    MissingTag(&'static str),
    /// A stream rate that is not a number.
    #[error("rate must be a number of Hz, got {0:?}")]
    RateNotANumber(String),
    /// A stream rate outside [`RATE_RANGE_HZ`].
    #[error("rate must be {min} ..= {max} Hz, got {0}", min = RATE_RANGE_HZ.0, max = RATE_RANGE_HZ.1)]
    Rate(f64),
    /// `POST /api/stiffness` with neither value.
    #[error("give \"k\" (N/m) and/or \"damping\" (N s/m)")]
    NoStiffness,
    /// `POST /api/stiffness` with a negative or non-finite damping.
    #[error("damping must be a finite number >= 0 N s/m, got {0}")]
    Damping(f64),
}

/// `at: message`, or the message alone when `at` is empty.
fn located(at: &str, message: &str) -> String {
    if at.is_empty() {
        message.to_owned()
    } else {
        format!("{at}: {message}")
    }
}

/// Checks a requested stream rate.
pub fn check_rate(rate_hz: f64) -> Result<f64, MessageError> {
    let (min, max) = RATE_RANGE_HZ;
    if rate_hz.is_finite() && (min..=max).contains(&rate_hz) {
        Ok(rate_hz)
    } else {
        Err(MessageError::Rate(rate_hz))
    }
}

// ---------------------------------------------------------------------------------------------------------
// Server to client.

/// First message on a WebSocket.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename = "hello")]
pub struct Hello<'a> {
    pub schema: &'static str,
    /// The state rate this client gets (Hz).
    pub rate_hz: f64,
    /// The servo loop's rate (Hz).
    pub servo_rate_hz: f64,
    pub scene: &'a SceneReport,
}

/// The servo's newest state (WebSocket `state`, and `GET /api/state`): the snapshot's fields as the protocol
/// names them ([`snapshot_fields`]), then `frames_dropped`, then the tick's truth.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename = "state")]
pub struct State<'a> {
    #[serde(flatten, serialize_with = "snapshot_fields")]
    pub snapshot: &'a Snapshot,
    /// State frames this client lost because it read too slowly (0 over REST).
    pub frames_dropped: u64,
    /// The tick's truth: `energy` (the ledger's totals, J), `force_off_cause`, `device_fault_bits`,
    /// `sample_age_ticks`, `device_force_n`, `external_force_n`, `device_local`.
    #[serde(flatten)]
    pub truth: &'a TickTruth,
}

impl<'a> State<'a> {
    pub fn new(snapshot: &'a Snapshot, frames_dropped: u64) -> Self {
        State {
            snapshot,
            frames_dropped,
            truth: &snapshot.truth,
        }
    }
}

/// The fields of a `state` message that come from the snapshot, each written once under its wire name:
/// `force_n` is the force sent to the device (after the safety pipeline), `rendered_force_n` the force the
/// tick rendered (before safety), `primitives` the valid ones, and `error_bound_m` is `null` when the tick
/// has no certificate. The snapshot's other fields (velocity, output state, flags) are not sent.
fn snapshot_fields<S: Serializer>(snapshot: &&Snapshot, serializer: S) -> Result<S::Ok, S::Error> {
    let s = *snapshot;
    let mut map = serializer.serialize_map(None)?;
    // Fields sent under the snapshot's own names: each name written once, as key and as field.
    macro_rules! as_named {
        ($($field:ident),+) => {
            $(map.serialize_entry(stringify!($field), &s.$field)?;)+
        };
    }
    as_named!(tick, t_s, probe_m, proxy_m);
    map.serialize_entry("force_n", &s.sent_force_n)?;
    as_named!(rendered_force_n);
    map.serialize_entry("primitives", &Primitives(s))?;
    let error_bound_m = s.error_bound_m.is_finite().then_some(s.error_bound_m);
    map.serialize_entry("error_bound_m", &error_bound_m)?;
    as_named!(
        status,
        sweeps,
        stiffness_n_per_m,
        damping_n_s_per_m,
        connected,
        engaged,
        scene_generation,
        hand_target_m
    );
    map.end()
}

/// A snapshot's valid primitives as a sequence, read in place.
struct Primitives<'a>(&'a Snapshot);

impl Serialize for Primitives<'_> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_seq(self.0.primitives())
    }
}

/// A control command (or rate change) succeeded.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename = "reply")]
pub struct Reply<'a> {
    pub id: &'a Value,
    pub ok: bool,
    pub message: &'a str,
    pub scene_generation: u64,
}

/// A client message was refused; the connection stays open.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename = "error")]
pub struct ErrorMessage<'a> {
    pub id: &'a Value,
    pub error: &'a str,
}

/// A slice, answering a client's `slice` request.
#[derive(Debug, Serialize)]
#[serde(tag = "type", rename = "slice")]
pub struct SliceMessage<'a> {
    pub id: &'a Value,
    #[serde(flatten)]
    pub slice: &'a Slice,
}

/// A slice as JSON text; with `u8` its values are 8-bit levels in base64 (`values_u8`, byte `b` stands for
/// `min + b (max - min) / 255`, a non-finite value is 0) in place of `values`: about 23 KiB for 128 x 128
/// samples instead of about 180 KiB of decimal numbers (the page asks for this).
pub fn slice_json(slice: &Slice, u8_levels: bool) -> String {
    if !u8_levels {
        return serde_json::to_string(slice).unwrap_or_default();
    }
    let mut value = serde_json::to_value(slice).unwrap_or_default();
    if let Some(object) = value.as_object_mut() {
        object.remove("values");
        let levels = quantise_u8(&slice.values, slice.min, slice.max);
        object.insert(
            "values_u8".to_owned(),
            Value::String(base64::engine::general_purpose::STANDARD.encode(levels)),
        );
    }
    value.to_string()
}

/// `values` mapped linearly from `min..=max` to 0..=255 (rounded); non-finite values and a flat range give 0.
pub fn quantise_u8(values: &[f32], min: f32, max: f32) -> Vec<u8> {
    let span = max - min;
    values
        .iter()
        .map(|&v| {
            let level = (v - min) / span * 255.0;
            if level.is_finite() {
                // In range by construction; the clamp guards rounding at the ends.
                level.round().clamp(0.0, 255.0) as u8
            } else {
                0
            }
        })
        .collect()
}

/// `{"ok": true, ...}` of a REST control request.
#[derive(Debug, Serialize)]
pub struct ControlOk {
    pub ok: bool,
    pub message: String,
    pub scene_generation: u64,
}

impl From<ControlReply> for ControlOk {
    fn from(reply: ControlReply) -> Self {
        ControlOk {
            ok: true,
            message: reply.message,
            scene_generation: reply.scene_generation,
        }
    }
}

/// `{"ok": false, "error": ...}` of a refused REST control request.
#[derive(Debug, Serialize)]
pub struct ControlFailed {
    pub ok: bool,
    pub error: String,
}

impl ControlFailed {
    pub fn new(error: impl Into<String>) -> Self {
        ControlFailed {
            ok: false,
            error: error.into(),
        }
    }
}

/// `{"error": ...}` of a failed read request.
#[derive(Debug, Serialize)]
pub struct ErrorBody {
    pub error: String,
}

/// The server's own counters (`GET /api/stats` → `server`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct ServerStats {
    /// WebSocket clients connected now.
    pub clients: usize,
    pub max_clients: usize,
    /// State frames written to clients.
    pub frames_sent: u64,
    /// State frames dropped because a client's queue was full.
    pub frames_dropped: u64,
    /// WebSocket upgrades refused because `max_clients` were connected.
    pub clients_refused: u64,
    /// Most TCP connections open at once (`max_clients` plus room for page and REST requests).
    pub max_connections: usize,
    /// Connections closed at once because `max_connections` were open.
    pub connections_refused: u64,
    /// Connections closed because nothing was read or written on them for the idle timeout.
    pub idle_closed: u64,
}

/// `GET /api/stats`.
#[derive(Debug, Serialize)]
pub struct StatsBody {
    pub servo: StatsReport,
    pub server: ServerStats,
}

// ---------------------------------------------------------------------------------------------------------
// Client to server.

/// A decoded WebSocket message from a client. `id` is echoed in the answer (any JSON value, `null` if absent).
#[derive(Debug, Clone, PartialEq)]
pub enum ClientMessage {
    Rate {
        id: Value,
        rate_hz: f64,
    },
    Control {
        id: Value,
        token: Option<String>,
        command: ControlCommand,
    },
    Slice {
        id: Value,
        request: SliceRequest,
    },
}

/// A client message that could not be decoded, with the `id` it carried (if any could be read).
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeError {
    pub id: Value,
    pub message: String,
}

#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum ClientWire {
    Rate {
        #[serde(default)]
        id: Value,
        rate_hz: f64,
    },
    Control {
        #[serde(default)]
        id: Value,
        #[serde(default)]
        token: Option<String>,
        command: Value,
    },
    Slice {
        #[serde(default)]
        id: Value,
        #[serde(default)]
        axis: Option<SliceAxis>,
        #[serde(default)]
        size: Option<usize>,
        #[serde(default)]
        at: Option<[f64; 3]>,
        #[serde(default)]
        volume: Option<String>,
    },
}

/// [`ControlCommand`] with an external tag, so a bad field's path survives decoding. A command whose fields a
/// REST endpoint's body has, spelt the same, takes that body ([`ModeBody`], [`VolumeBody`], [`RecordBody`],
/// [`HandBody`]). Kept in step with `ControlCommand` by the exhaustive match in [`CommandWire::from_command`]
/// (a test round-trips every variant).
#[derive(Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum CommandWire {
    SetStiffness {
        k: f64,
    },
    SetDamping {
        damping: f64,
    },
    SetTransfer {
        mode: String,
        transfer: TransferFunction,
    },
    SetModeEnabled {
        mode: String,
        enabled: bool,
    },
    AddMode(ModeBody),
    RemoveMode {
        name: String,
    },
    LoadVolume(VolumeBody),
    StartRecording(RecordBody),
    StopRecording {},
    SetHandTarget(HandBody),
    ClearFault {},
    SetExternalForce {
        force_n: [f64; 3],
    },
}

/// `CommandWire::into_command`, (for the round-trip test) `CommandWire::from_command`, and each REST body's
/// `From<body> for ControlCommand` (what its endpoint applies), from one list of the variants: those with
/// fields, then those that take a REST body (with the body's fields), then those without (a unit variant of
/// `ControlCommand`, an empty struct variant on the wire). `from_command`'s match
/// is exhaustive, so a new `ControlCommand` must be listed, and the body patterns name every field, so a
/// body cannot gain one the command lacks.
macro_rules! command_wire_conversions {
    (
        $($variant:ident { $($field:ident),+ }),+ ;
        $($bodied:ident($body:ident { $($body_field:ident),+ })),+ ;
        $($unit:ident),+
    ) => {
        impl CommandWire {
            fn into_command(self) -> ControlCommand {
                match self {
                    $(CommandWire::$variant { $($field),+ } => ControlCommand::$variant { $($field),+ },)+
                    $(CommandWire::$bodied(body) => body.into(),)+
                    $(CommandWire::$unit {} => ControlCommand::$unit,)+
                }
            }

            #[cfg(test)]
            fn from_command(command: ControlCommand) -> Self {
                match command {
                    $(ControlCommand::$variant { $($field),+ } => CommandWire::$variant { $($field),+ },)+
                    $(ControlCommand::$bodied { $($body_field),+ } => {
                        CommandWire::$bodied($body { $($body_field),+ })
                    })+
                    $(ControlCommand::$unit => CommandWire::$unit {},)+
                    ControlCommand::SetCoupling { .. } => {
                        unreachable!("set_coupling is not a wire command")
                    }
                }
            }
        }

        // The one command a REST body makes: its endpoint's, and the wire's for the same body.
        $(impl From<$body> for ControlCommand {
            fn from($body { $($body_field),+ }: $body) -> Self {
                ControlCommand::$bodied { $($body_field),+ }
            }
        })+
    };
}

command_wire_conversions! {
    SetStiffness { k },
    SetDamping { damping },
    SetTransfer { mode, transfer },
    SetModeEnabled { mode, enabled },
    RemoveMode { name },
    SetExternalForce { force_n };
    AddMode(ModeBody { mode }),
    LoadVolume(VolumeBody { path, name }),
    StartRecording(RecordBody { path, format }),
    SetHandTarget(HandBody { position_m });
    StopRecording,
    ClearFault
}

/// Parses JSON text; a syntax error is "malformed JSON: ...".
pub fn parse_json(bytes: &[u8]) -> Result<Value, MessageError> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(MessageError::Empty);
    }
    serde_json::from_slice(bytes).map_err(|e| MessageError::Malformed(e.to_string()))
}

/// Decodes `value` as `T`, naming the path of a bad field (`k: invalid type: ...`).
pub fn decode_value<T: DeserializeOwned>(value: Value) -> Result<T, MessageError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let mut path = e.path().to_string();
        let message = e.into_inner().to_string();
        // An unknown field's path ends with the field itself, which the message already names.
        if let Some(field) = message
            .strip_prefix("unknown field `")
            .and_then(|rest| rest.split('`').next())
        {
            if let Some(parent) = path.strip_suffix(field) {
                path = parent.trim_end_matches('.').to_owned();
            }
        }
        if path == "." || path == "?" {
            path.clear();
        }
        MessageError::Field { at: path, message }
    })
}

/// Turns `{"<tag_key>": "name", rest...}` into `{"name": {rest...}}`, decodes it as the externally tagged
/// `T`, and reports errors without the tag in the path.
fn decode_tagged<T: DeserializeOwned>(
    value: Value,
    tag_key: &'static str,
) -> Result<T, MessageError> {
    let Value::Object(mut object) = value else {
        return Err(MessageError::NotAnObject(tag_key));
    };
    let tag = match object.remove(tag_key) {
        Some(Value::String(tag)) => tag,
        Some(got) => return Err(MessageError::TagNotString { tag_key, got }),
        None => return Err(MessageError::MissingTag(tag_key)),
    };
    let mut wrapped = serde_json::Map::new();
    wrapped.insert(tag.clone(), Value::Object(object));
    decode_value(Value::Object(wrapped)).map_err(|error| match error {
        MessageError::Field { at, message } => {
            let inner = if at == tag {
                Some("")
            } else {
                at.strip_prefix(&format!("{tag}."))
            };
            match inner {
                Some("") => MessageError::Field {
                    at: format!("{tag_key} {tag:?}"),
                    message,
                },
                Some(inner) => MessageError::Field {
                    at: format!("{tag_key} {tag:?}: {inner}"),
                    message,
                },
                None => MessageError::Field { at, message },
            }
        }
        other => other,
    })
}

/// Decodes a control command (`{"command": "set_stiffness", "k": 400}`).
pub fn decode_command(value: Value) -> Result<ControlCommand, MessageError> {
    decode_tagged::<CommandWire>(value, "command").map(CommandWire::into_command)
}

/// Decodes a WebSocket text message from a client.
pub fn decode_client_message(text: &str) -> Result<ClientMessage, DecodeError> {
    let value = parse_json(text.as_bytes()).map_err(|error| DecodeError {
        id: Value::Null,
        message: error.to_string(),
    })?;
    let id = value.get("id").cloned().unwrap_or(Value::Null);
    let fail = |error: MessageError| DecodeError {
        id: id.clone(),
        message: error.to_string(),
    };
    let wire = decode_tagged::<ClientWire>(value, "type").map_err(fail)?;
    Ok(match wire {
        ClientWire::Rate { id, rate_hz } => ClientMessage::Rate { id, rate_hz },
        ClientWire::Control { id, token, command } => ClientMessage::Control {
            token,
            command: decode_command(command).map_err(|e| DecodeError {
                id: id.clone(),
                message: format!("command: {e}"),
            })?,
            id,
        },
        ClientWire::Slice {
            id,
            axis,
            size,
            at,
            volume,
        } => {
            let default = SliceRequest::default();
            ClientMessage::Slice {
                id,
                request: SliceRequest {
                    axis: axis.unwrap_or(default.axis),
                    size: size.unwrap_or(default.size),
                    at_m: at.map(DVec3::from_array),
                    volume,
                },
            }
        }
    })
}

// ---------------------------------------------------------------------------------------------------------
// REST bodies.

/// `POST /api/stiffness`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StiffnessBody {
    #[serde(default)]
    pub k: Option<f64>,
    #[serde(default)]
    pub damping: Option<f64>,
}

/// `POST /api/modes`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeBody {
    pub mode: ModeConfig,
}

/// `POST /api/modes/{name}/transfer`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransferBody {
    pub transfer: TransferFunction,
}

/// `POST /api/modes/{name}/enabled`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnabledBody {
    pub enabled: bool,
}

/// `POST /api/volume`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeBody {
    pub path: PathBuf,
    #[serde(default)]
    pub name: Option<String>,
}

/// `POST /api/record/start`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordBody {
    pub path: PathBuf,
    #[serde(default)]
    pub format: Option<TraceFormat>,
}

/// `POST /api/hand`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandBody {
    pub position_m: Option<[f64; 3]>,
}

/// `POST /api/record/stop` (an empty body or `{}`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StopRecordingBody {}

impl From<StopRecordingBody> for ControlCommand {
    fn from(StopRecordingBody {}: StopRecordingBody) -> Self {
        ControlCommand::StopRecording
    }
}

/// `DELETE /api/modes/{name}` (an empty body or `{}`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmptyBody {}

#[cfg(test)]
#[path = "messages_tests.rs"]
mod tests;
