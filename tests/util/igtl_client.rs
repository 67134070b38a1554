//! An OpenIGTLink client written from the specification (openigtlink/OpenIGTLink, Documents/Protocol/header.md,
//! transform.md, status.md, string.md, image.md), not from voxhap's codec: the CRC-64 computed bit by bit from the
//! ECMA-182 polynomial, messages packed and read by hand, and a [`Fixture`] running a real session on the
//! simulated arm with the server on 127.0.0.1 port 0 (tests/igtl/).

use glam::DVec3;
use std::io::Read;
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};
use voxhap::server::igtl::{IgtlConfig, IgtlServer};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{Session, SessionApi, SessionConfig};

pub const TOKEN: &str = "igtl-test-token-42";

/// CRC-64/ECMA-182, bit by bit: polynomial 0x42F0E1EBA9EA3693, initial 0, MSB first, no final xor.
pub fn crc64(data: &[u8]) -> u64 {
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

pub fn fixed(text: &str, width: usize) -> Vec<u8> {
    let mut bytes = text.as_bytes().to_vec();
    bytes.resize(width, 0);
    bytes
}

/// A whole message: header version 1, or 2 with the extended header and `metadata`.
pub fn pack(
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

pub fn transform_content(translation_mm: [f32; 3]) -> Vec<u8> {
    let values = [1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    values
        .iter()
        .chain(&translation_mm)
        .flat_map(|v| v.to_be_bytes())
        .collect()
}

pub fn string_content(text: &str) -> Vec<u8> {
    let mut content = 3u16.to_be_bytes().to_vec();
    content.extend_from_slice(&(text.len() as u16).to_be_bytes());
    content.extend_from_slice(text.as_bytes());
    content
}

/// A 16 x 12 x 8 uint16 RAS image, 2 mm voxels, centred at `centre_mm`, little-endian data, values
/// `offset + n % 100`.
pub fn image_content(centre_mm: [f32; 3], offset: u16) -> Vec<u8> {
    image_content_sized([16, 12, 8], centre_mm, offset)
}

/// As [`image_content`], `dims` voxels.
pub fn image_content_sized(dims: [u16; 3], centre_mm: [f32; 3], offset: u16) -> Vec<u8> {
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

pub struct Message {
    pub version: u16,
    pub kind: String,
    pub device: String,
    pub content: Vec<u8>,
}

pub fn text(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8(bytes[..end].to_vec()).unwrap()
}

/// Reads one message and checks its CRC; the content without the extended header and metadata.
pub fn read(stream: &mut TcpStream) -> Message {
    try_read(stream).expect("a whole message")
}

/// [`read`], or `None` when the connection ended (or failed) first.
pub fn try_read(stream: &mut TcpStream) -> Option<Message> {
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
pub fn statuses_until_closed(stream: &mut TcpStream, device: &str) -> Vec<(u16, String)> {
    let mut seen = Vec::new();
    while let Some(message) = try_read(stream) {
        if message.kind == "STATUS" && message.device == device {
            let code = u16::from_be_bytes([message.content[0], message.content[1]]);
            seen.push((code, text(&message.content[30..])));
        }
    }
    seen
}

pub fn translation_mm(content: &[u8]) -> DVec3 {
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
pub fn status(stream: &mut TcpStream, device: &str) -> (u16, String) {
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

pub struct Fixture {
    pub runtime: tokio::runtime::Runtime,
    pub server: Option<IgtlServer>,
    pub api: Arc<voxhap::servo::SessionShared>,
    pub _session: Session,
}

impl Fixture {
    pub fn start() -> Fixture {
        Fixture::start_at(100)
    }

    /// A session on the simulated arm and a server streaming at `rate_hz`.
    pub fn start_at(rate_hz: u32) -> Fixture {
        Fixture::start_with(rate_hz, voxhap::server::igtl::DEFAULT_IDLE_TIMEOUT)
    }

    /// A session on the simulated arm and a server streaming at `rate_hz` with `idle_timeout`.
    pub fn start_with(rate_hz: u32, idle_timeout: Duration) -> Fixture {
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

    pub fn connect(&self) -> TcpStream {
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
