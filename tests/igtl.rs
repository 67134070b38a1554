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
use voxhap::server::igtl::{MAX_CLIENTS, UNAUTHENTICATED_BODY_BYTES};
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
    image_content_sized([16, 12, 8], centre_mm, offset)
}

/// As [`image_content`], `dims` voxels.
fn image_content_sized(dims: [u16; 3], centre_mm: [f32; 3], offset: u16) -> Vec<u8> {
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
    let voxels = dims.iter().map(|&d| u32::from(d)).product::<u32>();
    for n in 0..voxels {
        content.extend_from_slice(&(offset + (n % 100) as u16).to_le_bytes());
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
    try_read(stream).expect("a whole message")
}

/// [`read`], or `None` when the connection ended (or failed) first.
fn try_read(stream: &mut TcpStream) -> Option<Message> {
    let mut header = [0u8; 58];
    stream.read_exact(&mut header).ok()?;
    let version = u16::from_be_bytes([header[0], header[1]]);
    let body_size = u64::from_be_bytes(header[42..50].try_into().unwrap()) as usize;
    let crc = u64::from_be_bytes(header[50..58].try_into().unwrap());
    let mut body = vec![0u8; body_size];
    stream.read_exact(&mut body).ok()?;
    assert_eq!(crc64(&body), crc, "CRC of {}", text(&header[2..14]));
    let content = if version == 2 {
        let ext = u16::from_be_bytes([body[0], body[1]]) as usize;
        let meta_header = u16::from_be_bytes([body[2], body[3]]) as usize;
        let meta = u32::from_be_bytes(body[4..8].try_into().unwrap()) as usize;
        body[ext..body.len() - meta_header - meta].to_vec()
    } else {
        body
    };
    Some(Message {
        version,
        kind: text(&header[2..14]),
        device: text(&header[14..34]),
        content,
    })
}

/// Reads until the server closes the connection; the STATUS messages of `device` on the way, as (code,
/// message).
fn statuses_until_closed(stream: &mut TcpStream, device: &str) -> Vec<(u16, String)> {
    let mut seen = Vec::new();
    while let Some(message) = try_read(stream) {
        if message.kind == "STATUS" && message.device == device {
            let code = u16::from_be_bytes([message.content[0], message.content[1]]);
            seen.push((code, text(&message.content[30..])));
        }
    }
    seen
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
        Fixture::start_with(rate_hz, voxhap::server::igtl::DEFAULT_IDLE_TIMEOUT)
    }

    /// A session on the simulated arm and a server streaming at `rate_hz` with `idle_timeout`.
    fn start_with(rate_hz: u32, idle_timeout: Duration) -> Fixture {
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
            rate_hz,
            idle_timeout,
            ..IgtlConfig::new("127.0.0.1:0".parse().unwrap())
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
/// `MAX_CLIENTS` a newcomer still gets in. The stream runs at 1 kHz so the stalled client's socket buffers
/// fill within seconds. The idle timeout is longer than the test, so the stalled client is not closed.
#[test]
fn a_stalled_client_loses_frames_without_slowing_another_and_a_seventeenth_still_gets_in() {
    let fixture = Fixture::start_with(1000, Duration::from_secs(3600));
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
    // 106-byte TRANSFORMs, 5.9 MB, against the server's 64 KiB send buffer (128 KiB as Linux books it) and
    // the 8 kB receive buffer; about 14 s at 1 kHz.
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

    // Fill the server up to MAX_CLIENTS; the next connection still gets in, in the place of another.
    let mut others: Vec<TcpStream> = (2..MAX_CLIENTS).map(|_| fixture.connect()).collect();
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.stats().clients < MAX_CLIENTS {
        assert!(Instant::now() < deadline, "{:?}", server.stats());
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut newcomer = fixture.connect();
    let message = read(&mut newcomer);
    assert_eq!(
        (message.kind.as_str(), message.device.as_str()),
        ("STATUS", "voxhap")
    );
    assert_ne!(
        u16::from_be_bytes([message.content[0], message.content[1]]),
        6,
        "the newcomer was refused"
    );
    assert_eq!(server.stats().clients_evicted, 1);
    // The admitted ones still stream.
    for stream in others.iter_mut().take(2) {
        let message = read(stream);
        assert!(["TRANSFORM", "STATUS"].contains(&message.kind.as_str()));
    }
    drop(stalled);
}

/// A full table of idle connections (they connect and then neither send nor read) never locks out a new
/// client: it gets in at once and is served, and the connection closed to make room is the one the
/// documented order picks (the oldest without the token; the one that sent the token stays).
#[test]
fn a_full_table_of_idle_connections_never_locks_out_a_new_client() {
    // 10 Hz: the idle connections' socket buffers take minutes to fill, so none is stalled here.
    let fixture = Fixture::start_at(10);
    let server = fixture.server.as_ref().unwrap();
    let mut holder = fixture.connect();
    let login = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    holder.write_all(&login).unwrap();
    assert_eq!(status(&mut holder, "Login").0, 1);
    let mut idle: Vec<TcpStream> = (1..MAX_CLIENTS).map(|_| fixture.connect()).collect();
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.stats().clients < MAX_CLIENTS {
        assert!(Instant::now() < deadline, "{:?}", server.stats());
        std::thread::sleep(Duration::from_millis(10));
    }
    // The newcomer is served: the stream, and answers to what it asks.
    let mut newcomer = fixture.connect();
    newcomer
        .write_all(&pack(1, "GET_STATUS", "Ask", &[], &[]))
        .unwrap();
    let (code, message) = status(&mut newcomer, "Ask");
    assert!([1, 13].contains(&code), "{code} {message}");
    let deadline = Instant::now() + Duration::from_secs(10);
    while read(&mut newcomer).device != "Probe" {
        assert!(Instant::now() < deadline, "no Probe transform");
    }
    assert_eq!(server.stats().clients_evicted, 1);
    // The oldest connection without the token was told why and closed.
    let seen = statuses_until_closed(&mut idle[0], "voxhap");
    let (code, message) = seen.last().expect("a STATUS before the close");
    assert_eq!(*code, 6, "{message}");
    assert!(message.contains("make room"), "{message}");
    // The token holder, connected before it, is still served.
    holder
        .write_all(&pack(1, "GET_STATUS", "Ask", &[], &[]))
        .unwrap();
    assert!([1, 13].contains(&status(&mut holder, "Ask").0));
    assert_eq!(server.stats().clients_evicted, 1);
}

/// A client that reads nothing (a 4 kB receive window, never read) is closed once a message could not be
/// written to it for the idle timeout (1 s here); a client that reads but never sends stays.
#[test]
fn a_client_that_reads_nothing_is_closed_by_the_idle_timeout_and_a_reader_stays() {
    let fixture = Fixture::start_with(200, Duration::from_secs(1));
    let server = fixture.server.as_ref().unwrap();
    let socket = |receive_buffer_bytes| {
        let socket =
            socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).unwrap();
        socket.set_recv_buffer_size(receive_buffer_bytes).unwrap();
        socket.connect(&server.local_addr().into()).unwrap();
        let stream: TcpStream = socket.into();
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        stream
    };
    let mut stalled = socket(4096);
    // The reader's 1 MB window holds seconds of stream, so a pause of this thread on a busy machine does
    // not stall it.
    let mut reader = socket(1 << 20);
    let started = Instant::now();
    while server.stats().idle_closed == 0 {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the stalled client was never closed: {:?}",
            server.stats()
        );
        read(&mut reader);
    }
    // The reader, silent all along, still streams, and only the stalled client was closed.
    let until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < until {
        read(&mut reader);
    }
    let stats = server.stats();
    assert_eq!((stats.idle_closed, stats.clients), (1, 1), "{stats:?}");
    statuses_until_closed(&mut stalled, "voxhap");
}

/// The 58-byte header of an IMAGE (header version 1) announcing `body_bytes` (OpenIGTLink header.md:
/// V u16, TYPE char[12], DEVICE_NAME char[20], TIME_STAMP u64, BODY_SIZE u64, CRC u64, big-endian).
fn image_header(body_bytes: u64) -> Vec<u8> {
    let mut header = 1u16.to_be_bytes().to_vec();
    header.extend(fixed("IMAGE", 12));
    header.extend(fixed("Big", 20));
    header.extend_from_slice(&0u64.to_be_bytes());
    header.extend_from_slice(&body_bytes.to_be_bytes());
    header.extend_from_slice(&0u64.to_be_bytes());
    header
}

/// A header announcing a body over the limit for a client without the token is refused from the header
/// alone: STATUS 5 naming the limit, then the connection is closed, before any of the body was sent. With
/// the token, a body over that limit is read and loaded.
#[test]
fn a_large_body_without_the_token_is_refused_from_its_header() {
    let fixture = Fixture::start();
    let server = fixture.server.as_ref().unwrap();
    let mut stream = fixture.connect();
    stream.write_all(&image_header(256 << 20)).unwrap();
    let seen = statuses_until_closed(&mut stream, "voxhap");
    let (code, message) = seen.last().expect("a STATUS before the close");
    assert_eq!(*code, 5, "{message}");
    assert!(
        message.contains(&format!("at most {UNAUTHENTICATED_BODY_BYTES} bytes")),
        "{message}"
    );
    assert_eq!(server.stats().large_bodies_refused, 1);

    // The same size class with the token first: a 64 x 64 x 16 uint16 image, 128 KiB of voxels.
    let mut stream = fixture.connect();
    let login = pack(
        1,
        "STRING",
        "Login",
        &string_content(&format!("token {TOKEN}")),
        &[],
    );
    stream.write_all(&login).unwrap();
    assert_eq!(status(&mut stream, "Login").0, 1);
    let content = image_content_sized([64, 64, 16], [0.0, 0.0, 0.0], 0);
    assert!(content.len() as u64 > UNAUTHENTICATED_BODY_BYTES);
    stream
        .write_all(&pack(1, "IMAGE", "CT", &content, &[]))
        .unwrap();
    let (code, message) = status(&mut stream, "CT");
    assert_eq!(code, 1, "{message}");
    assert_eq!(fixture.api.scene().volumes[0].dims, [64, 64, 16]);
}

/// 15 clients without the token each announce a 256 MiB IMAGE and try to send 32 MiB of it to a real
/// `voxhap serve --igtl`: the server stops reading each soon after its header (a client's writes fail or
/// block once the socket buffers and the bounded discard are full, before 32 MiB), and its peak resident
/// size (VmHWM in /proc/PID/status) grows by far less than the 480 MiB the bodies would take.
#[test]
fn unauthenticated_clients_announcing_large_bodies_do_not_grow_the_server() {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args([
            "serve",
            "--igtl",
            "127.0.0.1:0",
            "--no-http",
            "--no-foxglove",
            "--token",
            TOKEN,
            "--duration",
            "120",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id().to_string();
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    let addr: std::net::SocketAddr = loop {
        let line = lines.next().expect("serve printed its address").unwrap();
        if let Some(rest) = line.strip_prefix("igtl: listening on ") {
            break rest.split(' ').next().unwrap().parse().unwrap();
        }
    };
    let hwm_before_kb = crate::util::server::proc_status_kb(&pid, "VmHWM");
    const SENT_BYTES: usize = 32 << 20;
    let clients: Vec<_> = (0..15)
        .map(|_| {
            std::thread::spawn(move || {
                let mut stream = TcpStream::connect(addr).unwrap();
                stream
                    .set_write_timeout(Some(Duration::from_secs(5)))
                    .unwrap();
                stream.write_all(&image_header(256 << 20)).unwrap();
                let chunk = vec![0u8; 64 << 10];
                let mut written = 0;
                while written < SENT_BYTES {
                    match stream.write(&chunk) {
                        Ok(n) if n > 0 => written += n,
                        _ => break,
                    }
                }
                written
            })
        })
        .collect();
    let written: Vec<usize> = clients.into_iter().map(|c| c.join().unwrap()).collect();
    let hwm_after_kb = crate::util::server::proc_status_kb(&pid, "VmHWM");
    let _ = child.kill();
    let _ = child.wait();
    let growth_mib = hwm_after_kb.saturating_sub(hwm_before_kb) as f64 / 1024.0;
    eprintln!(
        "peak RSS {hwm_before_kb} kB before, {hwm_after_kb} kB after ({growth_mib:.1} MiB); bytes written {written:?}"
    );
    assert!(
        written.iter().all(|&w| w < SENT_BYTES),
        "the server read 32 MiB of body from a client without the token: {written:?}"
    );
    assert!(
        growth_mib < 64.0,
        "the server's peak RSS grew by {growth_mib:.1} MiB"
    );
}
