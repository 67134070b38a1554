//! The OpenIGTLink server against a client written here from the specification (openigtlink/OpenIGTLink,
//! Documents/Protocol/header.md, transform.md, status.md, string.md, image.md), not from voxhap's codec:
//! the CRC-64 is computed bit by bit from the ECMA-182 polynomial, the messages packed by hand. A real
//! session on the simulated arm, the server on 127.0.0.1 port 0.

use glam::DVec3;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};
use voxhap::server::igtl::{IgtlConfig, IgtlServer};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{ControlCommand, Session, SessionApi, SessionConfig};

const TOKEN: &str = "igtl-test-token-42";

/// CRC-64/ECMA-182, bit by bit: polynomial 0x42F0E1EBA9EA3693, initial 0, MSB first, no final xor.
fn crc64(data: &[u8]) -> u64 {
    let mut crc = 0u64;
    for &byte in data {
        crc ^= u64::from(byte) << 56;
        for _ in 0..8 {
            crc = if crc >> 63 == 1 {
                (crc << 1) ^ 0x42F0_E1EB_A9EA_3693
            } else {
                crc << 1
            };
        }
    }
    crc
}

fn fixed(text: &str, width: usize) -> Vec<u8> {
    let mut bytes = text.as_bytes().to_vec();
    bytes.resize(width, 0);
    bytes
}

/// A whole message: header version 1, or 2 with the extended header and `metadata`.
fn pack(
    version: u16,
    kind: &str,
    device: &str,
    content: &[u8],
    metadata: &[(&str, &str)],
) -> Vec<u8> {
    let mut body = Vec::new();
    if version == 2 {
        let meta_header = 2 + 8 * metadata.len();
        let meta_size: usize = metadata.iter().map(|(k, v)| k.len() + v.len()).sum();
        body.extend_from_slice(&12u16.to_be_bytes());
        body.extend_from_slice(&(meta_header as u16).to_be_bytes());
        body.extend_from_slice(&(meta_size as u32).to_be_bytes());
        body.extend_from_slice(&7u32.to_be_bytes());
        body.extend_from_slice(content);
        body.extend_from_slice(&(metadata.len() as u16).to_be_bytes());
        for (k, v) in metadata {
            body.extend_from_slice(&(k.len() as u16).to_be_bytes());
            body.extend_from_slice(&3u16.to_be_bytes());
            body.extend_from_slice(&(v.len() as u32).to_be_bytes());
        }
        for (k, v) in metadata {
            body.extend_from_slice(k.as_bytes());
            body.extend_from_slice(v.as_bytes());
        }
    } else {
        body.extend_from_slice(content);
    }
    let mut message = version.to_be_bytes().to_vec();
    message.extend(fixed(kind, 12));
    message.extend(fixed(device, 20));
    message.extend_from_slice(&0u64.to_be_bytes());
    message.extend_from_slice(&(body.len() as u64).to_be_bytes());
    message.extend_from_slice(&crc64(&body).to_be_bytes());
    message.extend(body);
    message
}

fn transform_content(translation_mm: [f32; 3]) -> Vec<u8> {
    let values = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    values
        .iter()
        .chain(&translation_mm)
        .flat_map(|v| v.to_be_bytes())
        .collect()
}

fn string_content(text: &str) -> Vec<u8> {
    let mut content = 3u16.to_be_bytes().to_vec();
    content.extend_from_slice(&(text.len() as u16).to_be_bytes());
    content.extend_from_slice(text.as_bytes());
    content
}

/// A 16 x 12 x 8 uint16 RAS image, 2 mm voxels, centred at `centre_mm`, little-endian data, values
/// `offset + n % 100`.
fn image_content(centre_mm: [f32; 3], offset: u16) -> Vec<u8> {
    let dims = [16u16, 12, 8];
    let mut content = 1u16.to_be_bytes().to_vec();
    content.extend_from_slice(&[1, 5, 2, 1]); // scalar, uint16, little-endian, RAS
    for d in dims {
        content.extend_from_slice(&d.to_be_bytes());
    }
    let matrix = [2.0f32, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0];
    for v in matrix.iter().chain(&centre_mm) {
        content.extend_from_slice(&v.to_be_bytes());
    }
    content.extend_from_slice(&[0; 6]);
    for d in dims {
        content.extend_from_slice(&d.to_be_bytes());
    }
    for n in 0..(16 * 12 * 8u16) {
        content.extend_from_slice(&(offset + n % 100).to_le_bytes());
    }
    content
}

struct Message {
    version: u16,
    kind: String,
    device: String,
    content: Vec<u8>,
}

fn text(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8(bytes[..end].to_vec()).unwrap()
}

/// Reads one message and checks its CRC; the content without the extended header and metadata.
fn read(stream: &mut TcpStream) -> Message {
    let mut header = [0u8; 58];
    stream.read_exact(&mut header).unwrap();
    let version = u16::from_be_bytes([header[0], header[1]]);
    let body_size = u64::from_be_bytes(header[42..50].try_into().unwrap()) as usize;
    let crc = u64::from_be_bytes(header[50..58].try_into().unwrap());
    let mut body = vec![0u8; body_size];
    stream.read_exact(&mut body).unwrap();
    assert_eq!(crc64(&body), crc, "CRC of {}", text(&header[2..14]));
    let content = if version == 2 {
        let ext = u16::from_be_bytes([body[0], body[1]]) as usize;
        let meta_header = u16::from_be_bytes([body[2], body[3]]) as usize;
        let meta = u32::from_be_bytes(body[4..8].try_into().unwrap()) as usize;
        body[ext..body.len() - meta_header - meta].to_vec()
    } else {
        body
    };
    Message {
        version,
        kind: text(&header[2..14]),
        device: text(&header[14..34]),
        content,
    }
}

fn translation_mm(content: &[u8]) -> DVec3 {
    let value = |i: usize| {
        f64::from(f32::from_be_bytes(
            content[4 * i..4 * i + 4].try_into().unwrap(),
        ))
    };
    assert_eq!(
        [value(0), value(4), value(8), value(1)],
        [1.0, 1.0, 1.0, 0.0],
        "identity rotation"
    );
    DVec3::new(value(9), value(10), value(11))
}

/// The next STATUS for `device`: (code, message).
fn status(stream: &mut TcpStream, device: &str) -> (u16, String) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        let message = read(stream);
        if message.kind == "STATUS" && message.device == device {
            let code = u16::from_be_bytes([message.content[0], message.content[1]]);
            return (code, text(&message.content[30..]));
        }
    }
    panic!("no STATUS for {device}");
}

struct Fixture {
    runtime: tokio::runtime::Runtime,
    server: Option<IgtlServer>,
    api: Arc<voxhap::servo::SessionShared>,
    _session: Session,
}

impl Fixture {
    fn start() -> Fixture {
        Fixture::start_at(100)
    }

    /// A session on the simulated arm and a server streaming at `rate_hz`.
    fn start_at(rate_hz: u32) -> Fixture {
        let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
        config.rt = voxhap::servo::rt::RtMode::Off;
        config.spin_ns = 20_000;
        let session = Session::start(config).unwrap();
        let api = session.api();
        let deadline = Instant::now() + Duration::from_secs(5);
        while api.snapshot().is_none() {
            assert!(Instant::now() < deadline, "the servo never ticked");
            std::thread::sleep(Duration::from_millis(5));
        }
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let shared: Arc<dyn SessionApi> = api.clone();
        let config = IgtlConfig {
            addr: "127.0.0.1:0".parse().unwrap(),
            rate_hz,
        };
        let server = runtime
            .block_on(IgtlServer::start(shared, &config, TOKEN.to_owned()))
            .unwrap();
        Fixture {
            runtime,
            server: Some(server),
            api,
            _session: session,
        }
    }

    fn connect(&self) -> TcpStream {
        let addr = self.server.as_ref().unwrap().local_addr();
        let stream = TcpStream::connect(addr).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        stream
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            self.runtime.block_on(server.stop());
        }
    }
}

#[test]
fn the_stream_carries_ras_millimetres_with_valid_crcs_and_the_force_in_newtons() {
    let fixture = Fixture::start();
    // Hold the simulated hand still so the probe can be compared with the session's own state.
    fixture
        .api
        .control(ControlCommand::SetHandTarget {
            position_m: Some([0.0, 0.0, 0.08]),
        })
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let mut stream = fixture.connect();
    let first = read(&mut stream);
    assert_eq!(
        (first.kind.as_str(), first.device.as_str()),
        ("STATUS", "voxhap")
    );
    let mut devices = Vec::new();
    let mut probe = None;
    let mut force = None;
    while devices.len() < 40 {
        let message = read(&mut stream);
        assert_eq!(
            message.version, 1,
            "header version 1 until the client speaks 2"
        );
        if message.kind != "TRANSFORM" {
            continue;
        }
        match message.device.as_str() {
            "Probe" => probe = Some(translation_mm(&message.content)),
            "Force" => force = Some(translation_mm(&message.content)),
            _ => {}
        }
        devices.push(message.device);
    }
    for name in ["Probe", "Proxy", "ProbeVelocity", "Force"] {
        assert!(
            devices.iter().any(|d| d == name),
            "{name} missing: {devices:?}"
        );
    }
    let snapshot = fixture.api.snapshot().unwrap();
    let probe = probe.unwrap();
    assert!(
        (probe - snapshot.probe_m * 1000.0).length() < 0.5,
        "IGTL probe {probe} mm, session {} m",
        snapshot.probe_m
    );
    assert!(
        (probe - DVec3::new(0.0, 0.0, 80.0)).length() < 5.0,
        "{probe}"
    );
    let force = force.unwrap();
    assert!(
        (force - snapshot.sent_force_n).length() < 0.05,
        "IGTL force {force} N, session {} N",
        snapshot.sent_force_n
    );
}

#[test]
fn an_image_needs_the_token_and_then_replaces_the_first_volume() {
    let fixture = Fixture::start();
    let mut stream = fixture.connect();
    let before = fixture.api.scene().volumes[0].clone();
    let image = pack(1, "IMAGE", "CT", &image_content([10.0, 0.0, 0.0], 0), &[]);
    stream.write_all(&image).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 5, "{message}");
    assert!(message.contains("token"), "{message}");
    assert_eq!(fixture.api.scene().volumes[0], before);

    // A corrupted CRC is answered with 9 and the connection goes on.
    let mut corrupt = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    let last = corrupt.len() - 1;
    corrupt[last] ^= 0x20;
    stream.write_all(&corrupt).unwrap();
    assert_eq!(status(&mut stream, "Login").0, 9);

    let login = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    stream.write_all(&login).unwrap();
    assert_eq!(status(&mut stream, "Login").0, 1);
    stream.write_all(&image).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 1, "{message}");
    let volume = fixture.api.scene().volumes[0].clone();
    assert_eq!(volume.dims, [16, 12, 8]);
    // Centre (10, 0, 0) mm, 2 mm voxels: voxel 0 at centre - 2 mm x (15, 11, 7) / 2.
    let expected_min = DVec3::new(-5.0, -11.0, -7.0) / 1000.0;
    assert!(
        (volume.min_m - expected_min).length() < 1e-9,
        "{}",
        volume.min_m
    );
    assert!((volume.max_m - DVec3::new(25.0, 11.0, 7.0) / 1000.0).length() < 1e-9);
    // Values 0 to 99 hold the built-in surface's 0.45 .. 0.5 ramp: its transfer is kept.
    assert!(!message.contains("transfer"), "{message}");
    let transfer = |api: &voxhap::servo::SessionShared| {
        let scene = api.scene();
        let surface = scene
            .modes
            .iter()
            .find(|m| m.display_name() == "surface")
            .unwrap();
        surface.transfer.as_ref().unwrap().points().to_vec()
    };
    assert_eq!(transfer(&fixture.api), vec![[0.45, 0.0], [0.5, 2.0]]);
    // Values 1000 to 1099 do not: the surface is fitted to them (0 N at 45 %, 2 N at 50 % of the range).
    let shifted = pack(
        1,
        "IMAGE",
        "CT",
        &image_content([10.0, 0.0, 0.0], 1000),
        &[],
    );
    stream.write_all(&shifted).unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 1, "{message}");
    assert!(message.contains("did not fit"), "{message}");
    assert_eq!(transfer(&fixture.api), vec![[1044.55, 0.0], [1049.5, 2.0]]);
}

#[test]
fn a_protocol_3_probe_target_with_a_metadata_token_moves_the_hand() {
    let fixture = Fixture::start();
    let mut stream = fixture.connect();
    let target = pack(
        2,
        "TRANSFORM",
        "ProbeTarget",
        &transform_content([5.0, -10.0, 60.0]),
        &[],
    );
    stream.write_all(&target).unwrap();
    assert_eq!(status(&mut stream, "ProbeTarget").0, 5);
    assert_eq!(fixture.api.snapshot().unwrap().hand_target_m, None);
    let target = pack(
        2,
        "TRANSFORM",
        "ProbeTarget",
        &transform_content([5.0, -10.0, 60.0]),
        &[("token", TOKEN)],
    );
    stream.write_all(&target).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let hand = fixture.api.snapshot().unwrap().hand_target_m;
        if let Some(hand) = hand {
            assert!(
                (hand - DVec3::new(0.005, -0.010, 0.060)).length() < 1e-6,
                "{hand}"
            );
            break;
        }
        assert!(Instant::now() < deadline, "the hand target was never set");
        std::thread::sleep(Duration::from_millis(10));
    }
    // The stream now comes in header version 2.
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let message = read(&mut stream);
        if message.kind == "TRANSFORM" && message.version == 2 {
            assert_eq!(message.content.len(), 48);
            break;
        }
        assert!(Instant::now() < deadline, "no version-2 stream");
    }
}

/// `voxhap serve --igtl` without the HTTP server: `--token` is accepted and the token in use is printed.
#[test]
fn serve_runs_the_igtl_server_without_http_and_prints_its_token() {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "serve",
            "--igtl",
            "127.0.0.1:0",
            "--no-http",
            "--no-foxglove",
            "--token",
            "given-token-123",
            "--duration",
            "0.5",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("igtl: listening on 127.0.0.1:"), "{stdout}");
    assert!(
        stdout
            .lines()
            .any(|l| l == "igtl: control token given-token-123"),
        "{stdout}"
    );
    assert!(!stdout.contains("http: listening"), "{stdout}");
    // A remote address needs --igtl-allow-remote, and nothing starts without it.
    let refused = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "serve",
            "--igtl",
            "0.0.0.0:0",
            "--no-http",
            "--no-foxglove",
            "--duration",
            "0.5",
        ])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--igtl-allow-remote"));
}

/// Several clients: each gets the whole stream; a client that stops reading (a tiny receive window) loses
/// the oldest frames, counted, while another keeps its full rate and the servo keeps ticking; past
/// `MAX_CLIENTS` a connection gets STATUS 6 (busy) and is closed. The stream runs at 1 kHz so the stalled
/// client's socket buffers (up to 4 MB on the server's side with Linux defaults) fill in about 10 s.
#[test]
fn a_stalled_client_loses_frames_without_slowing_another_and_the_seventeenth_is_refused_busy() {
    let fixture = Fixture::start_at(1000);
    let server = fixture.server.as_ref().unwrap();
    let addr = server.local_addr();
    // The stalled client: a 4 kB receive buffer (set before connecting, so the window stays small), never
    // read.
    let stalled = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
    stalled.set_recv_buffer_size(4096).unwrap();
    stalled.connect(&addr.into()).unwrap();
    let mut reader = fixture.connect();
    let tick_before = fixture.api.snapshot().unwrap().tick;
    let started = Instant::now();
    let mut probes = 0u32;
    // Until the stalled client was sent more than its socket buffers can hold: 14 000 frames of four
    // 106-byte TRANSFORMs, 5.9 MB, against at most 4 MB of send buffer (Linux's default tcp_wmem maximum)
    // and the 8 kB receive buffer; about 14 s at 1 kHz.
    while probes < 14_000 && started.elapsed() < Duration::from_secs(60) {
        let message = read(&mut reader);
        probes += u32::from(message.kind == "TRANSFORM" && message.device == "Probe");
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    let ticks = fixture.api.snapshot().unwrap().tick - tick_before;
    // The stalled client's writer is stuck writing into full socket buffers; once the client reads again,
    // it finds its queue overflowed: the frames it lost are counted and it goes on with the newest.
    let mut stalled: TcpStream = stalled.into();
    stalled
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let drained = Instant::now();
    while server.stats().frames_dropped == 0 && drained.elapsed() < Duration::from_secs(20) {
        read(&mut stalled);
    }
    let stats = server.stats();
    assert!(
        stats.frames_dropped > 0,
        "the stalled client lost no frames: {stats:?}"
    );
    // The servo kept ticking (1 kHz; at least half of it here, with RT scheduling off), and the reading
    // client kept up with the stream: one frame per new tick the streamer saw (at least half the ticks).
    assert!(
        ticks as f64 > 500.0 * elapsed_s,
        "{ticks} ticks in {elapsed_s:.1} s"
    );
    let rate_hz = f64::from(probes) / elapsed_s;
    assert!(
        f64::from(probes) > 0.5 * ticks as f64,
        "the reading client got {probes} Probe messages in {elapsed_s:.1} s ({rate_hz:.1} Hz) for {ticks} ticks"
    );
    eprintln!(
        "stalled client: {} frames dropped after {elapsed_s:.1} s; reader {rate_hz:.1} Hz",
        stats.frames_dropped
    );

    // Fill the server up to MAX_CLIENTS; the next connection is refused with STATUS 6 and closed.
    let max = voxhap::server::igtl::MAX_CLIENTS;
    let mut others: Vec<TcpStream> = (2..max).map(|_| fixture.connect()).collect();
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.stats().clients < max {
        assert!(Instant::now() < deadline, "{:?}", server.stats());
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut refused = fixture.connect();
    let (code, text) = status(&mut refused, "voxhap");
    assert_eq!(code, 6, "{text}");
    assert!(text.contains("connected already"), "{text}");
    let mut rest = Vec::new();
    assert_eq!(refused.read_to_end(&mut rest).unwrap(), 0, "not closed");
    assert_eq!(server.stats().clients_refused, 1);
    // The admitted ones still stream.
    for stream in others.iter_mut().take(2) {
        let message = read(stream);
        assert!(["TRANSFORM", "STATUS"].contains(&message.kind.as_str()));
    }
    drop(stalled);
}
