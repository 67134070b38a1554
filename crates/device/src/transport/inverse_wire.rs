//! The Haply Inverse Service's JSON messages as voxhap reads and writes them: the parts of an inventory or state
//! update it uses ([`WireFrame`] and its parts, unknown keys ignored) and the force command
//! ([`force_message`]). No I/O: [`super::inverse_service`] moves them over the WebSocket.

use glam::DVec3;
use serde::Deserialize;
use tungstenite::Message;

/// A vector as the service writes it.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
pub struct WireVec3 {
    /// x
    #[serde(default)]
    pub x: f64,
    /// y
    #[serde(default)]
    pub y: f64,
    /// z
    #[serde(default)]
    pub z: f64,
}

impl From<WireVec3> for DVec3 {
    fn from(v: WireVec3) -> DVec3 {
        DVec3::new(v.x, v.y, v.z)
    }
}

/// The part of an Inverse3's `state` voxhap reads.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct WireState {
    /// Handle position (m).
    pub cursor_position: Option<WireVec3>,
    /// Handle velocity (m/s).
    pub cursor_velocity: Option<WireVec3>,
}

/// `config.device_info` of the inventory.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct WireDeviceInfo {
    /// Firmware major version.
    pub major_version: Option<u32>,
    /// Firmware minor version.
    pub minor_version: Option<u32>,
    /// Device id.
    pub id: Option<String>,
    /// Device type code.
    pub device_type: Option<u32>,
}

/// The part of an Inverse3's `config` voxhap reads (inventory only).
#[derive(Debug, Clone, Default, Deserialize)]
pub struct WireConfig {
    /// "inverse3", "inverse3x", "minverse".
    #[serde(rename = "type")]
    pub device_type: Option<String>,
    /// Firmware identity.
    pub device_info: Option<WireDeviceInfo>,
    /// "left" or "right".
    pub handedness: Option<String>,
}

/// One Inverse3 in a message.
#[derive(Debug, Clone, Deserialize)]
pub struct WireInverse3 {
    /// The id commands are addressed to.
    pub device_id: String,
    /// Configuration (inventory only).
    pub config: Option<WireConfig>,
    /// State.
    pub state: Option<WireState>,
}

/// A message from the service (inventory or state update).
#[derive(Debug, Clone, Deserialize)]
pub struct WireFrame {
    /// Session id (inventory).
    pub session_id: Option<u64>,
    /// Inverse3 devices (absent: none).
    #[serde(default)]
    pub inverse3: Vec<WireInverse3>,
}

/// The JSON of one force command (and, on the first message, the session configuration).
pub fn force_message(device_id: &str, force_n: DVec3, session: Option<&str>) -> String {
    let mut message = serde_json::json!({
        "inverse3": [{
            "device_id": device_id,
            "commands": {"set_cursor_force": {"vector": {"x": force_n.x, "y": force_n.y, "z": force_n.z}}}
        }]
    });
    if let Some(profile) = session {
        message["session"] = serde_json::json!({
            "configure": {"profile": {"name": profile}, "basis": {"permutation": "XYZ"}}
        });
    }
    message.to_string()
}

/// A text message parsed as a [`WireFrame`]; `None` for any other message or JSON that does not fit.
pub(crate) fn parse_frame(message: &Message) -> Option<WireFrame> {
    match message {
        Message::Text(text) => serde_json::from_str(text.as_str()).ok(),
        _ => None,
    }
}
