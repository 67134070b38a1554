//! The spec device's own codec and state machine, checked before it judges the host: its codec against
//! protocol/vectors/*.hex, its state machine against a host written with the reference crate (SPEC section 6).

use crate::util::spec_device::{types, HostMessage, SpecDevice, SpecDeviceConfig};
use crate::util::spec_serve::PATIENCE;
use std::io::Read;
use std::path::Path;
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// The double's own codec against the vectors (it must agree with the SPEC before it can judge the host).

fn vector_files() -> Vec<(String, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("protocol/vectors");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "hex"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path).unwrap();
            let line = text
                .lines()
                .find_map(|l| l.strip_prefix("serial: "))
                .unwrap_or_else(|| panic!("{} has no serial line", path.display()));
            let bytes = line
                .split_whitespace()
                .map(|h| u8::from_str_radix(h, 16).unwrap())
                .collect();
            (
                path.file_name().unwrap().to_string_lossy().into_owned(),
                bytes,
            )
        })
        .collect()
}

#[test]
fn spec_device_codec_matches_the_vectors() {
    use crate::util::spec_device::{crc16, decode_frame, encode_frame, payload_len};
    assert_eq!(crc16(b"123456789"), 0x29B1, "SPEC section 4.2 check value");
    assert_eq!(crc16(&[]), 0xFFFF);
    let files = vector_files();
    assert!(files.len() >= 12, "only {} vectors", files.len());
    for (name, wire) in files {
        let (last, stuffed) = wire.split_last().unwrap();
        assert_eq!(*last, 0, "{name}: the delimiter ends the frame");
        assert!(!stuffed.contains(&0), "{name}: no 0x00 inside a frame");
        let (message_type, payload) =
            decode_frame(stuffed).unwrap_or_else(|e| panic!("{name}: {e:?}"));
        let expected_len = payload_len(message_type).unwrap();
        assert_eq!(payload.len(), expected_len, "{name}");
        // SPEC section 4.2 "Sizes": payload + 3 unstuffed, + 1 stuffed, + 1 with the delimiter.
        assert_eq!(wire.len(), expected_len + 5, "{name}: wire length");
        assert_eq!(
            encode_frame(message_type, &payload),
            wire,
            "{name}: re-encoding"
        );
    }
    // The SPEC's own examples.
    assert_eq!(
        encode_frame(types::HELLO, &[1, 0]),
        [0x03, 0x01, 0x01, 0x03, 0x9d, 0xc8, 0x00]
    );
    assert_eq!(encode_frame(types::SET_FORCE, &[0; 18]).len(), 23);
    assert_eq!(encode_frame(types::STATE, &[0; 46]).len(), 51);
    assert_eq!(encode_frame(types::DEVICE_INFO, &[0; 62]).len(), 67);
}

/// A host written with the reference crate, to check the double's state machine (SPEC section 6) before the
/// double judges voxhap's host: two independent readings of the SPEC must agree.
struct ReferenceHost {
    port: std::fs::File,
    decoder: voxhap_protocol::FrameDecoder<voxhap_protocol::DeviceToHost>,
}

impl ReferenceHost {
    fn open(path: &str) -> ReferenceHost {
        use std::os::fd::AsRawFd;
        use std::os::unix::fs::OpenOptionsExt;
        let port = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(path)
            .unwrap();
        // SAFETY: termios is plain data, filled by tcgetattr and applied to our own fd.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(port.as_raw_fd(), &mut t), 0);
            libc::cfmakeraw(&mut t);
            assert_eq!(libc::tcsetattr(port.as_raw_fd(), libc::TCSANOW, &t), 0);
        }
        ReferenceHost {
            port,
            decoder: voxhap_protocol::FrameDecoder::new(),
        }
    }

    fn send(&mut self, message: voxhap_protocol::HostToDevice) {
        use std::io::Write;
        let mut frame = [0u8; voxhap_protocol::MAX_WIRE_FRAME_LEN];
        let len = voxhap_protocol::encode_frame(&message, &mut frame).unwrap();
        self.port.write_all(&frame[..len]).unwrap();
    }

    /// Every message decoded until `expected` have come (or [`PATIENCE`] passed), and for 100 ms after, so that
    /// an unexpected extra reply shows too. The wait is for a count, not a time, because a loaded machine can hold
    /// the pty's bytes back far longer than the double takes to answer.
    fn receive(&mut self, expected: usize) -> Vec<voxhap_protocol::DeviceToHost> {
        let mut deadline = Instant::now() + PATIENCE;
        let mut complete = false;
        let mut messages = Vec::new();
        let mut buffer = [0u8; 256];
        while Instant::now() < deadline {
            if !complete && messages.len() >= expected {
                complete = true;
                deadline = Instant::now() + Duration::from_millis(100);
            }
            match self.port.read(&mut buffer) {
                Ok(n) if n > 0 => {
                    for &byte in &buffer[..n] {
                        if let Some(decoded) = self.decoder.push(byte) {
                            messages
                                .push(decoded.expect("the double sent a frame the crate rejects"));
                        }
                    }
                }
                _ => std::thread::sleep(Duration::from_millis(1)),
            }
        }
        messages
    }
}

#[test]
fn spec_device_follows_section_6_as_the_reference_crate_reads_it() {
    use voxhap_protocol::{
        DeviceToHost, Enable, FaultCode, Heartbeat, Hello, HostToDevice, RejectReason, SetForce,
        StatusFlags, PROTOCOL_VERSION,
    };
    let mut device = SpecDevice::spawn(SpecDeviceConfig {
        max_force_n: 4.0,
        ..SpecDeviceConfig::default()
    });
    let mut host = ReferenceHost::open(device.path());
    let set_force = |sequence, force_n| {
        HostToDevice::SetForce(SetForce {
            sequence,
            force_n,
            flags: voxhap_protocol::ForceFlags::EMPTY,
        })
    };

    // Before Hello: Enable is refused for want of a session; SetForce is ignored silently.
    host.send(HostToDevice::Enable(Enable {
        watchdog_timeout_us: 0,
    }));
    host.send(set_force(1, [1.0, 0.0, 0.0]));
    match host.receive(1).as_slice() {
        [DeviceToHost::Rejected(r)] => assert_eq!(r.reason, RejectReason::NO_SESSION),
        other => panic!("before Hello: {other:?}"),
    }

    host.send(HostToDevice::Hello(Hello {
        version: PROTOCOL_VERSION,
    }));
    match host.receive(1).as_slice() {
        [DeviceToHost::DeviceInfo(info)] => {
            assert_eq!(info.max_force_n, 4.0);
            assert_eq!(info.model.as_str(), "spec-device");
        }
        other => panic!("Hello: {other:?}"),
    }
    host.send(HostToDevice::Heartbeat(Heartbeat { counter: 7 }));
    host.send(set_force(1, [0.0; 3]));
    let replies = host.receive(2);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::Heartbeat(h), DeviceToHost::State(s)]
            if h.counter == 7 && s.last_force_sequence == 1
                && s.status.contains(StatusFlags::SESSION_OPEN | StatusFlags::LOCKSTEP)
                && !s.status.contains(StatusFlags::ENABLED)),
        "Heartbeat and lockstep State: {replies:?}"
    );

    // Enabled: a force above max_force_n is applied clamped, and the State says so. Then no SetForce for the 50 ms
    // default: the watchdog fires once, 50 ms (plus at most a few control periods) later.
    host.send(HostToDevice::Enable(Enable {
        watchdog_timeout_us: 0,
    }));
    host.send(set_force(2, [30.0, 40.0, 0.0]));
    let replies = host.receive(2);
    match replies.as_slice() {
        [DeviceToHost::State(s), DeviceToHost::Fault(f)] => {
            assert_eq!(s.last_force_sequence, 2);
            assert!(
                s.status
                    .contains(StatusFlags::ENABLED | StatusFlags::FORCE_CLAMPED),
                "{s:?}"
            );
            assert_eq!(f.code, FaultCode::WATCHDOG_EXPIRED);
            let after_us = f.device_time_us - s.device_time_us;
            assert!(
                (50_000..=80_000).contains(&after_us),
                "watchdog after {after_us} us"
            );
        }
        other => panic!("enabled, then silent: {other:?}"),
    }
    let logged = device.forces();
    assert_eq!(logged.len(), 3, "{logged:?}");
    assert!(!logged[0].enabled && !logged[1].enabled && logged[2].enabled);

    host.send(HostToDevice::Heartbeat(Heartbeat { counter: 8 }));
    let replies = host.receive(1);
    assert!(
        matches!(replies.as_slice(), [DeviceToHost::Heartbeat(h)]
            if h.status.contains(StatusFlags::WATCHDOG_TRIPPED) && !h.status.contains(StatusFlags::ENABLED)),
        "after the watchdog: {replies:?}"
    );
    device.stop();
    let messages: Vec<_> = device.messages().iter().map(|m| m.message).collect();
    assert_eq!(
        messages,
        [
            HostMessage::Enable {
                watchdog_timeout_us: 0
            },
            HostMessage::Hello { major: 1, minor: 1 },
            HostMessage::Heartbeat { counter: 7 },
            HostMessage::Enable {
                watchdog_timeout_us: 0
            },
            HostMessage::Heartbeat { counter: 8 },
        ]
    );
}
