//! The wire format against Haply's own documented messages (docs.haply.co "WebSocket Protocol", step 1: the
//! initial inventory example, copied field by field) and the type drifts voxhap must name.

use super::*;

/// Haply's documented inventory example (docs.haply.co/inverseSDK/service/realtime/websocket-protocol, step 1),
/// with the fields voxhap does not use kept so that they are seen to be ignored.
const DOCUMENTED_INVENTORY: &str = r#"{
  "session_id": 7,
  "inverse3": [{
    "device_id": "049D",
    "config": {
      "type": "inverse3", "port": "COM12",
      "device_info": {"major_version": 7, "minor_version": 4, "id": "049D", "device_type": 4, "uuid": "…"},
      "extended_device_id": "…", "extended_firmware_version": "…",
      "gravity_compensation": {"enabled": true, "scaling_factor": 1.0},
      "handedness": "right", "streaming_mode": "USB",
      "torque_scaling": {"enabled": true}, "home_return": {"enabled": false},
      "preset": "defaults",
      "basis": {"permutation": "XYZ"},
      "mount": {"position": {"x": 0, "y": 0, "z": 0}, "rotation": {"w": 1, "x": 0, "y": 0, "z": 0}, "scale": {"x": 1, "y": 1, "z": 1}},
      "filters": {"force_gate": {"gain": 0.3}, "damping": {"scalar": 0.0}}
    },
    "state": {
      "cursor_position": {"x": 0.0, "y": -0.12, "z": 0.15},
      "cursor_velocity": {"x": 0.0, "y": 0.0, "z": 0.0},
      "angular_position": {"a0": 0.0, "a1": 0.0, "a2": 0.0},
      "body_orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
      "current_cursor_force": {"x": 0.0, "y": 0.0, "z": 0.0},
      "control_domain": "cartesian", "control_mode": "idle",
      "transform": {"position": {"x": 0, "y": 0, "z": 0}, "rotation": {"w": 1, "x": 0, "y": 0, "z": 0}, "scale": {"x": 1, "y": 1, "z": 1}}
    },
    "status": {"calibrated": true, "in_use": false, "power_supply": true, "ready": true, "started": true}
  }]
}"#;

#[test]
fn the_documented_inventory_reads_as_haply_writes_it() {
    let frame = parse_frame_text(DOCUMENTED_INVENTORY).unwrap();
    assert_eq!(frame.session_id.as_deref(), Some("7"));
    let device = &frame.inverse3[0];
    assert_eq!(device.device_id, "049D");
    let config = device.config.as_ref().unwrap();
    assert_eq!(config.device_type.as_deref(), Some("inverse3"));
    assert_eq!(config.firmware.as_deref(), Some("7.4"));
    assert_eq!(config.preset.as_deref(), Some("defaults"));
    assert_eq!(config.basis.as_deref(), Some("XYZ"));
    assert!(config.mount.unwrap().is_identity());
    assert!(config.filters.as_deref().unwrap().contains("force_gate"));
    let state = device.state.unwrap();
    assert_eq!(state.cursor_position, Some(DVec3::new(0.0, -0.12, 0.15)));
    assert_eq!(state.current_cursor_force, Some(DVec3::ZERO));
    assert!(state.transform.unwrap().is_identity());
}

#[test]
fn identifiers_come_as_strings_or_numbers_and_unknown_keys_are_ignored() {
    let frame = parse_frame_text(
        r#"{"session_id": "s-12", "new_key": [1, 2], "inverse3": [{"device_id": 1181, "future": {"a": 1},
            "state": {"cursor_position": {"x": 0.1, "y": 0.2, "z": 0.3, "w": "ignored"}}}]}"#,
    )
    .unwrap();
    assert_eq!(frame.session_id.as_deref(), Some("s-12"));
    assert_eq!(frame.inverse3[0].device_id, "1181");
    // A session id of another type is only a label: ignored, as Haply's client does.
    let frame = parse_frame_text(r#"{"session_id": {"id": 3}, "inverse3": []}"#).unwrap();
    assert_eq!(frame.session_id, None);
}

#[test]
fn identity_parts_left_out_are_the_identity_and_a_real_transform_is_not() {
    // docs.haply.co "01. Print Inverse3": sub-fields equal to their identity default are omitted.
    let frame = parse_frame_text(
        r#"{"inverse3": [{"device_id": "A", "state": {"transform": {}}, "config": {"mount": {"scale": {"x": 2}}}}]}"#,
    )
    .unwrap();
    let device = &frame.inverse3[0];
    assert!(device.state.unwrap().transform.unwrap().is_identity());
    let mount = device.config.as_ref().unwrap().mount.unwrap();
    assert!(!mount.is_identity());
    assert_eq!(mount.scale, DVec3::new(2.0, 1.0, 1.0));
}

#[test]
fn a_type_drift_on_a_field_voxhap_uses_names_the_field_and_both_types() {
    let cases = [
        (
            r#"{"inverse3": [{"device_id": "A", "state": {"cursor_position": "0,0,0"}}]}"#,
            "inverse3[0].state.cursor_position",
            "an object",
            "a string",
        ),
        (
            r#"{"inverse3": [{"device_id": "A", "state": {"cursor_position": {"x": "0.1"}}}]}"#,
            "inverse3[0].state.cursor_position.x",
            "a number",
            "a string",
        ),
        (
            r#"{"inverse3": [{"device_id": true}]}"#,
            "inverse3[0].device_id",
            "a string or a number",
            "a boolean",
        ),
        (
            r#"{"inverse3": [{"device_id": "A", "config": {"basis": {"permutation": 123}}}]}"#,
            "inverse3[0].config.basis.permutation",
            "a string",
            "a number",
        ),
        (
            r#"{"inverse3": {"device_id": "A"}}"#,
            "inverse3",
            "an array",
            "an object",
        ),
    ];
    for (text, field, expected, got) in cases {
        let error = parse_frame_text(text).unwrap_err();
        assert_eq!(
            error,
            WireError::TypeDrift {
                field: field.to_owned(),
                expected,
                got
            },
            "{text}"
        );
        assert!(error.to_string().contains(field));
    }
    assert!(matches!(
        parse_frame_text("{\"inverse3\": ["),
        Err(WireError::NotJson { .. })
    ));
}

#[test]
fn messages_follow_the_documented_command_layout() {
    let value: Value =
        serde_json::from_str(&force_message("049D", DVec3::new(0.0, 0.5, 1.5))).unwrap();
    let vector = &value["inverse3"][0]["commands"]["set_cursor_force"]["vector"];
    assert_eq!(value["inverse3"][0]["device_id"], "049D");
    assert_eq!(vector["y"], 0.5);
    assert_eq!(vector["z"], 1.5);
    assert!(value.get("session").is_none());
    let value: Value = serde_json::from_str(&setup_message("0\"4", "voxhap")).unwrap();
    let device = &value["inverse3"][0];
    assert_eq!(device["device_id"], "0\"4");
    assert_eq!(device["configure"]["preset"]["preset"], "defaults");
    assert_eq!(device["configure"]["basis"]["permutation"], "XYZ");
    // Mount and preset never share a configure block (docs.haply.co tutorial 07).
    assert!(device["configure"].get("mount").is_none());
    assert_eq!(value["session"]["configure"]["profile"]["name"], "voxhap");
    assert!(value["session"]["force_render_full_state"].is_object());
    assert_eq!(device["commands"]["set_cursor_force"]["vector"]["x"], 0.0);
}
