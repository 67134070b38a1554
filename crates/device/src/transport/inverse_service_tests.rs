//! Unit tests of the Inverse Service connection's pure parts.

use super::*;

#[test]
fn urls_must_be_plain_websocket_with_a_port() {
    assert_eq!(
        split_url("ws://127.0.0.1:10001").unwrap().0,
        "127.0.0.1:10001"
    );
    assert_eq!(split_url("ws://localhost:9/x").unwrap().0, "localhost:9");
    for bad in [
        "http://localhost:10001",
        "ws://",
        "ws://localhost",
        "wss://h:1",
    ] {
        assert!(split_url(bad).is_err(), "{bad}");
    }
}

#[test]
fn absent_state_fields_keep_their_previous_value() {
    let mut snapshot = ServiceSnapshot {
        answers_sequence: 0,
        position_m: DVec3::ONE,
        velocity_m_per_s: DVec3::ONE,
        arm_force_n: None,
    };
    let frame = parse_frame_text(
        r#"{"inverse3":[{"device_id":"A","state":{"cursor_velocity":{"x":2.0},"current_cursor_force":{"z":1.5}}}]}"#,
    )
    .unwrap();
    assert!(snapshot.apply(frame.inverse3[0].state.as_ref()));
    assert_eq!(snapshot.position_m, DVec3::ONE);
    assert_eq!(snapshot.velocity_m_per_s, DVec3::new(2.0, 0.0, 0.0));
    assert_eq!(snapshot.arm_force_n, Some(DVec3::new(0.0, 0.0, 1.5)));
}

fn device(text: &str) -> WireInverse3 {
    parse_frame_text(text).unwrap().inverse3.remove(0)
}

#[test]
fn the_read_back_configuration_is_confirmed_only_as_asked_for() {
    // The documented inventory's configuration (docs.haply.co "WebSocket Protocol", step 1).
    let documented = device(
        r#"{"inverse3":[{"device_id":"049D","config":{"preset":"defaults","basis":{"permutation":"XYZ"},
            "mount":{"position":{"x":0,"y":0,"z":0},"rotation":{"w":1,"x":0,"y":0,"z":0},"scale":{"x":1,"y":1,"z":1}}},
            "state":{"transform":{}}}]}"#,
    );
    assert_eq!(
        check_configuration(&documented),
        Ok(Configuration::Confirmed)
    );
    let no_config = device(r#"{"inverse3":[{"device_id":"049D","state":{}}]}"#);
    assert!(matches!(
        check_configuration(&no_config),
        Ok(Configuration::Unconfirmed(why)) if why.contains("config")
    ));
    let mounted = device(
        r#"{"inverse3":[{"device_id":"049D","config":{"preset":"defaults","basis":{"permutation":"XYZ"},
            "mount":{"position":{"x":0.1}}}}]}"#,
    );
    let wrong = check_configuration(&mounted).unwrap_err().to_string();
    assert!(wrong.contains("mount position (0.1, 0, 0)"), "{wrong}");
    let other = device(
        r#"{"inverse3":[{"device_id":"049D","config":{"preset":"arm_front_centered","basis":{"permutation":"XZY"}},
            "state":{"transform":{"scale":{"x":2,"y":2,"z":2}}}}]}"#,
    );
    let wrong = check_configuration(&other).unwrap_err().to_string();
    for part in [
        "preset \"arm_front_centered\"",
        "basis \"XZY\"",
        "workspace transform",
    ] {
        assert!(wrong.contains(part), "{wrong}");
    }
}

/// The spec's two URLs: the simulation channel and, after `,events=`, the events channel (Haply's events
/// channel is its own WebSocket, docs.haply.co "Events Channel", default port 10020 on the service's host).
#[test]
fn a_spec_gives_the_simulation_and_events_urls() {
    let both = ServiceConfig::from_spec("ws://lab:9000,events=ws://lab:9020").unwrap();
    assert_eq!(both.url, "ws://lab:9000");
    assert_eq!(both.events_url.as_deref(), Some("ws://lab:9020"));
    let one = ServiceConfig::from_spec("ws://lab:9000").unwrap();
    assert_eq!((one.url.as_str(), one.events_url), ("ws://lab:9000", None));
    for bad in [
        "lab:9000",
        "ws://",
        "ws://lab:1,events=lab:2",
        "ws://lab:1,events=",
        "ws://a:1,events=ws://b:2,x",
    ] {
        assert!(ServiceConfig::from_spec(bad).is_none(), "{bad}");
    }
}
