//! Tests of the wire messages: each command and reply as JSON, both ways; and protocol/VISUALISER.md held to
//! the keys the server's WebSocket messages carry.

use super::*;
use serde_json::json;
use std::collections::{BTreeMap, BTreeSet};
use voxhap_api::PrimitiveView;
use voxhap_core::haptics::modes::ModeKind;
use voxhap_core::haptics::tick::TickStatus;

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

/// The refusals of the commands whose fields are a REST body's, word for word (the texts they had as
/// struct variants of the wire form): the field's path and serde's message.
#[test]
fn bodied_commands_name_the_field_word_for_word() {
    let cases = [
        json!({"command": "load_volume"}),
        json!({"command": "load_volume", "path": 3}),
        json!({"command": "load_volume", "path": "a.nrrd", "nmae": "b"}),
        json!({"command": "start_recording", "path": "t.csv", "format": "xls"}),
        json!({"command": "start_recording", "format": "csv"}),
        json!({"command": "set_hand_target", "position_m": [0.0, 0.1]}),
        json!({"command": "set_hand_target", "where": null}),
        json!({"command": "add_mode"}),
        json!({"command": "add_mode", "mode": {"kind": "surface", "bogus": 1}}),
        json!({"command": "add_mode", "mode": 7}),
        json!({"command": "stop_recording", "path": "t.csv"}),
    ];
    let refusals: Vec<String> = cases
        .into_iter()
        .map(|value| decode_command(value).unwrap_err().to_string())
        .collect();
    assert_eq!(
        refusals,
        [
            "command \"load_volume\": missing field `path`",
            "command \"load_volume\": path: invalid type: integer `3`, expected path string",
            "command \"load_volume\": unknown field `nmae`, expected `path` or `name`",
            "command \"start_recording\": format: unknown variant `xls`, expected one of `csv`, `mcap`, `parquet`",
            "command \"start_recording\": missing field `path`",
            "command \"set_hand_target\": position_m: invalid length 2, expected an array of length 3",
            "command \"set_hand_target\": unknown field `where`, expected `position_m`",
            "command \"add_mode\": missing field `mode`",
            "command \"add_mode\": mode: unknown field `bogus`, expected one of `kind`, `name`, `volume`, \
             `transfer`, `side`, `surface`, `mu`, `power_budget_w`, `point_m`, `normal`, `strength_n`, `enabled`",
            "command \"add_mode\": mode: invalid type: integer `7`, expected struct ModeConfig",
            "command \"stop_recording\": unknown field `path`, there are no fields",
        ]
    );
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

/// A certified tick with two primitives (a plane and a point).
fn certified_with_primitives() -> Snapshot {
    let plane = PrimitiveView {
        kind: voxhap_core::haptics::PrimitiveKind::Plane,
        mode: 0,
        position_m: DVec3::new(0.001, -0.02, 0.0219),
        direction: DVec3::new(0.0, 0.6, 0.8),
        strength_n: 2.0,
    };
    let point = PrimitiveView {
        kind: voxhap_core::haptics::PrimitiveKind::Point,
        mode: 2,
        direction: DVec3::ZERO,
        strength_n: 0.184,
        ..plane
    };
    let mut slots = [None; voxhap_core::haptics::modes::MAX_MODES];
    slots[0] = Some(plane);
    slots[1] = Some(point);
    Snapshot {
        tick: 2390,
        t_s: 2.39,
        probe_m: DVec3::new(0.00161, -0.01999, 0.02119),
        probe_velocity_m_per_s: DVec3::new(0.1, 0.2, 0.3),
        proxy_m: DVec3::new(0.00106, -0.02008, 0.0219),
        rendered_force_n: DVec3::new(-0.2768, -0.0456, 0.3562),
        sent_force_n: DVec3::new(-0.1, 0.0, 0.25),
        primitive_slots: slots,
        primitive_count: 2,
        error_bound_m: 2.14e-15,
        sweeps: 6,
        flags: 7,
        active_faults: 3,
        ..Snapshot::example()
    }
}

/// A tick with a hand target and every field of the tick's truth set (a device force, a local model).
fn with_every_truth_field() -> Snapshot {
    Snapshot {
        hand_target_m: Some(DVec3::new(0.01, 0.0, -0.02)),
        error_bound_m: 1e-6,
        status: TickStatus::BudgetExhausted,
        damping_n_s_per_m: 1.5,
        scene_generation: 9,
        truth: TickTruth {
            energy: voxhap_api::TickEnergy {
                work_on_probe_j: -0.00213,
                coupling_energy_j: 0.000148,
                generated_j: 4.12e-5,
                active_work_j: 0.5,
                device_dissipation_j: 0.00051,
                net_generated_j: -0.000469,
                passivity_dissipated_j: 0.25,
            },
            force_off_cause: voxhap_api::ForceOffCause::StaleLink,
            device_fault_bits: 0b101,
            sample_age_ticks: 4,
            device_force_n: Some(DVec3::new(0.5, -0.5, 1.0)),
            external_force_n: DVec3::new(0.0, 0.0, -1.25),
            device_local: Some(voxhap_api::DeviceLocal {
                proxy_m: DVec3::new(0.0, 0.001, 0.002),
                proxy_bound_m: 1e-9,
                model_sequence: 12,
                model_age_s: 0.003,
            }),
        },
        ..Snapshot::example()
    }
}

/// The `state` message's exact text for a few snapshots: certified with primitives, no certificate (a `null`
/// bound), a hand target and every truth field set. The literals are the output of the implementation
/// before `State` stopped copying the snapshot's fields (checked key by key against protocol/VISUALISER.md,
/// "`state`"), so the wire form, key order included, stays the same.
#[test]
fn state_text_is_the_wire_form_to_the_byte() {
    let certified = certified_with_primitives();
    let uncertified = Snapshot {
        error_bound_m: f64::INFINITY,
        status: TickStatus::Uncertified,
        connected: false,
        engaged: false,
        ..Snapshot::example()
    };
    let with_truth = with_every_truth_field();
    for (snapshot, frames_dropped, expected) in [
        (
            &certified,
            0,
            r#"{"type":"state","tick":2390,"t_s":2.39,"probe_m":[0.00161,-0.01999,0.02119],"proxy_m":[0.00106,-0.02008,0.0219],"force_n":[-0.1,0.0,0.25],"rendered_force_n":[-0.2768,-0.0456,0.3562],"primitives":[{"kind":"plane","mode":0,"position_m":[0.001,-0.02,0.0219],"direction":[0.0,0.6,0.8],"strength_n":2.0},{"kind":"point","mode":2,"position_m":[0.001,-0.02,0.0219],"direction":[0.0,0.0,0.0],"strength_n":0.184}],"error_bound_m":2.14e-15,"status":"certified","sweeps":6,"stiffness_n_per_m":500.0,"damping_n_s_per_m":0.0,"connected":true,"engaged":true,"scene_generation":1,"hand_target_m":null,"frames_dropped":0,"energy":{"work_on_probe_j":0.0,"coupling_energy_j":0.0,"generated_j":0.0,"active_work_j":0.0,"device_dissipation_j":0.0,"net_generated_j":0.0,"passivity_dissipated_j":0.0},"force_off_cause":"none","device_fault_bits":0,"sample_age_ticks":0,"device_force_n":null,"external_force_n":[0.0,0.0,0.0],"device_local":null}"#,
        ),
        (
            &uncertified,
            3,
            r#"{"type":"state","tick":5,"t_s":0.005,"probe_m":[1.0,0.0,0.0],"proxy_m":[0.0,1.0,0.0],"force_n":[0.0,0.0,1.0],"rendered_force_n":[0.0,0.0,1.0],"primitives":[],"error_bound_m":null,"status":"uncertified","sweeps":2,"stiffness_n_per_m":500.0,"damping_n_s_per_m":0.0,"connected":false,"engaged":false,"scene_generation":1,"hand_target_m":null,"frames_dropped":3,"energy":{"work_on_probe_j":0.0,"coupling_energy_j":0.0,"generated_j":0.0,"active_work_j":0.0,"device_dissipation_j":0.0,"net_generated_j":0.0,"passivity_dissipated_j":0.0},"force_off_cause":"none","device_fault_bits":0,"sample_age_ticks":0,"device_force_n":null,"external_force_n":[0.0,0.0,0.0],"device_local":null}"#,
        ),
        (
            &with_truth,
            17,
            r#"{"type":"state","tick":5,"t_s":0.005,"probe_m":[1.0,0.0,0.0],"proxy_m":[0.0,1.0,0.0],"force_n":[0.0,0.0,1.0],"rendered_force_n":[0.0,0.0,1.0],"primitives":[],"error_bound_m":1e-6,"status":"budget_exhausted","sweeps":2,"stiffness_n_per_m":500.0,"damping_n_s_per_m":1.5,"connected":true,"engaged":true,"scene_generation":9,"hand_target_m":[0.01,0.0,-0.02],"frames_dropped":17,"energy":{"work_on_probe_j":-0.00213,"coupling_energy_j":0.000148,"generated_j":0.0000412,"active_work_j":0.5,"device_dissipation_j":0.00051,"net_generated_j":-0.000469,"passivity_dissipated_j":0.25},"force_off_cause":"stale_link","device_fault_bits":5,"sample_age_ticks":4,"device_force_n":[0.5,-0.5,1.0],"external_force_n":[0.0,0.0,-1.25],"device_local":{"proxy_m":[0.0,0.001,0.002],"proxy_bound_m":1e-9,"model_sequence":12,"model_age_s":0.003}}"#,
        ),
    ] {
        let text = serde_json::to_string(&State::new(snapshot, frames_dropped)).unwrap();
        assert_eq!(text, expected);
    }
}

/// Every key path in `value` (`energy`, `energy.generated_j`); an array's elements are under the array's own
/// path (`primitives.kind`).
fn key_paths(value: &Value, prefix: &str, paths: &mut BTreeSet<String>) {
    match value {
        Value::Object(object) => {
            for (key, child) in object {
                let path = if prefix.is_empty() {
                    key.clone()
                } else {
                    format!("{prefix}.{key}")
                };
                key_paths(child, &path, paths);
                paths.insert(path);
            }
        }
        Value::Array(items) => {
            for item in items {
                key_paths(item, prefix, paths);
            }
        }
        _ => {}
    }
}

/// The words in backticks in a piece of markdown.
fn backticked(text: &str) -> impl Iterator<Item = &str> {
    text.split('`').skip(1).step_by(2)
}

/// The section of protocol/VISUALISER.md under the heading `### TITLE`, up to the next `###` heading.
fn visualiser_section(title: &str) -> String {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../protocol/VISUALISER.md");
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|err| panic!("cannot read {}: {err}", path.display()));
    text.split_once(&format!("\n### {title}\n"))
        .and_then(|(_, rest)| rest.split_once("\n### "))
        .map(|(section, _)| section.to_owned())
        .unwrap_or_else(|| {
            panic!("VISUALISER.md has a section \"### {title}\" followed by another")
        })
}

/// protocol/VISUALISER.md's "Server to client" messages: each paragraph that starts with `**`NAME`**`, up to
/// the next one, by NAME.
fn visualiser_server_messages() -> BTreeMap<String, String> {
    let section = visualiser_section("Server to client");
    let mut messages = BTreeMap::new();
    let mut name = None;
    for line in section.lines() {
        if let Some(rest) = line.strip_prefix("**`") {
            let (message, _) = rest
                .split_once("`**")
                .unwrap_or_else(|| panic!("not a message heading: {line:?}"));
            name = Some(message.to_owned());
        }
        if let Some(name) = &name {
            let paragraph: &mut String = messages.entry(name.clone()).or_default();
            paragraph.push_str(line);
            paragraph.push('\n');
        }
    }
    messages
}

/// What a message's paragraph documents: `keys`, the key paths of its ```json examples and the fields named
/// in backticks in the first column of its table, which must all exist; and `mentioned`, each table field
/// joined to the words in backticks in its meaning (`energy.generated_j`), where the keys of a value the
/// example shows as `null` are documented. A meaning also names values (`none`, `certified`), so its words
/// need not be keys.
fn documented(paragraph: &str) -> (BTreeSet<String>, BTreeSet<String>) {
    let mut keys = BTreeSet::new();
    let mut mentioned = BTreeSet::new();
    let mut lines = paragraph.lines();
    while let Some(line) = lines.next() {
        if line == "```json" {
            let block: Vec<&str> = lines.by_ref().take_while(|l| *l != "```").collect();
            let block = block.join("\n");
            for value in serde_json::Deserializer::from_str(&block).into_iter::<Value>() {
                let value = value.unwrap_or_else(|err| panic!("not JSON ({err}):\n{block}"));
                key_paths(&value, "", &mut keys);
            }
        } else if line.starts_with("| `") {
            let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
            for field in backticked(cells[0]) {
                keys.insert(field.to_owned());
                for word in backticked(cells.get(1).copied().unwrap_or_default()) {
                    mentioned.insert(format!("{field}.{word}"));
                }
            }
        }
    }
    (keys, mentioned)
}

/// A message as the server writes it.
fn wire(message: &impl Serialize) -> Value {
    serde_json::to_value(message).expect("a server message serialises")
}

/// Each server-to-client WebSocket message with every optional part present: a `state` of a tick with
/// primitives, a certificate, a hand target and every field of the tick's truth set (written out field by
/// field, so a new one must be given a value); a `hello` whose scene is recording and has a recording error.
fn every_server_message() -> BTreeMap<&'static str, Value> {
    let certified = certified_with_primitives();
    let snapshot = Snapshot {
        primitive_slots: certified.primitive_slots,
        primitive_count: certified.primitive_count,
        ..with_every_truth_field()
    };
    let scene = SceneReport {
        stiffness_n_per_m: 500.0,
        damping_n_s_per_m: 0.5,
        modes: vec![ModeConfig::new(ModeKind::Viscosity)],
        volumes: vec![voxhap_api::VolumeReport {
            name: "density".to_owned(),
            source: "builtin:density-flow".to_owned(),
            dims: [64, 64, 64],
            kind: "scalar",
            min_m: DVec3::splat(-0.05),
            max_m: DVec3::splat(0.05),
        }],
        device: "sim".to_owned(),
        simulated: true,
        recording: Some("session.mcap".into()),
        recording_error: Some("No space left on device".to_owned()),
    };
    let slice = Slice {
        axis: SliceAxis::Z,
        width: 2,
        height: 1,
        origin_m: DVec3::splat(-0.05),
        u_m: DVec3::X * 0.1,
        v_m: DVec3::Y * 0.1,
        min: 0.0,
        max: 1.0,
        values: vec![0.0, 1.0],
        volume: "density".to_owned(),
        volume_kind: "scalar",
        volume_min_m: DVec3::splat(-0.05),
        volume_max_m: DVec3::splat(0.05),
    };
    let id = json!(4);
    BTreeMap::from([
        (
            "hello",
            wire(&Hello {
                schema: SCHEMA,
                rate_hz: 60.0,
                servo_rate_hz: 1000.0,
                scene: &scene,
            }),
        ),
        ("state", wire(&State::new(&snapshot, 3))),
        (
            "reply",
            wire(&Reply {
                id: &id,
                ok: true,
                message: "stiffness set to 400 N/m",
                scene_generation: 2,
            }),
        ),
        (
            "error",
            wire(&ErrorMessage {
                id: &id,
                error: "unauthorized: wrong token",
            }),
        ),
        (
            "slice",
            wire(&SliceMessage {
                id: &id,
                slice: &slice,
            }),
        ),
    ])
}

/// What a message of the server's sends that its paragraph in VISUALISER.md does not document, and what the
/// paragraph documents that the server does not send. The keys of `hello`'s `scene.modes` are the scene
/// file's (docs/reference/scene.md, generated from the schema) and are not held here.
fn visualiser_drift(documented_messages: &BTreeMap<String, String>) -> Vec<String> {
    let sent = every_server_message();
    let mut problems = Vec::new();
    let names: BTreeSet<&str> = documented_messages.keys().map(String::as_str).collect();
    if names != sent.keys().copied().collect() {
        problems.push(format!(
            "VISUALISER.md documents the messages {names:?}, the server sends {:?}",
            sent.keys().collect::<Vec<_>>()
        ));
    }
    let held = |path: &String| !path.starts_with("scene.modes.");
    for (name, message) in &sent {
        let mut wire_paths = BTreeSet::new();
        key_paths(message, "", &mut wire_paths);
        let (keys, mentioned) =
            documented(documented_messages.get(*name).map_or("", String::as_str));
        for path in wire_paths.iter().filter(|p| held(p)) {
            if !keys.contains(path) && !mentioned.contains(path) {
                problems.push(format!(
                    "`{name}`: the server sends `{path}`, which is not documented"
                ));
            }
        }
        for path in keys.iter().filter(|p| held(p)) {
            if !wire_paths.contains(path) {
                problems.push(format!(
                    "`{name}`: `{path}` is documented, but the server sends no such key"
                ));
            }
        }
    }
    problems
}

/// Every key the server's WebSocket messages carry (every optional part present) is in protocol/VISUALISER.md:
/// in the message's example or its table (a nested key like `device_local.proxy_m` in backticks in its
/// parent's row), and every key the examples and tables show is one the server sends.
#[test]
fn visualiser_protocol_documents_every_key_the_server_sends() {
    let problems = visualiser_drift(&visualiser_server_messages());
    assert!(
        problems.is_empty(),
        "protocol/VISUALISER.md and the server's messages differ:\n{}",
        problems.join("\n")
    );
}

/// The check fails on a drifted page: a key the example renames (missing one way, unknown the other) and a
/// table field that does not exist.
#[test]
fn visualiser_drift_names_missing_and_unknown_keys() {
    let mut messages = visualiser_server_messages();
    let reply = messages.get_mut("reply").expect("a `reply` paragraph");
    *reply = reply.replace("\"scene_generation\": 2", "\"generation\": 2");
    let state = messages.get_mut("state").expect("a `state` paragraph");
    *state = state.replace("| `sweeps` |", "| `sweeps`, `sweep_count` |");
    assert_eq!(
        visualiser_drift(&messages),
        [
            "`reply`: the server sends `scene_generation`, which is not documented",
            "`reply`: `generation` is documented, but the server sends no such key",
            "`state`: `sweep_count` is documented, but the server sends no such key",
        ]
    );
}

/// The `GET /api/stats` example in protocol/VISUALISER.md has every key the server's answer has, and no
/// other (every field of the statistics is a plain value or an object, so the default report has them all;
/// `realtime.pinned_cpu` is `null` there, a leaf like a number).
#[test]
fn visualiser_stats_example_has_exactly_the_keys_of_the_answer() {
    let section = visualiser_section("`GET /api/stats`");
    // The section's JSON example (it has no field table): its key paths, read as a message's paragraph is.
    let (documented_paths, _) = documented(&section);
    assert!(
        !documented_paths.is_empty(),
        "no JSON example in:\n{section}"
    );
    let mut sent_paths = BTreeSet::new();
    let answer = StatsBody {
        servo: voxhap_api::StatsReport::default(),
        server: ServerStats::default(),
    };
    key_paths(&wire(&answer), "", &mut sent_paths);
    let missing: Vec<_> = sent_paths.difference(&documented_paths).collect();
    let unknown: Vec<_> = documented_paths.difference(&sent_paths).collect();
    assert!(
        missing.is_empty() && unknown.is_empty(),
        "GET /api/stats: the example lacks {missing:?}; it shows keys the server does not send: {unknown:?}"
    );
}
