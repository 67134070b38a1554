//! The decoders under hostile input: arbitrary bytes (the fuzz body), corrupted streams of valid frames,
//! resynchronisation after garbage, and each drop reason counted under its own counter.

use proptest::prelude::*;
use voxhap_protocol::{
    cobs, crc::crc16, decode_report, encode_frame, hid, DecoderStats, DeviceToHost, FrameDecoder,
    FrameError, HostToDevice, PayloadError, ReportError, MAX_WIRE_FRAME_LEN,
};

use crate::fuzz_body;
use crate::strategies::{device_to_host, host_to_device};

fn encode_all<M: voxhap_protocol::Message>(messages: &[M]) -> Vec<u8> {
    let mut stream = Vec::new();
    for message in messages {
        let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
        let len = encode_frame(message, &mut buf).expect("valid messages encode");
        stream.extend_from_slice(&buf[..len]);
    }
    stream
}

/// A hand-built frame: COBS(type ‖ payload ‖ CRC) ‖ 0x00, with the CRC right unless `corrupt_crc`.
fn raw_frame(message_type: u8, payload: &[u8], corrupt_crc: bool) -> Vec<u8> {
    let mut body = vec![message_type];
    body.extend_from_slice(payload);
    let crc = crc16(&body) ^ u16::from(corrupt_crc);
    body.extend_from_slice(&crc.to_le_bytes());
    let mut out = vec![0u8; cobs::max_encoded_len(body.len()) + 1];
    let len = cobs::encode(&body, &mut out).expect("sized by max_encoded_len");
    out.truncate(len);
    out.push(0);
    out
}

fn decode_all(bytes: &[u8]) -> (Vec<Result<HostToDevice, FrameError>>, DecoderStats) {
    let mut decoder = FrameDecoder::<HostToDevice>::new();
    let results = decoder.feed(bytes).collect();
    (results, *decoder.stats())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// The cargo-fuzz body on arbitrary bytes (zero-heavy too, so that short frames and delimiters are common).
    #[test]
    fn fuzz_body_on_arbitrary_bytes(data in proptest::collection::vec(any::<u8>(), 0..400)) {
        fuzz_body::run(&data);
    }

    #[test]
    fn fuzz_body_on_zero_heavy_bytes(
        data in proptest::collection::vec(prop_oneof![3 => Just(0u8), 1 => any::<u8>(), 1 => 1u8..4], 0..300)
    ) {
        fuzz_body::run(&data);
    }
}

proptest! {
    /// Valid frames with random bytes flipped, inserted and deleted: the fuzz invariants hold, and every frame the
    /// corruption did not touch still decodes.
    #[test]
    fn corrupted_streams_resynchronise(
        messages in proptest::collection::vec(host_to_device(), 1..20),
        edits in proptest::collection::vec((any::<usize>(), any::<u8>(), 0u8..3), 0..6),
    ) {
        let clean = encode_all(&messages);
        let mut stream = clean.clone();
        let mut touched_frames = std::collections::BTreeSet::new();
        // Map each clean byte to its frame index to know which frames an edit can reach.
        let mut frame_of = Vec::with_capacity(clean.len());
        let mut frame = 0;
        for &byte in &clean {
            frame_of.push(frame);
            if byte == 0 { frame += 1; }
        }
        // Apply edits back to front on positions in the clean stream so that indices stay meaningful.
        let mut positions: Vec<_> = edits.iter().map(|&(at, value, kind)| (at % clean.len(), value, kind)).collect();
        positions.sort_by_key(|p| std::cmp::Reverse(p.0));
        positions.dedup_by_key(|p| p.0);
        for (at, value, kind) in positions {
            // An edit at a delimiter can merge this frame with the next one.
            touched_frames.insert(frame_of[at]);
            if clean[at] == 0 { touched_frames.insert(frame_of[at] + 1); }
            match kind {
                0 => stream[at] ^= value | 1,
                1 => stream.insert(at, value),
                _ => { stream.remove(at); }
            }
            if value == 0 || kind == 2 {
                touched_frames.insert(frame_of[at] + 1);
            }
        }
        fuzz_body::run(&stream);
        let (results, stats) = decode_all(&stream);
        let decoded: Vec<HostToDevice> = results.iter().filter_map(|r| r.ok()).collect();
        for (index, message) in messages.iter().enumerate() {
            if !touched_frames.contains(&index) {
                prop_assert!(decoded.contains(message), "untouched frame {index} was lost");
            }
        }
        prop_assert_eq!(stats.frames_ok + stats.dropped(), results.len() as u64);
    }

    /// Garbage before a stream costs at most the first frame; garbage followed by one 0x00 costs nothing.
    #[test]
    fn garbage_prefix_costs_at_most_one_frame(
        garbage in proptest::collection::vec(any::<u8>(), 0..200),
        messages in proptest::collection::vec(device_to_host(), 1..10),
    ) {
        let clean = encode_all(&messages);
        let mut decoder = FrameDecoder::<DeviceToHost>::new();
        let mut decoded: Vec<DeviceToHost> = decoder.feed(&garbage).filter_map(Result::ok).collect();
        decoded.clear(); // whatever the garbage itself happened to contain does not matter here
        decoded.extend(decoder.feed(&clean).filter_map(Result::ok));
        prop_assert!(decoded.len() + 1 >= messages.len());
        prop_assert_eq!(&decoded[decoded.len() - (messages.len() - 1)..], &messages[1..]);

        let mut flushed = garbage.clone();
        flushed.push(0);
        flushed.extend_from_slice(&clean);
        let mut decoder = FrameDecoder::<DeviceToHost>::new();
        let decoded: Vec<DeviceToHost> = decoder.feed(&flushed).filter_map(Result::ok).collect();
        prop_assert!(decoded.ends_with(&messages));
    }
}

#[test]
fn each_drop_reason_has_its_counter() {
    let good = raw_frame(0x05, &42u32.to_le_bytes(), false);
    let mut stream = Vec::new();
    stream.extend_from_slice(&raw_frame(0x05, &42u32.to_le_bytes(), true)); // CRC
    stream.extend_from_slice(&[0x05, 0x11, 0x00]); // COBS: block promised 4 bytes
    stream.extend_from_slice(&[0x02, 0x11, 0x00]); // too short: one byte
    stream.extend_from_slice(&[0x01; 100]); // oversize, then its delimiter
    stream.push(0x00);
    stream.extend_from_slice(&raw_frame(0x7E, &[], false)); // unknown type
    stream.extend_from_slice(&raw_frame(0x05, &[1, 2, 3], false)); // bad length
    let nan = f32::NAN.to_le_bytes();
    let mut payload = vec![1, 0, 0, 0];
    payload.extend_from_slice(&nan);
    payload.extend_from_slice(&[0; 10]);
    stream.extend_from_slice(&raw_frame(0x04, &payload, false)); // NaN force
    stream.extend_from_slice(&[0x00, 0x00]); // idle filler: not an error
    stream.extend_from_slice(&good);

    let (results, stats) = decode_all(&stream);
    assert_eq!(results.len(), 8);
    assert!(matches!(results[0], Err(FrameError::Crc { .. })));
    assert_eq!(results[1], Err(FrameError::Cobs));
    assert_eq!(results[2], Err(FrameError::TooShort { len: 1 }));
    assert_eq!(results[3], Err(FrameError::Oversize));
    assert_eq!(
        results[4],
        Err(FrameError::Payload(PayloadError::UnknownType(0x7E)))
    );
    assert_eq!(
        results[5],
        Err(FrameError::Payload(PayloadError::BadLength {
            message_type: 0x05,
            expected: 4,
            actual: 3
        }))
    );
    assert_eq!(
        results[6],
        Err(FrameError::Payload(PayloadError::NonFinite {
            message_type: 0x04,
            field: "force_n"
        }))
    );
    assert_eq!(
        results[7],
        Ok(HostToDevice::Heartbeat(voxhap_protocol::Heartbeat {
            counter: 42
        }))
    );
    let expected = DecoderStats {
        frames_ok: 1,
        cobs_errors: 1,
        too_short: 1,
        oversize: 1,
        crc_errors: 1,
        unknown_type: 1,
        bad_length: 1,
        invalid_value: 1,
        bad_reports: 0,
    };
    assert_eq!(stats, expected);
    assert_eq!(stats.dropped(), 7);
}

#[test]
fn device_info_values_are_checked() {
    // A device info whose workspace corners are swapped on x.
    let mut payload = vec![1, 0];
    payload.extend_from_slice(b"model\0\0\0\0\0\0\0serial\0\0\0\0\0\0");
    payload.extend_from_slice(&[3, 3, 0, 0]);
    for v in [0.1f32, -0.1, -0.1, -0.1, 0.1, 0.1, 5.0, 1000.0] {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    let mut decoder = FrameDecoder::<DeviceToHost>::new();
    let results: Vec<_> = decoder.feed(&raw_frame(0x81, &payload, false)).collect();
    assert_eq!(
        results,
        vec![Err(FrameError::Payload(PayloadError::InvalidValue {
            message_type: 0x81,
            field: "workspace_max_m"
        }))]
    );
    // Fixed, it decodes.
    payload[30..34].copy_from_slice(&(-0.1f32).to_le_bytes());
    payload[42..46].copy_from_slice(&0.1f32.to_le_bytes());
    let results: Vec<_> = decoder.feed(&raw_frame(0x81, &payload, false)).collect();
    assert!(
        matches!(results[..], [Ok(DeviceToHost::DeviceInfo(_))]),
        "{results:?}"
    );
}

#[test]
fn hid_reports_are_checked() {
    let mut report = [0u8; hid::REPORT_LEN];
    report[0] = hid::HOST_TO_DEVICE_REPORT_ID;
    report[1] = 0x05;
    assert!(decode_report::<HostToDevice>(&report).is_ok());
    assert_eq!(
        decode_report::<DeviceToHost>(&report),
        Err(ReportError::WrongReportId {
            expected: 2,
            actual: 1
        })
    );
    assert_eq!(
        decode_report::<HostToDevice>(&report[..5]),
        Err(ReportError::BadLength { len: 5 })
    );
    assert_eq!(
        decode_report::<HostToDevice>(&[1]),
        Err(ReportError::BadLength { len: 1 })
    );
    assert_eq!(
        decode_report::<HostToDevice>(&[0u8; 65]),
        Err(ReportError::BadLength { len: 65 })
    );
    report[1] = 0x66;
    assert_eq!(
        decode_report::<HostToDevice>(&report),
        Err(ReportError::Payload(PayloadError::UnknownType(0x66)))
    );
    let mut stats = DecoderStats::default();
    stats.count_report(&decode_report::<HostToDevice>(&report));
    stats.count_report(&decode_report::<HostToDevice>(&[1]));
    assert_eq!(
        (stats.unknown_type, stats.bad_reports, stats.dropped()),
        (1, 1, 2)
    );
}
