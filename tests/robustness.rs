//! Regression tests for crashes, hangs and leaks on hostile inputs, each named after what it fixes.
//! Inputs are real files in temporary folders (FIFOs made with mkfifo), the real `voxhap` binary (under a
//! memory cap where an unbounded allocation would abort), a real session and server on 127.0.0.1:0.

use crate::util::server::{http, TestServer, TOKEN};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use voxhap::record::{create_trace_writer, read_trace, TraceFormat, TraceMeta, TraceSample};
use voxhap::servo::api::folders::{ConfinedVolumes, VolumeDirs};
use voxhap::servo::api::{ControlCommand, SessionApi};
use voxhap::volume::io::{load_with, LoadOptions, LoadProblem};

fn voxhap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
}

/// Runs `voxhap ARGS` with its address space capped at `cap_mib` (`RLIMIT_AS`), killed
/// after 20 s; returns its output.
fn run_capped(args: &[&str], cap_mib: u64, dir: &Path) -> Output {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let script = format!(
        "ulimit -v {}; exec timeout 20 '{}' {}",
        cap_mib * 1024,
        env!("CARGO_BIN_EXE_voxhap"),
        quoted.join(" ")
    );
    Command::new("sh")
        .arg("-c")
        .arg(script)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// Asserts a clean refusal: exit code 1 (not a signal, not the 124 of `timeout`) and `needle` in stderr.
fn assert_refused(output: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(
        output.status.code(),
        Some(1),
        "expected a clean error exit; status {:?}, stderr {stderr}",
        output.status
    );
    assert!(stderr.contains(needle), "{needle:?} not in: {stderr}");
}

fn mkfifo(path: &Path) {
    let c_path = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
}

/// A NIfTI-1 header (348 bytes + 4 of extension flags) for `dims` of u8, vox_offset 352.
fn nifti_header(dims: [u16; 3]) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3u16, dims[0], dims[1], dims[2], 1, 1, 1, 1]
        .iter()
        .enumerate()
    {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes()); // uint8
    h[72..74].copy_from_slice(&8i16.to_le_bytes());
    for (i, p) in [1.0f32, 1.0, 1.0, 1.0].iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

/// Gzips `header` followed by `zeros` zero bytes.
fn gzip_with_zeros(header: &[u8], zeros: usize) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    encoder.write_all(header).unwrap();
    let chunk = vec![0u8; 1 << 20];
    let mut left = zeros;
    while left > 0 {
        let n = left.min(chunk.len());
        encoder.write_all(&chunk[..n]).unwrap();
        left -= n;
    }
    encoder.finish().unwrap()
}

#[test]
fn a_gzip_bomb_nifti_is_refused_without_decompressing_it() {
    let dir = tempfile::tempdir().unwrap();
    // A header that claims 1024^3 voxels (1 GiB, and 4 GiB more as f32): refused from the header alone, before inflating anything.
    std::fs::write(
        dir.path().join("claims.nii.gz"),
        gzip_with_zeros(&nifti_header([1024, 1024, 1024]), 1 << 20),
    )
    .unwrap();
    let output = run_capped(&["info", "claims.nii.gz"], 1024, dir.path());
    assert_refused(&output, "--max-volume-bytes");
    // A 2x2x2 header followed by 256 MiB of zeros (a 256 KiB file): inflating stops one byte past the
    // 360 bytes the header describes.
    std::fs::write(
        dir.path().join("bomb.nii.gz"),
        gzip_with_zeros(&nifti_header([2, 2, 2]), 256 << 20),
    )
    .unwrap();
    let output = run_capped(&["info", "bomb.nii.gz"], 1024, dir.path());
    assert_refused(&output, "data is longer than the header describes");
}

#[test]
fn an_nrrd_byte_skip_cannot_get_past_the_volume_limit() {
    let dir = tempfile::tempdir().unwrap();
    let header = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: gzip\nbyte skip: 5000000000\n\n";
    let mut bytes = header.as_bytes().to_vec();
    bytes.extend(gzip_with_zeros(b"", 64 << 20));
    std::fs::write(dir.path().join("skip.nrrd"), bytes).unwrap();
    let output = run_capped(&["info", "skip.nrrd"], 1024, dir.path());
    assert_refused(&output, "--max-volume-bytes");
    // Within the limit, the skip still counts: a 1 MiB limit refuses a 2 MiB skip of a 2x2x2 volume.
    let header =
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\nbyte skip: 2097152\n\n";
    std::fs::write(dir.path().join("small.nrrd"), header).unwrap();
    let options = LoadOptions {
        max_volume_bytes: 1 << 20,
        allow_outside_paths: false,
    };
    let error = load_with(&dir.path().join("small.nrrd"), &options).unwrap_err();
    assert!(
        matches!(error.problem, LoadProblem::OverLimit { .. }),
        "{error}"
    );
}

#[test]
fn a_detached_data_file_pointing_at_dev_zero_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let headers = [
        (
            "zero.nhdr",
            "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: /dev/zero\n\n",
        ),
        (
            "zero.mhd",
            "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = /dev/zero\n",
        ),
        (
            "zero.toml",
            "data_file = \"/dev/zero\"\ndims = [2, 2, 2]\nscalar_type = \"u8\"\nspacing = [1, 1, 1]\n",
        ),
    ];
    let allowed = LoadOptions {
        allow_outside_paths: true,
        ..LoadOptions::default()
    };
    for (name, text) in headers {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        // Confined by default ...
        let message = load_with(&path, &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("--allow-outside-paths"),
            "{name}: {message}"
        );
        // ... and even when outside paths are allowed, a device is not a regular file.
        let message = load_with(&path, &allowed).unwrap_err().to_string();
        assert!(message.contains("character device"), "{name}: {message}");
    }
}

fn write_trace(path: &Path, format: TraceFormat, ticks: u64) {
    let meta = TraceMeta::new(
        vec!["surface".into()],
        1000.0,
        serde_json::json!({"name": "robustness"}),
        "builtin:sphere",
        "exact-dual",
    );
    let mut writer = create_trace_writer(path, format, &meta).unwrap();
    for tick in 0..ticks {
        let sample = TraceSample {
            tick,
            t_s: tick as f64 * 1e-3,
            ..TraceSample::zeroed(1)
        };
        writer.write_sample(&sample).unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn an_mcap_with_8_corrupted_length_bytes_is_an_error_not_a_huge_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("trace.mcap");
    write_trace(&path, TraceFormat::Mcap, 50);
    let good = std::fs::read(&path).unwrap();
    assert!(read_trace(&path).is_ok());
    // Every record's 8-byte length field in turn (top level), set to 4.3 GB.
    let mut at = 8;
    let mut edited = 0;
    while at + 9 <= good.len() - 8 {
        let length = u64::from_le_bytes(good[at + 1..at + 9].try_into().unwrap());
        let mut bytes = good.clone();
        bytes[at + 1..at + 9].copy_from_slice(&4_300_000_000u64.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let error = read_trace(&path).unwrap_err().to_string();
        assert!(error.contains("damaged file"), "record at {at}: {error}");
        edited += 1;
        at += 9 + length as usize;
    }
    assert!(edited >= 5, "only {edited} records");
    // `voxhap plot` on the damaged trace, under a 1 GiB memory cap: a clean error.
    let mut bytes = good.clone();
    bytes[9..17].copy_from_slice(&4_300_000_000u64.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let output = run_capped(
        &["plot", "trace.mcap", "--out", "plot.png"],
        1024,
        dir.path(),
    );
    assert_refused(&output, "damaged file");
}

#[test]
fn replaying_dev_zero_is_refused_at_once() {
    let error = read_trace(Path::new("/dev/zero")).unwrap_err();
    let cause = std::error::Error::source(&error).map(ToString::to_string);
    assert!(
        cause
            .as_deref()
            .is_some_and(|c| c.contains("character device")),
        "{error}: {cause:?}"
    );
    let started = Instant::now();
    let output = voxhap()
        .args([
            "serve",
            "--device",
            "replay:/dev/zero",
            "--no-http",
            "--no-foxglove",
            "--duration",
            "5",
        ])
        .output()
        .unwrap();
    assert!(started.elapsed() < Duration::from_secs(4));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    // The replay driver (crates/device/src) reports the reader's error without its cause; the cause is
    // checked on the reader above.
    assert!(stderr.contains("cannot read /dev/zero"), "{stderr}");
}

#[test]
fn durations_of_1e20_seconds_are_refused_when_parsed() {
    for args in [
        &["serve", "--duration", "1e20"][..],
        &["bench-loop", "--seconds", "1e20"][..],
        &["serve", "--duration", "inf"][..],
        &["bench-loop", "--seconds", "0"][..],
    ] {
        let output = voxhap().args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains("<= 1e9"), "{args:?}: {stderr}");
    }
}

#[test]
fn plot_sizes_of_100000_and_4294967295_are_refused_when_parsed() {
    for (flag, value, range) in [
        ("--width", "100000", "400..=8192"),
        ("--height", "100000", "300..=8192"),
        ("--width", "4294967295", "400..=8192"),
    ] {
        let output = voxhap()
            .args(["plot", "t.csv", "--out", "p.png", flag, value])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(range), "{stderr}");
    }
}

#[test]
fn a_fifo_given_as_a_volume_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    mkfifo(&dir.path().join("pipe.nii"));
    let started = Instant::now();
    let output = run_capped(&["info", "pipe.nii"], 1024, dir.path());
    assert!(started.elapsed() < Duration::from_secs(10));
    assert_refused(&output, "FIFO (named pipe), not a regular file");
    // A FIFO as a detached data file too.
    mkfifo(&dir.path().join("pipe.raw"));
    std::fs::write(
        dir.path().join("h.nhdr"),
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: pipe.raw\n\n",
    )
    .unwrap();
    let output = run_capped(&["info", "h.nhdr"], 1024, dir.path());
    assert_refused(&output, "FIFO");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fifo_loaded_through_the_api_does_not_block_later_commands() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.nrrd");
    mkfifo(&fifo);
    let server = TestServer::start(4).await;
    let started = Instant::now();
    let body = serde_json::json!({ "path": fifo }).to_string();
    let (status, reply) = server.post("/api/volume", &body).await;
    assert_eq!(status, 400, "{reply}");
    assert!(reply["error"].as_str().unwrap().contains("FIFO"), "{reply}");
    let (status, reply) = server.post("/api/stiffness", r#"{"k": 450}"#).await;
    assert_eq!(status, 200, "{reply}");
    assert!(started.elapsed() < Duration::from_secs(5));
}

#[test]
fn substeps_per_tick_of_4e9_is_refused() {
    let text = std::fs::read_to_string("sims/sphere_surface.toml")
        .unwrap()
        .replace("[arm]", "[arm]\nsubsteps_per_tick = 4000000000");
    let error = voxhap::sim::Scenario::parse(&text, "s.toml")
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("arm.substeps_per_tick: 4000000000 is out of range 1..=1000"),
        "{error}"
    );
}

#[test]
fn bench_loop_with_2000_load_threads_is_refused() {
    let output = voxhap()
        .args(["bench-loop", "--load-threads", "2000", "--seconds", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("0..=64"), "{stderr}");
}

/// Sends `request` on a fresh connection and returns the status code (0: closed without an answer).
async fn raw_status(addr: std::net::SocketAddr, request: &str) -> u16 {
    let mut stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut response = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut response)).await;
    let text = String::from_utf8_lossy(&response);
    text.split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_open_connections_cannot_lock_out_a_complete_request() {
    // max_clients 2: 66 connection slots. 200 half-open connections (half a request head each) ...
    let server = TestServer::start(2).await;
    let mut half_open = Vec::new();
    for _ in 0..200 {
        let mut stream = tokio::net::TcpStream::connect(server.addr).await.unwrap();
        let _ = stream.write_all(b"GET /api/state HTTP/1.1\r\nHo").await;
        half_open.push(stream);
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    // ... and a complete request still gets its answer at once.
    let started = Instant::now();
    let (status, _, body) = http(server.addr, "GET", "/api/state", None, "").await;
    assert_eq!(status, 200, "{body}");
    assert!(
        started.elapsed() < Duration::from_secs(2),
        "{:?}",
        started.elapsed()
    );
    drop(half_open);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_head_must_arrive_within_the_header_deadline() {
    let server = TestServer::start_configured(4, |config| {
        config.header_timeout = Duration::from_millis(400);
    })
    .await;
    let mut stream = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    stream
        .write_all(b"GET /api/state HTTP/1.1\r\nHost: x")
        .await
        .unwrap();
    let started = Instant::now();
    let mut buf = [0u8; 64];
    let read = tokio::time::timeout(Duration::from_secs(5), stream.read(&mut buf)).await;
    assert!(matches!(read, Ok(Ok(0)) | Ok(Err(_))), "{read:?}");
    let elapsed = started.elapsed();
    assert!(
        elapsed >= Duration::from_millis(300) && elapsed < Duration::from_secs(3),
        "closed after {elapsed:?} (idle rule is 30 s, head deadline 0.4 s)"
    );
    // A WebSocket client keeps its stream well past the head deadline.
    let mut ws = server.ws("rate=30").await;
    tokio::time::sleep(Duration::from_millis(900)).await;
    let message = crate::util::server::next_json(&mut ws).await;
    assert_eq!(message["type"], "state", "{message}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dns_rebinding_and_cross_site_pages_are_refused() {
    let server = TestServer::start_configured(4, |config| {
        config.allowed_hosts = vec!["voxhap.lab".to_owned()];
    })
    .await;
    let addr = server.addr;
    let port = addr.port();
    let get = |host: String, path: &str| {
        format!("GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n")
    };
    // DNS rebinding: the page's own name re-pointed at 127.0.0.1.
    for path in ["/api/state", "/api/slice", "/"] {
        let status = raw_status(addr, &get(format!("rebind.example:{port}"), path)).await;
        assert_eq!(status, 403, "{path}");
    }
    assert_eq!(
        raw_status(addr, &get(format!("localhost:{port}"), "/api/state")).await,
        200
    );
    assert_eq!(
        raw_status(addr, &get(format!("voxhap.lab:{port}"), "/api/state")).await,
        200
    );
    // Cross-site WebSocket and control requests.
    let upgrade = |origin: &str| {
        format!(
            "GET /ws HTTP/1.1\r\nHost: {addr}\r\nOrigin: {origin}\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n\
             Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
        )
    };
    assert_eq!(
        raw_status(addr, &upgrade("https://evil.example")).await,
        403
    );
    assert_eq!(
        raw_status(addr, &upgrade(&format!("http://{addr}"))).await,
        101
    );
    let post = |origin: &str| {
        format!(
            "POST /api/stiffness HTTP/1.1\r\nHost: {addr}\r\nOrigin: {origin}\r\nAuthorization: Bearer {TOKEN}\r\n\
             Content-Type: application/json\r\nContent-Length: 10\r\nConnection: close\r\n\r\n{{\"k\": 450}}"
        )
    };
    assert_eq!(raw_status(addr, &post("https://evil.example")).await, 403);
    assert_eq!(
        raw_status(addr, &post(&format!("http://{addr}"))).await,
        200
    );
}

fn crafted_nhdr(dir: &Path, name: &str, data_file: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(
        &path,
        format!("NRRD0004\ntype: uchar\ndimension: 3\nsizes: 8 1 1\nencoding: raw\ndata file: {data_file}\n\n"),
    )
    .unwrap();
    path
}

#[test]
fn a_header_whose_data_file_climbs_out_of_its_folder_is_refused() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("volumes");
    std::fs::create_dir(&dir).unwrap();
    std::fs::write(root.path().join("secret.raw"), b"secret!!").unwrap();
    std::os::unix::fs::symlink(root.path().join("secret.raw"), dir.join("link.raw")).unwrap();
    for (name, data_file) in [
        ("climb.nhdr", "../../../../../../etc/passwd"),
        ("absolute.nhdr", "/etc/passwd"),
        ("up.nhdr", "../secret.raw"),
        ("symlink.nhdr", "link.raw"),
    ] {
        let path = crafted_nhdr(&dir, name, data_file);
        let message = load_with(&path, &LoadOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("outside the folder") && message.contains("--allow-outside-paths"),
            "{name}: {message}"
        );
    }
    // The flag lets a trusted header reach outside.
    let allowed = LoadOptions {
        allow_outside_paths: true,
        ..LoadOptions::default()
    };
    let path = crafted_nhdr(&dir, "allowed.nhdr", "../secret.raw");
    assert!(load_with(&path, &allowed).is_ok());
    // Scene files: a volume file outside the scenario's folder.
    let scenario = std::fs::read_to_string("sims/sphere_surface.toml")
        .unwrap()
        .replace("builtin = \"sphere\"", "file = \"../secret.nhdr\"");
    crafted_nhdr(root.path(), "secret.nhdr", "secret.raw");
    std::fs::write(dir.join("scene.toml"), scenario).unwrap();
    let output = voxhap()
        .args(["sim", "scene.toml", "--out", "t.csv"])
        .current_dir(&dir)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("--allow-outside-paths"), "{stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_slice_never_serves_etc_passwd() {
    let dir = tempfile::tempdir().unwrap();
    let volumes = dir.path().join("volumes");
    std::fs::create_dir(&volumes).unwrap();
    let crafted = crafted_nhdr(&volumes, "passwd.nhdr", "/etc/passwd");
    std::fs::write(volumes.join("ok.raw"), [9u8; 8]).unwrap();
    crafted_nhdr(&volumes, "ok.nhdr", "ok.raw");
    let server = TestServer::start(4).await;
    let session: Arc<dyn SessionApi> = server.api.clone();
    // No --volume-dir: files are not loaded through the API at all.
    let closed = ConfinedVolumes::new(session.clone(), VolumeDirs::default());
    let load = |path: &Path| ControlCommand::LoadVolume {
        path: path.to_path_buf(),
        name: None,
    };
    let error = closed.control(load(&crafted)).unwrap_err().to_string();
    assert!(error.contains("--volume-dir"), "{error}");
    // With --volume-dir: only files inside it, and their data files only inside their folder.
    let open = ConfinedVolumes::new(
        session,
        VolumeDirs::new(std::slice::from_ref(&volumes)).unwrap(),
    );
    let error = open
        .control(load(Path::new("passwd.nhdr")))
        .unwrap_err()
        .to_string();
    assert!(error.contains("outside the folder"), "{error}");
    let error = open
        .control(load(Path::new("/etc/passwd")))
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("outside the --volume-dir folders"),
        "{error}"
    );
    let error = open
        .control(load(Path::new("../volumes/../../etc/hosts")))
        .unwrap_err();
    assert!(!error.to_string().is_empty());
    open.control(load(Path::new("ok.nhdr"))).unwrap();
    // /api/slice serves the volume that did load: nine-valued voxels, nothing from /etc/passwd.
    let (status, slice) = server.get("/api/slice?size=16").await;
    assert_eq!(status, 200, "{slice}");
    assert_eq!(slice["max"], 9.0, "{slice}");
}

/// `bench-loop --baseline --json`: the loop and the empty schedule in alternating windows, each side accounting
/// for every deadline of its windows (waited for or skipped).
#[test]
fn bench_loop_baseline_reports_the_empty_schedule_beside_the_loop() {
    let output = voxhap()
        .args([
            "bench-loop",
            "--seconds",
            "2.4",
            "--rate",
            "1000",
            "--rt",
            "off",
            "--baseline",
            "--json",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    // 2.4 s in windows of at most 2 s: 2 pairs of 1.2 s.
    assert_eq!(report["pairs"], 2, "{report}");
    assert_eq!(report["window_s"], 1.2, "{report}");
    // The empty schedule waits for each of its 2 x 1 200 deadlines or skips it; the loop's sessions tick from
    // their start to their stop (start-up and shutdown take a little of each window).
    let ticks = report["baseline"]["ticks"].as_u64().unwrap();
    let skipped = report["baseline"]["skipped_ticks"].as_u64().unwrap();
    assert!(ticks <= 2400 && ticks + skipped >= 2400, "{report}");
    assert!(report["loop"]["ticks"].as_u64().unwrap() > 1000, "{report}");
    for side in ["loop", "baseline"] {
        let ticks = report[side]["ticks"].as_u64();
        assert_eq!(
            report[side]["lateness"]["count"].as_u64(),
            ticks,
            "{side}: {report}"
        );
        // The lateness histogram by decade counts every tick once.
        let decades = report[side]["lateness_by_decade"].as_array().unwrap();
        assert_eq!(decades.len(), 6, "{side}: {report}");
        assert_eq!(
            decades.iter().map(|c| c.as_u64().unwrap()).sum::<u64>(),
            ticks.unwrap(),
            "{side}: {report}"
        );
    }
    assert_eq!(report["sched_fifo"], false, "--rt off asks for nothing");
    // Steal time over the run, where Linux's /proc/stat is readable.
    if std::fs::read_to_string("/proc/stat").is_ok() {
        let steal = &report["steal"];
        assert!(steal["total_ms"].as_f64().unwrap() >= 0.0, "{report}");
        assert!(steal["resolution_ms"].as_f64().unwrap() > 0.0, "{report}");
        assert!(
            steal["servo_cpu_ms"].is_null(),
            "--rt off pins no CPU: {report}"
        );
    } else {
        eprintln!("SKIP steal time check: /proc/stat not readable here");
    }
}

/// Plain `bench-loop` (text): the lateness histogram row counts every tick once, and the steal line is there.
#[test]
fn bench_loop_prints_the_lateness_histogram_and_the_steal_time() {
    let output = voxhap()
        .args([
            "bench-loop",
            "--seconds",
            "0.5",
            "--rate",
            "1000",
            "--rt",
            "off",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let text = String::from_utf8_lossy(&output.stdout);
    let ticks: u64 = text
        .split("ticks ")
        .nth(1)
        .and_then(|rest| rest.split(',').next())
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no tick count in:\n{text}"));
    let lines: Vec<&str> = text.lines().collect();
    let head = lines
        .iter()
        .position(|l| l.starts_with("lateness histogram"))
        .unwrap_or_else(|| panic!("no lateness histogram in:\n{text}"));
    assert!(
        lines[head].contains("<=1us") && lines[head].contains(">10ms"),
        "{text}"
    );
    let counts: Vec<u64> = lines[head + 1]
        .split_whitespace()
        .skip(1)
        .map(|c| c.parse().unwrap())
        .collect();
    assert_eq!(counts.len(), 6, "{text}");
    assert_eq!(counts.iter().sum::<u64>(), ticks, "{text}");
    assert!(text.contains("steal time"), "{text}");
}
