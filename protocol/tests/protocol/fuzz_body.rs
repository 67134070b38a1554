//! The body of the cargo-fuzz target `decode` (protocol/fuzz/fuzz_targets/decode.rs includes this file), also run
//! by proptest in the normal test suite so that it keeps compiling and runs where no nightly toolchain exists.
//!
//! It feeds arbitrary bytes to every decoder and checks invariants beyond "no panic": streaming results do not
//! depend on how the input is chunked, every frame is counted exactly once, what decodes re-encodes to the same
//! message, no non-finite force ever comes out, the slice decoder agrees with the streaming one, and the sessions
//! driven by the decoded messages never command a force that is non-finite or above the device maximum.

use voxhap_protocol::{
    decode_frame, decode_report, encode_frame, encode_report, hid, DeviceInfo, DeviceSample,
    DeviceSession, DeviceToHost, FrameDecoder, FrameError, HostSession, HostToDevice, Label,
    Message, RateSet, SliceError, MAX_WIRE_FRAME_LEN, PROTOCOL_VERSION,
};

/// Runs every decoder over `data` and panics if an invariant breaks.
pub fn run(data: &[u8]) {
    let host_messages = check_stream::<HostToDevice>(data);
    let device_messages = check_stream::<DeviceToHost>(data);
    check_report::<HostToDevice>(data);
    check_report::<DeviceToHost>(data);

    for message in &host_messages {
        if let HostToDevice::SetForce(set_force) = message {
            assert!(
                set_force.force_n.iter().all(|f| f.is_finite()),
                "decoder let a non-finite force through"
            );
        }
    }

    // Drive a device session with whatever decoded; the force it commands must stay finite and bounded.
    // Both with and without the local-model capability (SPEC section 10); the capable one also records a loop
    // cycle per message, so its LocalState replies are encoded too.
    let info = fuzz_device_info();
    for capable in [false, true] {
        drive_device(info, capable, data, &host_messages);
    }
    let mut host = HostSession::new();
    for message in &device_messages {
        host.on_message(message);
    }
    let stats = host.stats();
    assert!(stats.states_received + stats.states_stale <= device_messages.len() as u64);
}

fn drive_device(info: DeviceInfo, capable: bool, data: &[u8], host_messages: &[HostToDevice]) {
    let mut device = if capable {
        DeviceSession::with_local_model(info)
    } else {
        DeviceSession::new(info)
    };
    let mut now_us = 0u64;
    for (index, message) in host_messages.iter().enumerate() {
        now_us += 1 + u64::from(data.get(index).copied().unwrap_or(0)) * 500;
        device.on_message(message, now_us);
        if let Some((model, at_us)) = device.local_model() {
            assert!(model
                .si_primitives()
                .all(|p| p.direction.iter().all(|c| c.is_finite())));
            device.record_local_tick(&voxhap_protocol::LocalTick {
                model_sequence: model.sequence,
                model_age_us: (now_us - at_us) as u32,
                ..Default::default()
            });
        }
        let force_n = device.poll(now_us, &DeviceSample::default());
        let norm = force_n.iter().map(|f| f * f).sum::<f32>().sqrt();
        assert!(
            norm.is_finite() && norm <= info.max_force_n * (1.0 + 1e-6),
            "force {force_n:?} escaped the clamp"
        );
        while let Some(reply) = device.poll_transmit() {
            let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
            encode_frame(&reply, &mut buf).expect("the device session only queues valid messages");
        }
    }
}

fn fuzz_device_info() -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("fuzz").expect("valid label"),
        serial_number: Label::new("0").expect("valid label"),
        position_dof: 3,
        force_dof: 3,
        button_count: 2,
        supported_rates: RateSet(0xFF),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 1000.0,
    }
}

fn check_stream<M: Message>(data: &[u8]) -> Vec<M> {
    let mut whole = FrameDecoder::<M>::new();
    let whole_results: Vec<Result<M, FrameError>> = whole.feed(data).collect();

    // Chunking must not matter: split at a point chosen by the data itself, and also push byte by byte.
    let split = usize::from(data.first().copied().unwrap_or(0)).min(data.len());
    let mut chunked = FrameDecoder::<M>::new();
    let mut chunked_results: Vec<Result<M, FrameError>> = chunked.feed(&data[..split]).collect();
    chunked_results.extend(chunked.feed(&data[split..]));
    assert_eq!(whole_results, chunked_results, "results depend on chunking");
    let mut bytewise = FrameDecoder::<M>::new();
    let bytewise_results: Vec<Result<M, FrameError>> =
        data.iter().filter_map(|&b| bytewise.push(b)).collect();
    assert_eq!(whole_results, bytewise_results, "feed and push disagree");

    // Every closed frame is counted exactly once.
    let stats = whole.stats();
    let ok = whole_results.iter().filter(|r| r.is_ok()).count() as u64;
    assert_eq!(stats.frames_ok, ok);
    assert_eq!(
        stats.frames_ok + stats.dropped(),
        whole_results.len() as u64,
        "a frame went uncounted"
    );
    assert_eq!(stats, chunked.stats());

    // What decodes, re-encodes and decodes to the same message.
    let messages: Vec<M> = whole_results.into_iter().filter_map(Result::ok).collect();
    for message in &messages {
        let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
        let len = encode_frame(message, &mut buf).expect("a decoded message re-encodes");
        let (again, consumed) =
            decode_frame::<M>(&buf[..len]).expect("a re-encoded message decodes");
        assert_eq!((again, consumed), (*message, len));
    }

    // The stateless slice decoder finds the same messages.
    let mut rest = data;
    let mut slice_messages = Vec::new();
    loop {
        match decode_frame::<M>(rest) {
            Ok((message, consumed)) => {
                assert!(consumed > 0 && consumed <= rest.len());
                slice_messages.push(message);
                rest = &rest[consumed..];
            }
            Err(SliceError::Invalid { consumed, .. }) => {
                assert!(consumed > 0 && consumed <= rest.len());
                rest = &rest[consumed..];
            }
            Err(SliceError::Incomplete) => break,
        }
    }
    assert_eq!(
        slice_messages, messages,
        "slice and streaming decoders disagree"
    );
    messages
}

fn check_report<M: Message>(data: &[u8]) {
    if let Ok(message) = decode_report::<M>(data) {
        assert!(data.len() <= hid::REPORT_LEN);
        let mut report = [0u8; hid::REPORT_LEN];
        encode_report(&message, &mut report).expect("a decoded message re-encodes");
        assert_eq!(decode_report::<M>(&report), Ok(message));
        let used = 2 + M::payload_len(message.message_type()).expect("known type");
        assert_eq!(
            &report[..used],
            &data[..used],
            "report bytes do not round-trip"
        );
    }
}
