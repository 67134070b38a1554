//! Criterion benchmarks of the serial and HID codecs: encode plus decode of one state frame and one set-force frame
//! (the two messages that cross the link every servo tick). Target: under 200 ns each, median.
//!
//! Run: `cargo bench -p voxhap-protocol --bench codec`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use voxhap_protocol::{
    decode_report, encode_frame, encode_report, hid, DeviceToHost, FaultFlags, ForceFlags,
    FrameDecoder, HostToDevice, SetForce, State, StatusFlags, MAX_WIRE_FRAME_LEN,
};

fn state() -> DeviceToHost {
    DeviceToHost::State(State {
        sequence: 123_456,
        device_time_us: 9_876_543_210,
        position_m: [0.012, -0.034, 0.056],
        velocity_m_per_s: [0.1, 0.2, -0.3],
        last_force_sequence: 123_400,
        buttons: 0b01,
        status: StatusFlags::SESSION_OPEN | StatusFlags::ENABLED,
        faults: FaultFlags::EMPTY,
    })
}

fn set_force() -> HostToDevice {
    HostToDevice::SetForce(SetForce {
        sequence: 123_401,
        force_n: [0.5, -1.25, 2.0],
        flags: ForceFlags::EMPTY,
    })
}

fn bench_serial(c: &mut Criterion) {
    let mut group = c.benchmark_group("serial_encode_decode");
    let mut buf = [0u8; MAX_WIRE_FRAME_LEN];

    let message = state();
    let mut decoder = FrameDecoder::<DeviceToHost>::new();
    group.bench_function("state", |b| {
        b.iter(|| {
            let len = encode_frame(black_box(&message), &mut buf).expect("state encodes");
            decoder.feed(black_box(&buf[..len])).next()
        })
    });
    assert_eq!(decoder.stats().dropped(), 0, "bench frames must decode");

    let message = set_force();
    let mut decoder = FrameDecoder::<HostToDevice>::new();
    group.bench_function("set_force", |b| {
        b.iter(|| {
            let len = encode_frame(black_box(&message), &mut buf).expect("set-force encodes");
            decoder.feed(black_box(&buf[..len])).next()
        })
    });
    assert_eq!(decoder.stats().dropped(), 0, "bench frames must decode");
    group.finish();
}

fn bench_hid(c: &mut Criterion) {
    let mut group = c.benchmark_group("hid_encode_decode");
    let mut report = [0u8; hid::REPORT_LEN];
    let message = state();
    group.bench_function("state", |b| {
        b.iter(|| {
            encode_report(black_box(&message), &mut report).expect("state encodes");
            decode_report::<DeviceToHost>(black_box(&report))
        })
    });
    let message = set_force();
    group.bench_function("set_force", |b| {
        b.iter(|| {
            encode_report(black_box(&message), &mut report).expect("set-force encodes");
            decode_report::<HostToDevice>(black_box(&report))
        })
    });
    group.finish();
}

/// The parts of the state round trip, to see where the time goes.
fn bench_parts(c: &mut Criterion) {
    let mut group = c.benchmark_group("state_parts");
    let message = state();
    let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(&message, &mut buf).expect("state encodes");
    group.bench_function("crc16_49_bytes", |b| {
        b.iter(|| voxhap_protocol::crc::crc16(black_box(&buf[..49])))
    });
    group.bench_function("encode_frame", |b| {
        b.iter(|| encode_frame(black_box(&message), black_box(&mut buf)).expect("state encodes"))
    });
    let frame = buf;
    let mut decoder = FrameDecoder::<DeviceToHost>::new();
    group.bench_function("decode_frame_streaming", |b| {
        b.iter(|| decoder.feed(black_box(&frame[..len])).next())
    });
    group.bench_function("decode_frame_slice", |b| {
        b.iter(|| voxhap_protocol::decode_frame::<DeviceToHost>(black_box(&frame[..len])))
    });
    group.finish();
}

criterion_group!(benches, bench_serial, bench_hid, bench_parts);
criterion_main!(benches);
