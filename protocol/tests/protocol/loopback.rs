//! Host and device sessions talking over real encoded bytes, as voxhap's mock device and a firmware would: a
//! simulated 1 kHz link over serial (with line noise injected) and over HID, then the host stalls and the device's
//! watchdog must drop the force and report it.

use voxhap_protocol::{
    decode_report, encode_frame, encode_report, hid, DeviceInfo, DeviceSample, DeviceSession,
    DeviceToHost, DriveState, FaultCode, ForceFlags, FrameDecoder, HostEvent, HostPhase,
    HostSession, HostToDevice, Label, Message, RateSet, StatusFlags, MAX_WIRE_FRAME_LEN,
    PROTOCOL_VERSION,
};

fn info() -> DeviceInfo {
    DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("loopback").expect("valid label"),
        serial_number: Label::new("L-1").expect("valid label"),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::from_rates_hz(&[1000]).expect("standard rate"),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 3.0,
        max_stiffness_n_per_m: 1000.0,
    }
}

/// A byte pipe that can inject noise: every `noise_every`-th frame gets a byte flipped.
struct SerialPipe {
    bytes: Vec<u8>,
    frames: u64,
    noise_every: u64,
}

impl SerialPipe {
    fn send<M: Message>(&mut self, message: &M) {
        let mut buf = [0u8; MAX_WIRE_FRAME_LEN];
        let len = encode_frame(message, &mut buf).expect("sessions only produce valid messages");
        self.frames += 1;
        if self.noise_every != 0 && self.frames.is_multiple_of(self.noise_every) {
            buf[len / 2] ^= 0x5A;
        }
        self.bytes.extend_from_slice(&buf[..len]);
    }

    fn take(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.bytes)
    }
}

/// A simulated arm: position follows a slow sine, so states differ tick to tick.
fn sample(now_us: u64) -> DeviceSample {
    let t = now_us as f32 * 1e-6;
    DeviceSample {
        position_m: [0.05 * t.sin(), 0.0, 0.01],
        velocity_m_per_s: [0.05 * t.cos(), 0.0, 0.0],
        buttons: 0,
    }
}

#[test]
fn serial_link_with_noise_runs_at_1khz_and_trips_the_watchdog_when_the_host_stalls() {
    let mut host = HostSession::new();
    let mut device = DeviceSession::new(info());
    let mut to_device = SerialPipe {
        bytes: Vec::new(),
        frames: 0,
        noise_every: 37,
    };
    let mut to_host = SerialPipe {
        bytes: Vec::new(),
        frames: 0,
        noise_every: 41,
    };
    let mut device_decoder = FrameDecoder::<HostToDevice>::new();
    let mut host_decoder = FrameDecoder::<DeviceToHost>::new();
    let mut states = 0u64;
    let mut faults = Vec::new();
    let mut last_position_x = f32::NAN;

    // A line-noise burst before the host even starts.
    to_device
        .bytes
        .extend_from_slice(&[0x13, 0x37, 0x00, 0xFF, 0x42]);
    to_device.bytes.push(0x00);
    to_device.send(&host.hello());

    let stall_from_us = 300_000;
    for tick in 0..400u64 {
        let now_us = tick * 1_000;
        // Device: receive, run the cycle, transmit.
        for message in device_decoder
            .feed(&to_device.take())
            .filter_map(Result::ok)
        {
            device.on_message(&message, now_us);
        }
        let force_n = device.poll(now_us, &sample(now_us));
        assert!(force_n.iter().all(|f| f.abs() <= 3.0));
        while let Some(message) = device.poll_transmit() {
            to_host.send(&message);
        }
        // Host: receive, react, send the next force (until it stalls).
        for message in host_decoder.feed(&to_host.take()).filter_map(Result::ok) {
            match host.on_message(&message) {
                HostEvent::Connected(_) => to_device.send(&host.enable(0)),
                HostEvent::State { state, .. } => {
                    states += 1;
                    last_position_x = state.position_m[0];
                }
                HostEvent::Fault(fault) => faults.push((now_us, fault)),
                _ => {}
            }
        }
        if host.phase() == HostPhase::Ready && now_us < stall_from_us {
            to_device.send(&host.set_force([0.0, 0.0, 2.0], ForceFlags::EMPTY));
        }
        // A lost enable (noise) is retried: the status tells.
        if tick % 50 == 49 && now_us < stall_from_us && device.drive_state() == DriveState::Idle {
            to_device.send(&host.enable(0));
        }
    }

    assert_eq!(host.phase(), HostPhase::Ready);
    let device_stats = device_decoder.stats();
    let host_stats = host_decoder.stats();
    assert!(
        device_stats.crc_errors + device_stats.cobs_errors > 0,
        "noise was injected toward the device"
    );
    assert!(
        host_stats.crc_errors + host_stats.cobs_errors > 0,
        "noise was injected toward the host"
    );
    assert!(
        states > 250,
        "only {states} states arrived in 300 ms of lockstep at 1 kHz"
    );
    assert!(
        host.stats().states_lost > 0,
        "noise-dropped state frames are counted as lost"
    );
    assert!(last_position_x.is_finite());
    // The stall: the watchdog fires 50 ms after the last set-force, and the host hears about it.
    assert_eq!(device.drive_state(), DriveState::Idle);
    assert!(device.status().contains(StatusFlags::WATCHDOG_TRIPPED));
    let (heard_at_us, fault) = faults
        .last()
        .copied()
        .expect("the watchdog fault reached the host");
    assert_eq!(fault.code, FaultCode::WATCHDOG_EXPIRED);
    let last_force_us = stall_from_us - 1_000;
    assert!(
        fault.device_time_us > last_force_us + 50_000
            && fault.device_time_us <= last_force_us + 52_000
    );
    assert!(heard_at_us >= fault.device_time_us);
}

#[test]
fn hid_link_runs_the_same_session() {
    let mut host = HostSession::new();
    let mut device = DeviceSession::new(info());
    let mut report = [0u8; hid::REPORT_LEN];
    let mut to_device: Vec<[u8; hid::REPORT_LEN]> = Vec::new();
    let mut to_host: Vec<[u8; hid::REPORT_LEN]> = Vec::new();
    let send = |queue: &mut Vec<[u8; hid::REPORT_LEN]>, report: &mut [u8; hid::REPORT_LEN], len| {
        assert_eq!(len, hid::REPORT_LEN);
        queue.push(*report);
    };
    let len = encode_report(&host.hello(), &mut report).expect("valid");
    send(&mut to_device, &mut report, len);
    let mut applied_z = 0.0f32;
    for tick in 0..20u64 {
        let now_us = tick * 1_000;
        for r in to_device.drain(..) {
            device.on_message(
                &decode_report::<HostToDevice>(&r).expect("clean link"),
                now_us,
            );
        }
        applied_z = device.poll(now_us, &sample(now_us))[2];
        while let Some(message) = device.poll_transmit() {
            let len = encode_report(&message, &mut report).expect("valid");
            send(&mut to_host, &mut report, len);
        }
        for r in to_host.drain(..) {
            if let HostEvent::Connected(_) =
                host.on_message(&decode_report::<DeviceToHost>(&r).expect("clean link"))
            {
                let len = encode_report(&host.enable(0), &mut report).expect("valid");
                send(&mut to_device, &mut report, len);
            }
        }
        if host.phase() == HostPhase::Ready {
            let len = encode_report(
                &host.set_force([0.0, 0.0, 10.0], ForceFlags::EMPTY),
                &mut report,
            )
            .expect("valid");
            send(&mut to_device, &mut report, len);
        }
    }
    assert_eq!(applied_z, 3.0, "the device clamps to its 3 N maximum");
    assert_eq!(host.stats().states_lost, 0);
    assert!(host.stats().states_received >= 15);
    assert!(
        host.forces_in_flight() <= 2,
        "lockstep keeps the link shallow"
    );
}
