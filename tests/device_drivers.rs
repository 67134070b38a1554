//! Driver tests against scripted transports, byte for byte, with the formats taken from public sources:
//!
//! - voxhap protocol: protocol/vectors/*.hex (SPEC.md section 8, written by an independent Python encoder);
//! - WoodenHaptics 1.5: WoodenHaptics/woody-experimental `mbed-code/main.cpp` (report structs) and
//!   forsslund/chai3d `src/devices/CWoodenDevice.cpp` (USB branch: report id 0 + 8 bytes, kinematics);
//! - Haply 2DIY: HaplyHaptics/Haply-API-cpp `src/Haply/Board.cpp` and `src/Haply/Device.cpp` (V2.1.0 command
//!   layout), and the 2DIY setup values of the HaplyHAPI Python package (PyPI) README and the Haply examples.
//!
//! Also: the lifecycle wrapper's ordering rules, and property tests that arbitrary bytes from a device never make a
//! driver panic.

use glam::DVec3;
use proptest::prelude::*;
use std::time::Duration;
use voxhap::device::drivers::haply::{Haply2Diy, Haply2DiyConfig};
use voxhap::device::drivers::protocol::{ProtocolConfig, ProtocolDevice, SerialLink};
use voxhap::device::drivers::woodenhaptics::{
    decode_input, encode_output, hfab_counts, WoodenHaptics, KINEMATICS as WOODENHAPTICS_HID,
    MAX_CURRENT_MA as WOODENHAPTICS_HID_MAX_MA,
};
use voxhap::device::drivers::HidLink;
use voxhap::device::transport::memory::{
    ReportTiming, ScriptedReports, ScriptedStream, Transaction,
};
use voxhap::device::Error as _;
use voxhap::device::{ErrorKind, HapticDevice, Lifecycle, LifecycleState};
use voxhap_protocol::{
    encode_frame, encode_report, DeviceToHost, FaultFlags, State, StatusFlags, MAX_WIRE_FRAME_LEN,
};

fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|byte| u8::from_str_radix(byte, 16).unwrap())
        .collect()
}

/// The `serial:` line of a protocol test vector.
fn vector(name: &str) -> Vec<u8> {
    let path = format!("{}/protocol/vectors/{name}.hex", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap();
    let line = text
        .lines()
        .find_map(|l| l.strip_prefix("serial: "))
        .unwrap();
    hex(line)
}

fn state_frame(sequence: u32, echo: u32, x_m: f32) -> Vec<u8> {
    let state = DeviceToHost::State(State {
        sequence,
        device_time_us: 1_000 * u64::from(sequence),
        position_m: [x_m, 0.0, 0.0],
        velocity_m_per_s: [0.0; 3],
        last_force_sequence: echo,
        buttons: 0,
        status: StatusFlags::SESSION_OPEN,
        faults: FaultFlags::EMPTY,
    });
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(&state, &mut frame).unwrap();
    frame[..len].to_vec()
}

/// The handshake's Heartbeat (its nonce), encoded by the protocol crate.
fn heartbeat_frame(counter: u32) -> Vec<u8> {
    let message = voxhap_protocol::HostToDevice::Heartbeat(voxhap_protocol::Heartbeat { counter });
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(&message, &mut frame).unwrap();
    frame[..len].to_vec()
}

/// The device's HeartbeatReply with `status`.
fn heartbeat_reply_frame(counter: u32, status: StatusFlags) -> Vec<u8> {
    let reply = DeviceToHost::Heartbeat(voxhap_protocol::HeartbeatReply {
        counter,
        device_time_us: 1,
        status,
    });
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(&reply, &mut frame).unwrap();
    frame[..len].to_vec()
}

/// The handshake nonce the scripted tests fix.
const NONCE: u32 = 7;

/// SetForce frames are encoded by the protocol crate, whose encoder the crate's own tests hold to the vectors.
fn set_force_frame(sequence: u32, force_n: [f32; 3]) -> Vec<u8> {
    let message = voxhap_protocol::HostToDevice::SetForce(voxhap_protocol::SetForce {
        sequence,
        force_n,
        flags: voxhap_protocol::ForceFlags::EMPTY,
    });
    let mut frame = [0u8; MAX_WIRE_FRAME_LEN];
    let len = encode_frame(&message, &mut frame).unwrap();
    frame[..len].to_vec()
}

#[test]
fn protocol_driver_handshake_enable_force_disable_over_serial_match_the_vectors() {
    let stream = ScriptedStream::new(&[
        Transaction::write(&[0x00]),
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE)),
        Transaction::Read(vector("device_info")),
        Transaction::Read(heartbeat_reply_frame(NONCE, StatusFlags::SESSION_OPEN)),
        Transaction::Write(set_force_frame(1, [0.0; 3])),
        Transaction::Read(state_frame(1, 1, 0.01)),
        Transaction::Write(vector("enable")),
        Transaction::Write(set_force_frame(2, [0.5, -1.25, 2.0])),
        // A late state (echo 1) first, then the answer (echo 2): the driver skips the late one.
        Transaction::Read(state_frame(2, 1, 0.02)),
        Transaction::Read(state_frame(3, 2, 0.03)),
        Transaction::Write(set_force_frame(3, [0.0; 3])),
        Transaction::Write(vector("disable")),
        // Close writes zero and Disable once more, whatever the host believed (docs/safety.md).
        Transaction::Write(set_force_frame(4, [0.0; 3])),
        Transaction::Write(vector("disable")),
    ]);
    let mut device = Lifecycle::new(
        ProtocolDevice::new(SerialLink::new(stream), ProtocolConfig::default())
            .with_handshake_nonce(NONCE),
    );
    device.open().unwrap();
    assert_eq!(device.info().model, "voxhap-sim");
    assert_eq!(device.info().state_rates_hz, [250, 500, 1000]);
    assert!((device.info().max_force_n - 8.5).abs() < 1e-6);
    device.enable().unwrap();
    device.write_force(DVec3::new(0.5, -1.25, 2.0)).unwrap();
    let state = device.read_state().unwrap();
    assert!((state.position_m.x - 0.03).abs() < 1e-7);
    assert_eq!(device.device().counters().late_states, 1);
    device.disable().unwrap();
    device.close().unwrap();
    device.device().link().transport().done();
}

#[test]
fn protocol_driver_times_out_and_reports_a_disconnect() {
    // No answer: Hello (each with its nonce Heartbeat) is sent six times in the default 3 s (waits of 0.1, 0.2,
    // 0.4, 0.8, 1 and the last 0.5 s; SPEC 7.1), then open fails naming what it sent.
    let config = ProtocolConfig::default();
    let waits: Vec<Duration> = config.hello_waits().collect();
    assert_eq!(
        waits,
        [100, 200, 400, 800, 1000, 500].map(Duration::from_millis),
        "the Hello schedule"
    );
    let mut script = vec![Transaction::write(&[0x00])];
    for attempt in 0..6 {
        script.push(Transaction::Write(vector("hello")));
        script.push(Transaction::Write(heartbeat_frame(NONCE + attempt)));
        script.push(Transaction::ReadTimeout);
    }
    let stream = ScriptedStream::new(&script);
    let mut device =
        ProtocolDevice::new(SerialLink::new(stream), config).with_handshake_nonce(NONCE);
    let error = device.open().unwrap_err();
    assert_eq!(error.kind(), ErrorKind::Timeout);
    assert!(
        error
            .to_string()
            .contains("no DeviceInfo answering Hello within")
            && error.to_string().contains("(6 Hellos sent)"),
        "{error}"
    );
    device.link().transport().done();

    // A corrupted DeviceInfo (bad CRC) counts as no answer: the second Hello gets the real one.
    let mut corrupted = vector("device_info");
    let crc_at = corrupted.len() - 3;
    corrupted[crc_at] ^= 0x01;
    let stream = ScriptedStream::new(&[
        Transaction::write(&[0x00]),
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE)),
        Transaction::Read(corrupted),
        Transaction::Read(heartbeat_reply_frame(NONCE, StatusFlags::SESSION_OPEN)),
        Transaction::ReadTimeout,
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE + 1)),
        Transaction::Read(vector("device_info")),
        Transaction::Read(heartbeat_reply_frame(NONCE + 1, StatusFlags::SESSION_OPEN)),
        Transaction::Write(set_force_frame(1, [0.0; 3])),
        Transaction::Read(state_frame(1, 1, 0.01)),
    ]);
    let mut device = ProtocolDevice::new(SerialLink::new(stream), ProtocolConfig::default())
        .with_handshake_nonce(NONCE);
    device.open().unwrap();
    assert_eq!(device.counters().hellos, 2);
    device.link().transport().done();

    let stream = ScriptedStream::new(&[
        Transaction::write(&[0x00]),
        Transaction::Write(vector("hello")),
        Transaction::Disconnect,
    ]);
    let mut device = ProtocolDevice::new(SerialLink::new(stream), ProtocolConfig::default());
    assert_eq!(device.open().unwrap_err().kind(), ErrorKind::Disconnected);
}

/// A DeviceInfo that answered another open's Hello (here: followed by the reply to a heartbeat this open never
/// sent, nonce 6), or one whose confirming reply says the session is not open, is not taken for this open's; the
/// next Hello's DeviceInfo, confirmed by this open's nonce, is. States that came before the confirmation (an
/// earlier session's) are not taken for the first State either.
#[test]
fn protocol_driver_takes_only_a_device_info_confirmed_by_its_own_nonce() {
    let stream = ScriptedStream::new(&[
        Transaction::write(&[0x00]),
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE)),
        Transaction::Read(vector("device_info")),
        Transaction::Read(heartbeat_reply_frame(NONCE - 1, StatusFlags::SESSION_OPEN)),
        Transaction::Read(state_frame(40, 12, 0.05)),
        Transaction::ReadTimeout,
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE + 1)),
        Transaction::Read(vector("device_info")),
        Transaction::Read(heartbeat_reply_frame(NONCE, StatusFlags::EMPTY)),
        Transaction::ReadTimeout,
        Transaction::Write(vector("hello")),
        Transaction::Write(heartbeat_frame(NONCE + 2)),
        Transaction::Read(vector("device_info")),
        Transaction::Read(heartbeat_reply_frame(NONCE + 1, StatusFlags::SESSION_OPEN)),
        Transaction::Write(set_force_frame(1, [0.0; 3])),
        Transaction::Read(state_frame(41, 1, 0.01)),
    ]);
    let mut device = Lifecycle::new(
        ProtocolDevice::new(SerialLink::new(stream), ProtocolConfig::default())
            .with_handshake_nonce(NONCE),
    );
    device.open().unwrap();
    assert_eq!(device.device().counters().hellos, 3);
    device.device().link().transport().done();
    device.mark_lost();
}

#[test]
fn protocol_driver_over_hid_sends_one_64_byte_report_per_message() {
    let report = |message: &voxhap_protocol::HostToDevice| {
        let mut out = [0u8; 64];
        encode_report(message, &mut out).unwrap();
        out.to_vec()
    };
    let device_report = |message: &DeviceToHost| {
        let mut out = [0u8; 64];
        encode_report(message, &mut out).unwrap();
        out.to_vec()
    };
    // The vector's `hid:` line for hello: report id 1, type 1, version 1.1, zero padding.
    let mut hello = vec![0x01, 0x01, 0x01, 0x01];
    hello.resize(64, 0);
    let info = voxhap::device::mock::mock_device_info();
    let zero_force = voxhap_protocol::HostToDevice::SetForce(voxhap_protocol::SetForce {
        sequence: 1,
        force_n: [0.0; 3],
        flags: voxhap_protocol::ForceFlags::EMPTY,
    });
    let state = DeviceToHost::State(State {
        sequence: 1,
        device_time_us: 5,
        position_m: [0.0, 0.01, 0.0],
        velocity_m_per_s: [0.0; 3],
        last_force_sequence: 1,
        buttons: 0,
        status: StatusFlags::SESSION_OPEN,
        faults: FaultFlags::EMPTY,
    });
    let heartbeat =
        voxhap_protocol::HostToDevice::Heartbeat(voxhap_protocol::Heartbeat { counter: NONCE });
    let reply = DeviceToHost::Heartbeat(voxhap_protocol::HeartbeatReply {
        counter: NONCE,
        device_time_us: 4,
        status: StatusFlags::SESSION_OPEN,
    });
    let reports = ScriptedReports::new(&[
        Transaction::Write(hello),
        Transaction::Write(report(&heartbeat)),
        Transaction::Read(device_report(&DeviceToHost::DeviceInfo(info))),
        Transaction::Read(device_report(&reply)),
        Transaction::Write(report(&zero_force)),
        Transaction::Read(device_report(&state)),
    ]);
    let mut device = Lifecycle::new(
        ProtocolDevice::new(HidLink::new(reports), ProtocolConfig::default())
            .with_handshake_nonce(NONCE),
    );
    device.open().unwrap();
    assert_eq!(device.info().model, "voxhap-mock");
    device.device().link().transport().done();
    device.mark_lost();
}

#[test]
fn woodenhaptics_reports_match_the_firmware_structs() {
    // pc_to_hid_message {short a, b, c; debug}: little-endian (LPC1768), preceded by report id 0 on hid_write.
    assert_eq!(
        encode_output([1000, -2, 3000], 0),
        [0x00, 0xe8, 0x03, 0xfe, 0xff, 0xb8, 0x0b, 0x00, 0x00]
    );
    // hid_to_pc_message {short encoder_a, b, c; unsigned short debug}.
    assert_eq!(
        decode_input(&[0x10, 0x00, 0xf0, 0xff, 0x00, 0x80, 0x07, 0x00]).unwrap(),
        ([16, -16, i16::MIN], 7)
    );
    assert_eq!(
        decode_input(&[0; 7]).unwrap_err().kind(),
        ErrorKind::Protocol
    );
}

#[test]
fn woodenhaptics_kinematics_at_zero_counts() {
    // At zero counts θA = θB = 0 and θC = π/2: x = Lc - ox, y = -oy, z = La + Lb - oz (CWoodenDevice.cpp).
    let config = WOODENHAPTICS_HID;
    let theta = config.joint_angles_rad(hfab_counts([0, 0, 0]));
    let p = config.position_m(theta).unwrap();
    assert!((p.x - (0.245 - 0.220)).abs() < 1e-12);
    assert!(p.y.abs() < 1e-12);
    assert!((p.z - (0.080 + 0.205 - 0.080)).abs() < 1e-12);
    // A force along +z there: J row for z is (0, -Lb sin θB, Lc sin θC) = (0, 0, Lc): τC = Lc Fz; the motor C
    // current is -τC dcap/dbody / kt = -(0.245 · 1 · 0.010/0.120)/0.0259 A = -0.788 A -> -788 mA.
    assert_eq!(
        config.currents_ma(theta, DVec3::new(0.0, 0.0, 1.0), WOODENHAPTICS_HID_MAX_MA),
        [0, 0, -788]
    );
    // A huge force saturates at 3 A.
    assert_eq!(
        config.currents_ma(
            theta,
            DVec3::new(0.0, 0.0, 1000.0),
            WOODENHAPTICS_HID_MAX_MA
        )[2],
        -3000
    );
}

#[test]
fn woodenhaptics_driver_reads_counts_and_writes_currents() {
    let reports = ScriptedReports::new(&[
        Transaction::read(&[0, 0, 0, 0, 0, 0, 1, 0]),
        Transaction::write(&encode_output([0, 0, -788], 0)),
        Transaction::ReadTimeout,
    ]);
    let mut device = WoodenHaptics::new(reports, WOODENHAPTICS_HID).unwrap();
    let state = device.read_state().unwrap();
    assert!((state.position_m.z - 0.205).abs() < 1e-12);
    assert_eq!(device.last_counter(), Some(1));
    // The host's input checks accepted that report: force is converted at its pose.
    device.input_checked(true);
    device.write_force(DVec3::new(0.0, 0.0, 1.0)).unwrap();
    assert_eq!(device.read_state().unwrap_err().kind(), ErrorKind::Timeout);
    device.transport().done();
}

/// Force is converted only at a pose the host accepted (docs/safety.md: a rejected reading never steers the
/// force): before any accepted report the driver writes zero currents, and a refused report after an accepted
/// one leaves force converted at the accepted pose. Zero counts and 1 N along +z give [0, 0, -788] mA, worked by
/// hand from CWoodenDevice.cpp in `woodenhaptics_kinematics_at_zero_counts`; at 500 counts on encoder B the
/// z row of the Jacobian has `-Lb sin(thetaB)`, so converting there would drive motor B as well.
#[test]
fn woodenhaptics_hid_converts_force_only_at_a_pose_the_host_accepted() {
    let reports = ScriptedReports::new(&[
        Transaction::read(&[0, 0, 0, 0, 0, 0, 1, 0]),
        Transaction::write(&encode_output([0, 0, 0], 0)),
        Transaction::read(&[0, 0, 0, 0, 0, 0, 2, 0]),
        Transaction::write(&encode_output([0, 0, -788], 0)),
        Transaction::read(&[0, 0, 0xf4, 0x01, 0, 0, 3, 0]),
        Transaction::write(&encode_output([0, 0, -788], 0)),
    ]);
    let mut device = WoodenHaptics::new(reports, WOODENHAPTICS_HID).unwrap();
    for accepted in [false, true, false] {
        device.read_state().unwrap();
        device.input_checked(accepted);
        device.write_force(DVec3::new(0.0, 0.0, 1.0)).unwrap();
    }
    device.transport().done();
}

/// The legacy HID driver on the timed report double: reports come one per millisecond (a full-speed HID
/// interrupt endpoint is polled at most once per 1 ms frame, USB 2.0 section 5.7.4), each readable 0.3 ms after
/// its slot; the driver waits 0.75 ms per tick (three quarters of the 1 ms period). A report 1.5 ms late misses
/// two ticks' waits (two timeouts, each costing at most the wait, never a fixed 5-10 ms) and is then read on
/// the third tick, two ticks after it was due, and the driver says it may be two ticks old (it was sent in
/// slot 1, at tick 1); a report the device never sends costs one timeout. Worked by hand from the double's time
/// model (virtual time, so the machine's load cannot change it).
#[test]
fn woodenhaptics_hid_sees_a_late_report_late_and_a_missing_one_as_a_timeout() {
    let zero = encode_output([0, 0, 0], 0);
    let report = |counter: u8| Transaction::read(&[0, 0, 0, 0, 0, 0, counter, 0]);
    let mut script = Vec::new();
    for _ in 0..5 {
        script.push(Transaction::Write(zero.to_vec()));
    }
    script.extend([
        report(1),
        // Slot 1 (due at 1.3 ms) comes 1.5 ms late: readable at 2.8 ms.
        Transaction::Late(Duration::from_micros(1_500), vec![0, 0, 0, 0, 0, 0, 2, 0]),
        // Slot 2: the device sends nothing.
        Transaction::ReadTimeout,
        report(4),
    ]);
    let timing = ReportTiming {
        servo_period: Duration::from_millis(1),
        report_period: Duration::from_millis(1),
        latency: Duration::from_micros(300),
    };
    let reports = ScriptedReports::timed(&script, timing);
    let mut device = WoodenHaptics::new(reports, WOODENHAPTICS_HID)
        .unwrap()
        .with_reply_wait(Duration::from_micros(750));
    let mut seen = Vec::new();
    for _ in 0..5 {
        // No pose accepted: zero currents every tick.
        device.write_force(DVec3::ZERO).unwrap();
        seen.push(match device.read_state() {
            Ok(_) => Ok((device.last_counter().unwrap(), device.state_age_ticks())),
            Err(error) => Err(error.kind()),
        });
    }
    assert_eq!(
        seen,
        vec![
            Ok((1, 0)),
            Err(ErrorKind::Timeout),
            Err(ErrorKind::Timeout),
            // Read at tick 3 (3.0 ms): the 2.8 ms report, sent in slot 1 (tick 1), two ticks old; the next is
            // not there yet.
            Ok((2, 2)),
            // Slot 3's report, readable at 3.3 ms, read in tick 4: the tick after the one before, 0.
            Ok((4, 0)),
        ]
    );
    // Every wait ended at its bound: tick 4 read its report at 4.0 ms (it arrived at 3.3 ms).
    assert_eq!(device.transport().now(), Duration::from_millis(4));
    device.transport().done();
}

#[test]
fn haply_commands_match_the_hapi_board_layout() {
    let config = Haply2DiyConfig::default();
    // Board::reset_board: type 0, device id 0, no data.
    assert_eq!(Haply2DiyConfig::reset_command(), [0, 0]);
    // Device::device_set_parameters with actuator 1 CCW on port 2, actuator 2 CW on port 1, encoders likewise
    // (offsets 241 and -61 degrees, 10752 steps): [1, 5, 0b0011, CW, CCW, 0b0011, CW, CCW, 0, 0] then the floats
    // -61, 10752, 241, 10752 in little-endian order (port 1 first).
    let mut expected = vec![1, 5, 3, 0, 1, 3, 0, 1, 0, 0];
    expected.extend_from_slice(&hex("00 00 74 c2 00 00 28 46 00 00 71 43 00 00 28 46"));
    assert_eq!(config.setup_command().to_vec(), expected);
    // device_write_torques: [2, 5, τ(port 1) = actuator 2, τ(port 2) = actuator 1].
    assert_eq!(
        config.torque_command([1.0, -2.0]),
        [2, 5, 0x00, 0x00, 0x00, 0xc0, 0x00, 0x00, 0x80, 0x3f]
    );
    // A reply [5, angle(port 1) = encoder 2, angle(port 2) = encoder 1] gives (θ1, θ2).
    let reply = [5, 0x00, 0x00, 0x34, 0x42, 0x00, 0x00, 0x07, 0x43];
    assert_eq!(config.parse_reply(&reply).unwrap(), [135.0, 45.0]);
    let mut wrong_id = reply;
    wrong_id[0] = 4;
    assert_eq!(
        config.parse_reply(&wrong_id).unwrap_err().kind(),
        ErrorKind::Protocol
    );
}

#[test]
fn haply_pantograph_is_symmetric_and_its_jacobian_matches_finite_differences() {
    let config = Haply2DiyConfig::default();
    // θ1 = 135°, θ2 = 45° with d = 0: the elbows mirror each other, so the handle is on the y axis.
    let ([x, y], jacobian) = config.kinematics([135.0, 45.0]).unwrap();
    assert!(x.abs() < 1e-9, "x = {x}");
    // Elbows at (∓l/√2, l/√2); the handle is L·sin β above their midpoint: y = l/√2 + sqrt(L² - l²/2).
    let l = 0.07_f64;
    let expected_y = l / 2f64.sqrt() + (0.09f64 * 0.09 - l * l / 2.0).sqrt();
    assert!(
        (y - expected_y).abs() < 1e-9,
        "y = {y}, expected {expected_y}"
    );
    // τ = Jᵀ-style rows: column i of d(x, y)/dθ is (J_i1, J_i2) (HaplyHAPI's convention τ_i = J_i1 fx + J_i2 fy).
    let h = 0.1_f32;
    for (i, row) in jacobian.iter().enumerate() {
        let mut plus = [135.0, 45.0];
        let mut minus = plus;
        plus[i] += h;
        minus[i] -= h;
        let (p, _) = config.kinematics(plus).unwrap();
        let (m, _) = config.kinematics(minus).unwrap();
        let step_rad = 2.0 * f64::from(h).to_radians();
        let dx = (p[0] - m[0]) / step_rad;
        let dy = (p[1] - m[1]) / step_rad;
        assert!(
            (dx - row[0]).abs() < 1e-4 && (dy - row[1]).abs() < 1e-4,
            "θ{} row {row:?} vs ({dx}, {dy})",
            i + 1
        );
    }
}

#[test]
fn haply_driver_opens_writes_and_reads() {
    let config = Haply2DiyConfig::default();
    let reply = [5, 0x00, 0x00, 0x34, 0x42, 0x00, 0x00, 0x07, 0x43];
    let stream = ScriptedStream::new(&[
        Transaction::write(&[0, 0]),
        Transaction::write(&config.setup_command()),
        Transaction::write(&config.torque_command([0.0, 0.0])),
        Transaction::read(&reply[..4]),
        Transaction::read(&reply[4..]),
        Transaction::write(&config.torque_command([0.0, 0.0])),
        Transaction::read(&reply),
    ]);
    let mut device = Lifecycle::new(Haply2Diy::new(stream, config));
    device.open().unwrap();
    device.enable().unwrap();
    device.write_force(DVec3::ZERO).unwrap();
    let state = device.read_state().unwrap();
    assert!(state.position_m.x.abs() < 1e-9 && state.position_m.z == 0.0);
    // disable: the wrapper's explicit zero torque, then the driver drains its reply.
    device.disable().unwrap();
    device.device().transport().done();
    device.mark_lost();
}

#[test]
fn lifecycle_refuses_forces_before_enable_and_zeroes_on_disable() {
    let config = Haply2DiyConfig::default();
    let stream = ScriptedStream::new(&[]);
    let mut device = Lifecycle::new(Haply2Diy::new(stream, config));
    let error = device.write_force(DVec3::X).unwrap_err();
    assert_eq!(error.kind(), ErrorKind::InvalidState);
    assert_eq!(device.enable().unwrap_err().kind(), ErrorKind::InvalidState);
    assert_eq!(
        device.read_state().unwrap_err().kind(),
        ErrorKind::InvalidState
    );
    assert_eq!(device.state(), LifecycleState::Closed);
    device.device().transport().done();
}

proptest! {
    #[test]
    fn protocol_driver_survives_arbitrary_device_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let stream = ScriptedStream::new(&[
            Transaction::write(&[0x00]),
            Transaction::Write(vector("hello")),
            Transaction::Write(heartbeat_frame(NONCE)),
            Transaction::Read(bytes),
            Transaction::ReadTimeout,
        ]);
        let mut device = ProtocolDevice::new(SerialLink::new(stream), ProtocolConfig::default())
            .with_handshake_nonce(NONCE);
        // Whatever the bytes, open ends with an error or (if they happen to hold device info) goes on to write.
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| device.open())).map_err(|panic| {
            // Only the scripted double may panic (an unexpected write after a lucky device info); never the driver.
            let text = panic.downcast_ref::<String>().cloned().unwrap_or_default();
            assert!(text.contains("scripted transport"), "driver panicked: {text}");
        });
    }

    #[test]
    fn protocol_driver_over_hid_survives_arbitrary_reports(
        reports in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..65), 0..6)
    ) {
        let mut script = vec![Transaction::Write({
            let mut hello = vec![0x01, 0x01, 0x01, 0x00];
            hello.resize(64, 0);
            hello
        }), Transaction::Write({
            let heartbeat = voxhap_protocol::HostToDevice::Heartbeat(voxhap_protocol::Heartbeat { counter: NONCE });
            let mut out = [0u8; 64];
            encode_report(&heartbeat, &mut out).unwrap();
            out.to_vec()
        })];
        script.extend(reports.into_iter().map(Transaction::Read));
        script.push(Transaction::ReadTimeout);
        let mut device = ProtocolDevice::new(HidLink::new(ScriptedReports::new(&script)), ProtocolConfig::default())
            .with_handshake_nonce(NONCE);
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| device.open())).map_err(|panic| {
            let text = panic.downcast_ref::<String>().cloned().unwrap_or_default();
            assert!(text.contains("scripted transport"), "driver panicked: {text}");
        });
    }

    #[test]
    fn woodenhaptics_decoder_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..20)) {
        let result = decode_input(&bytes);
        prop_assert_eq!(result.is_ok(), bytes.len() == 8);
        if let Ok((counts, _)) = result {
            let config = WOODENHAPTICS_HID;
            prop_assert!(config
                .position_m(config.joint_angles_rad(hfab_counts(counts)))
                .is_some_and(|p| p.is_finite()));
        }
    }

    #[test]
    fn haply_reply_parser_and_kinematics_never_panic(reply in any::<[u8; 9]>()) {
        let config = Haply2DiyConfig::default();
        if let Ok(angles) = config.parse_reply(&reply) {
            if let Some((position, jacobian)) = config.kinematics(angles) {
                prop_assert!(position.iter().chain(jacobian.iter().flatten()).all(|v| v.is_finite()));
            }
        }
    }
}

#[test]
fn state_timeout_is_short_enough_for_the_servo_loop() {
    // The default lockstep wait must stay well under the device watchdog so that a lost frame costs a few ticks.
    let config = ProtocolConfig::default();
    assert!(config.state_timeout <= Duration::from_millis(10));
    assert!(u128::from(config.device_watchdog_us) > config.state_timeout.as_micros() * 2);
}
