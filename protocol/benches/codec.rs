//! Criterion benchmarks of the serial and HID codecs: encode plus decode of one state frame and one set-force frame
//! (the two messages that cross the link every servo tick). Target: under 200 ns each, median.
//!
//! Run: `cargo bench -p voxhap-protocol --bench codec`.

use std::hint::black_box;

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, Criterion};
use voxhap_protocol::{
    decode_report, encode_frame, encode_report, hid, DeviceToHost, FaultFlags, ForceFlags,
    FrameDecoder, HostToDevice, Message, SetForce, State, StatusFlags, MAX_WIRE_FRAME_LEN,
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

/// `message` encoded as a serial frame and fed to a streaming decoder, as the benchmark `name` of `group`.
fn bench_frame<M: Message>(group: &mut BenchmarkGroup<'_, WallTime>, name: &str, message: &M) {
    let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
    let mut decoder = FrameDecoder::<M>::new();
    group.bench_function(name, |b| {
        b.iter(|| {
            let len = encode_frame(black_box(message), &mut buf).expect("bench message encodes");
            decoder.feed(black_box(&buf[..len])).next()
        })
    });
    assert_eq!(decoder.stats().dropped(), 0, "bench frames must decode");
}

/// `message` encoded as a HID report and decoded, as the benchmark `name` of `group`.
fn bench_report<M: Message>(group: &mut BenchmarkGroup<'_, WallTime>, name: &str, message: &M) {
    let mut report = [0u8; hid::REPORT_LEN];
    group.bench_function(name, |b| {
        b.iter(|| {
            encode_report(black_box(message), &mut report).expect("bench message encodes");
            decode_report::<M>(black_box(&report))
        })
    });
}

fn bench_serial(c: &mut Criterion) {
    let mut group = c.benchmark_group("serial_encode_decode");
    bench_frame(&mut group, "state", &state());
    bench_frame(&mut group, "set_force", &set_force());
    group.finish();
}

fn bench_hid(c: &mut Criterion) {
    let mut group = c.benchmark_group("hid_encode_decode");
    bench_report(&mut group, "state", &state());
    bench_report(&mut group, "set_force", &set_force());
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
