//! The hex test vectors in protocol/vectors/, written by an independent Python implementation of SPEC.md
//! (vectors/generate.py), checked both ways: the bytes decode to the expected message, and the message encodes to
//! exactly the bytes. Every vector file must be listed here and every listed vector must exist.

use std::path::{Path, PathBuf};

use voxhap_protocol::{
    decode_frame, decode_report, encode_frame, encode_report, hid, DeviceInfo, DeviceToHost,
    Enable, Fault, FaultCode, FaultFlags, ForceFlags, FrameDecoder, Heartbeat, HeartbeatReply,
    Hello, HostToDevice, Label, Message, RateSet, RejectReason, Rejected, SetForce, SetStateRate,
    State, StatusFlags, Version, MAX_WIRE_FRAME_LEN,
};

pub(crate) enum Expected {
    Host(HostToDevice),
    Device(DeviceToHost),
}

pub(crate) fn expected_vectors() -> Vec<(&'static str, Expected)> {
    use Expected::{Device, Host};
    let label = |text| Label::new(text).expect("valid label");
    // SPEC section 2: this document is 1.1; the 1.0 forms of Hello and DeviceInfo stay valid (same major).
    let device_info = |minor| {
        Device(DeviceToHost::DeviceInfo(DeviceInfo {
            version: Version { major: 1, minor },
            model: label("voxhap-sim"),
            serial_number: label("SN0001"),
            position_dof: 3,
            force_dof: 3,
            button_count: 2,
            supported_rates: RateSet::from_rates_hz(&[250, 500, 1000]).expect("standard rates"),
            workspace_min_m: [-0.08, -0.06, -0.05],
            workspace_max_m: [0.08, 0.06, 0.05],
            max_force_n: 8.5,
            max_stiffness_n_per_m: 2000.0,
        }))
    };
    vec![
        (
            "hello",
            Host(HostToDevice::Hello(Hello {
                version: Version { major: 1, minor: 1 },
            })),
        ),
        (
            "hello_v1_0",
            Host(HostToDevice::Hello(Hello {
                version: Version { major: 1, minor: 0 },
            })),
        ),
        (
            "enable",
            Host(HostToDevice::Enable(Enable {
                watchdog_timeout_us: 50_000,
            })),
        ),
        ("disable", Host(HostToDevice::Disable)),
        (
            "set_force",
            Host(HostToDevice::SetForce(SetForce {
                sequence: 7,
                force_n: [0.5, -1.25, 2.0],
                flags: ForceFlags::REQUEST_STATE,
            })),
        ),
        (
            "heartbeat",
            Host(HostToDevice::Heartbeat(Heartbeat { counter: 42 })),
        ),
        ("clear_fault", Host(HostToDevice::ClearFault)),
        (
            "set_state_rate",
            Host(HostToDevice::SetStateRate(SetStateRate {
                state_rate_hz: 1000,
            })),
        ),
        ("device_info", device_info(1)),
        ("device_info_v1_0", device_info(0)),
        (
            "state",
            Device(DeviceToHost::State(State {
                sequence: 1000,
                device_time_us: 1_234_567_890_123,
                position_m: [0.01, -0.02, 0.03],
                velocity_m_per_s: [0.1, 0.0, -0.25],
                last_force_sequence: 999,
                buttons: 0b01,
                status: StatusFlags::SESSION_OPEN | StatusFlags::ENABLED,
                faults: FaultFlags::EMPTY,
            })),
        ),
        (
            "heartbeat_reply",
            Device(DeviceToHost::Heartbeat(HeartbeatReply {
                counter: 42,
                device_time_us: 5_000_000,
                status: StatusFlags::SESSION_OPEN | StatusFlags::LOCKSTEP,
            })),
        ),
        (
            "fault_watchdog",
            Device(DeviceToHost::Fault(Fault {
                code: FaultCode::WATCHDOG_EXPIRED,
                active_faults: FaultFlags::EMPTY,
                device_time_us: 75_000,
            })),
        ),
        (
            "fault_over_current",
            Device(DeviceToHost::Fault(Fault {
                code: FaultCode::OVER_CURRENT,
                active_faults: FaultFlags::of(FaultCode::OVER_CURRENT)
                    | FaultFlags::of(FaultCode::EMERGENCY_STOP),
                device_time_us: 2_000_000,
            })),
        ),
        (
            "rejected",
            Device(DeviceToHost::Rejected(Rejected {
                message_type: 0x02,
                reason: RejectReason::FAULTED,
            })),
        ),
    ]
    .into_iter()
    .chain(crate::local::expected_local_vectors())
    .collect()
}

fn vectors_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("vectors")
}

struct VectorFile {
    serial: Vec<u8>,
    hid: Vec<u8>,
}

fn parse_hex(text: &str, what: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|pair| {
            u8::from_str_radix(pair, 16).unwrap_or_else(|_| panic!("{what}: bad hex byte {pair:?}"))
        })
        .collect()
}

fn read_vector(name: &str) -> VectorFile {
    let path = vectors_dir().join(format!("{name}.hex"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    assert!(
        lines.next().is_some_and(|l| l.starts_with("# ")),
        "{name}: first line must be a # comment"
    );
    let mut serial = None;
    let mut hid = None;
    for line in lines.filter(|l| !l.trim().is_empty()) {
        if let Some(hex) = line.strip_prefix("serial:") {
            serial = Some(parse_hex(hex, name));
        } else if let Some(hex) = line.strip_prefix("hid:") {
            hid = Some(parse_hex(hex, name));
        } else {
            panic!("{name}: unexpected line {line:?}");
        }
    }
    VectorFile {
        serial: serial.unwrap_or_else(|| panic!("{name}: no serial line")),
        hid: hid.unwrap_or_else(|| panic!("{name}: no hid line")),
    }
}

fn check_both_ways<M: Message>(name: &str, expected: &M, file: &VectorFile) {
    // Bytes -> message, stateless and streaming.
    assert_eq!(
        decode_frame::<M>(&file.serial),
        Ok((*expected, file.serial.len())),
        "{name}: serial decode"
    );
    let mut decoder = FrameDecoder::<M>::new();
    let decoded: Vec<_> = decoder.feed(&file.serial).collect();
    assert_eq!(decoded, vec![Ok(*expected)], "{name}: streaming decode");
    assert_eq!(
        file.hid.len(),
        hid::REPORT_LEN,
        "{name}: HID vector must be a full report"
    );
    assert_eq!(
        decode_report::<M>(&file.hid),
        Ok(*expected),
        "{name}: HID decode"
    );
    // Message -> bytes.
    let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(expected, &mut buf).expect("vector messages are valid");
    assert_eq!(&buf[..len], &file.serial[..], "{name}: serial encode");
    let mut report = [0u8; hid::REPORT_LEN];
    encode_report(expected, &mut report).expect("vector messages are valid");
    assert_eq!(&report[..], &file.hid[..], "{name}: HID encode");
}

#[test]
fn every_vector_decodes_and_encodes_exactly() {
    for (name, expected) in expected_vectors() {
        let file = read_vector(name);
        match expected {
            Expected::Host(message) => check_both_ways(name, &message, &file),
            Expected::Device(message) => check_both_ways(name, &message, &file),
        }
    }
}

#[test]
fn every_vector_file_is_checked() {
    let listed: Vec<&str> = expected_vectors().iter().map(|(name, _)| *name).collect();
    let mut found = 0;
    // The top folder, and local/ (the optional local-model capability, SPEC section 10).
    let folders = [("", vectors_dir()), ("local/", vectors_dir().join("local"))];
    let entries = folders.iter().flat_map(|(prefix, dir)| {
        std::fs::read_dir(dir)
            .expect("protocol/vectors and protocol/vectors/local exist")
            .map(move |entry| (*prefix, entry.expect("readable directory").path()))
    });
    for (prefix, path) in entries {
        if path.extension().is_some_and(|e| e == "hex") {
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .map(|s| format!("{prefix}{s}"))
                .unwrap_or_default();
            assert!(
                listed.contains(&stem.as_str()),
                "{} has no expected message in vectors.rs",
                path.display()
            );
            found += 1;
        }
    }
    assert_eq!(found, listed.len(), "a listed vector file is missing");
}

#[test]
fn every_message_type_has_a_vector() {
    let mut host_types: Vec<u8> = Vec::new();
    let mut device_types: Vec<u8> = Vec::new();
    for (_, expected) in expected_vectors() {
        match expected {
            Expected::Host(m) => host_types.push(m.message_type()),
            Expected::Device(m) => device_types.push(m.message_type()),
        }
    }
    for message_type in 0..=255u8 {
        if HostToDevice::payload_len(message_type).is_some() {
            assert!(
                host_types.contains(&message_type),
                "no vector for host type 0x{message_type:02x}"
            );
        }
        if DeviceToHost::payload_len(message_type).is_some() {
            assert!(
                device_types.contains(&message_type),
                "no vector for device type 0x{message_type:02x}"
            );
        }
    }
}
