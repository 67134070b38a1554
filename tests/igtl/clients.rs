//! Clients that misbehave: a stalled client loses frames without slowing another, a full table of idle
//! connections never locks out a new client, the idle timeout, and large bodies without the token refused from
//! their header without growing the server.

use crate::util::igtl_client::{
    fixed, image_content_sized, pack, read, status, statuses_until_closed, string_content, Fixture,
    TOKEN,
};
use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};
use voxhap::server::igtl::{MAX_CLIENTS, UNAUTHENTICATED_BODY_BYTES};
use voxhap::servo::SessionApi;

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
