//! Tests of the wire messages: each command and reply as JSON, both ways.

use super::*;
use serde_json::json;
use voxhap_core::haptics::modes::ModeKind;

#[test]
fn every_command_round_trips_through_the_wire_form() {
    let commands = vec![
        ControlCommand::SetStiffness { k: 400.0 },
        ControlCommand::SetDamping { damping: 1.5 },
        ControlCommand::SetTransfer {
            mode: "surface".into(),
            transfer: TransferFunction::new(vec![[0.0, 0.0], [1.0, 2.0]]).unwrap(),
        },
        ControlCommand::SetModeEnabled {
            mode: "surface".into(),
            enabled: false,
        },
        ControlCommand::AddMode {
            mode: ModeConfig::new(ModeKind::Viscosity),
        },
        ControlCommand::RemoveMode { name: "v".into() },
        ControlCommand::LoadVolume {
            path: "a.nrrd".into(),
            name: Some("density".into()),
        },
        ControlCommand::StartRecording {
            path: "t.mcap".into(),
            format: Some(TraceFormat::Mcap),
        },
        ControlCommand::StopRecording,
        ControlCommand::SetHandTarget {
            position_m: Some([0.01, 0.0, 0.02]),
        },
        ControlCommand::SetHandTarget { position_m: None },
        ControlCommand::SetExternalForce {
            force_n: [0.5, -1.0, 2.0],
        },
    ];
    for command in commands {
        // The library's own (internally tagged) JSON decodes to the same command ...
        let text = serde_json::to_value(&command).unwrap();
        assert_eq!(decode_command(text).unwrap(), command);
        // ... and the wire form covers every variant.
        let wire = CommandWire::from_command(command.clone());
        assert_eq!(wire.into_command(), command);
    }
}

#[test]
fn slices_quantise_to_eight_bits() {
    assert_eq!(
        quantise_u8(&[0.0, 0.5, 1.0, f32::NAN, 2.0, -1.0], 0.0, 1.0),
        [0, 128, 255, 0, 255, 0]
    );
    assert_eq!(quantise_u8(&[3.0, 3.0], 3.0, 3.0), [0, 0], "a flat slice");
}

#[test]
fn bad_commands_name_the_field() {
    let err = decode_command(json!({"command": "set_stiffness", "k": "NaN"}))
        .unwrap_err()
        .to_string();
    assert!(
        err.starts_with("command \"set_stiffness\": k: invalid type: string \"NaN\""),
        "{err}"
    );
    let err = decode_command(json!({"command": "set_stiffness", "kk": 4}))
        .unwrap_err()
        .to_string();
    assert!(err.contains("unknown field `kk`"), "{err}");
    let err = decode_command(json!({"command": "set_stifness", "k": 4}))
        .unwrap_err()
        .to_string();
    assert!(err.contains("unknown variant `set_stifness`"), "{err}");
    let err = decode_command(json!({"k": 4})).unwrap_err().to_string();
    assert_eq!(err, "missing field `command`");
    let err =
        decode_command(json!({"command": "add_mode", "mode": {"kind": "surface", "bogus": 1}}))
            .unwrap_err()
            .to_string();
    assert!(err.contains("mode: unknown field `bogus`"), "{err}");
}

#[test]
fn client_messages_decode_or_say_why() {
    let m = decode_client_message(r#"{"type":"rate","rate_hz":200}"#).unwrap();
    assert_eq!(
        m,
        ClientMessage::Rate {
            id: Value::Null,
            rate_hz: 200.0
        }
    );
    let m = decode_client_message(
        r#"{"type":"control","id":7,"token":"t","command":{"command":"set_stiffness","k":400}}"#,
    )
    .unwrap();
    assert!(matches!(
        m,
        ClientMessage::Control { id: Value::Number(_), command: ControlCommand::SetStiffness { k }, .. } if k == 400.0
    ));
    let m =
        decode_client_message(r#"{"type":"slice","id":"a","axis":"x","size":64,"at":[0,0,0.01]}"#)
            .unwrap();
    let ClientMessage::Slice { id, request } = m else {
        panic!("a slice")
    };
    assert_eq!(id, json!("a"));
    assert_eq!(request.axis, SliceAxis::X);
    assert_eq!(request.size, 64);
    let err = decode_client_message("{nope").unwrap_err();
    assert!(err.message.starts_with("malformed JSON"), "{err:?}");
    let err = decode_client_message(
        r#"{"type":"control","id":3,"command":{"command":"set_damping","damping":"x"}}"#,
    )
    .unwrap_err();
    assert_eq!(err.id, json!(3));
    assert!(err.message.contains("damping: invalid type"), "{err:?}");
    let err = decode_client_message(r#"{"type":"dance","id":4}"#).unwrap_err();
    assert!(err.message.contains("unknown variant `dance`"), "{err:?}");
    assert_eq!(err.id, json!(4));
}

#[test]
fn state_serialises_the_contract_fields() {
    let snapshot = Snapshot {
        sent_force_n: DVec3::Z * 0.5,
        error_bound_m: f64::INFINITY,
        ..Snapshot::example()
    };
    let value = serde_json::to_value(State::new(&snapshot, 3)).unwrap();
    assert_eq!(value["type"], "state");
    assert_eq!(value["force_n"], json!([0.0, 0.0, 0.5]));
    assert_eq!(value["error_bound_m"], Value::Null);
    assert_eq!(value["primitives"], json!([]));
    assert_eq!(value["frames_dropped"], 3);
    assert_eq!(value["hand_target_m"], Value::Null);
    // The tick's truth, with its names as the docs give them.
    assert_eq!(value["force_off_cause"], "none");
    assert_eq!(value["device_fault_bits"], 0);
    assert_eq!(value["sample_age_ticks"], 0);
    assert_eq!(value["energy"]["net_generated_j"], 0.0);
    let faulted = Snapshot {
        truth: TickTruth {
            force_off_cause: voxhap_api::ForceOffCause::StaleLink,
            device_fault_bits: 0b10,
            sample_age_ticks: 5,
            ..TickTruth::default()
        },
        ..Snapshot::example()
    };
    let value = serde_json::to_value(State::new(&faulted, 0)).unwrap();
    assert_eq!(value["force_off_cause"], "stale_link");
    assert_eq!(value["device_fault_bits"], 2);
    assert_eq!(value["sample_age_ticks"], 5);
}
