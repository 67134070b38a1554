//! Where traces may be written and what happens when the disk refuses them: an output path is never
//! followed through a symbolic link (the trace, its sidecar; `sim --out`, `serve --record`, the API's
//! start-recording), `--force` never writes through a hard link, the control API records only into its
//! `--record-dir` folder under a plain file name, and a full disk (a child process under `RLIMIT_FSIZE`,
//! whose writes then fail with EFBIG, as they fail with ENOSPC on a full disk) stops the recording loudly
//! while the sidecar counts exactly the samples a reader gets back, in every format. Lying sidecars are
//! reported by every reader.

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;
use voxhap::record::{read_trace, sidecar_path, Sidecar};
use voxhap::servo::api::folders::{ConfinedVolumes, RecordDir, VolumeDirs};
use voxhap::servo::api::{ControlCommand, SessionApi};
use voxhap::servo::device::DeviceSpec;
use voxhap::servo::rt::RtMode;
use voxhap::servo::setup::SceneSetup;
use voxhap::servo::{Session, SessionConfig};

fn voxhap(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .args(args)
        .output()
        .unwrap()
}

/// Runs voxhap with every file it writes limited to `limit_bytes` (`RLIMIT_FSIZE`), SIGXFSZ ignored, so
/// a write past the limit fails with EFBIG ("File too large") the way one on a full disk fails with
/// ENOSPC: the part that fits is written, the rest refused. Unprivileged and portable to any Unix.
fn voxhap_with_file_limit(args: &[&std::ffi::OsStr], limit_bytes: u64) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command.args(args);
    // SAFETY: only async-signal-safe calls (signal, setrlimit) between fork and exec.
    unsafe {
        command.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let limit = libc::rlimit {
                rlim_cur: limit_bytes as libc::rlim_t,
                rlim_max: limit_bytes as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.output().unwrap()
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

/// A copy of a shipped scenario in `dir` lasting `duration_s`.
fn scenario(dir: &Path, duration_s: f64) -> PathBuf {
    let sims = Path::new(env!("CARGO_MANIFEST_DIR")).join("sims");
    let text = std::fs::read_to_string(sims.join("vortex_core.toml")).unwrap();
    assert!(text.contains("duration_s = 8.0"));
    let path = dir.join("scenario.toml");
    std::fs::write(
        &path,
        text.replace("duration_s = 8.0", &format!("duration_s = {duration_s}")),
    )
    .unwrap();
    path
}

fn sim(scenario: &Path, out: &Path, force: bool) -> Output {
    let mut args = vec![
        "sim".as_ref(),
        scenario.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ];
    if force {
        args.push("--force".as_ref());
    }
    voxhap(&args)
}

#[test]
fn sim_and_serve_never_create_a_file_through_a_symlink() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario(dir.path(), 0.1);
    let elsewhere = dir.path().join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    // A dangling link as the trace: refused, with and without --force, and its target never created.
    let target = elsewhere.join("created.csv");
    let link = dir.path().join("link.csv");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    for force in [false, true] {
        let output = sim(&scenario, &link, force);
        assert!(!output.status.success(), "force {force}");
        let text = stderr(&output);
        assert!(
            text.contains("link.csv is a symbolic link"),
            "force {force}: {text}"
        );
        assert!(
            !target.exists(),
            "force {force}: the link's target was created"
        );
        assert!(!sidecar_path(&link).exists());
    }
    // A dangling link as the sidecar: refused before anything is created.
    let sidecar_target = elsewhere.join("sidecar.json");
    let out = dir.path().join("run.parquet");
    std::os::unix::fs::symlink(&sidecar_target, sidecar_path(&out)).unwrap();
    let output = sim(&scenario, &out, true);
    assert!(!output.status.success());
    assert!(
        stderr(&output).contains("run.parquet.json is a symbolic link"),
        "{}",
        stderr(&output)
    );
    assert!(!sidecar_target.exists() && !out.exists());
    // serve --record through a dangling link.
    let serve_target = elsewhere.join("serve.mcap");
    let serve_link = dir.path().join("serve.mcap");
    std::os::unix::fs::symlink(&serve_target, &serve_link).unwrap();
    let output = voxhap(&[
        "serve".as_ref(),
        "--record".as_ref(),
        serve_link.as_os_str(),
        "--duration".as_ref(),
        "0.2".as_ref(),
        "--no-http".as_ref(),
        "--no-foxglove".as_ref(),
    ]);
    assert!(!output.status.success());
    assert!(
        stderr(&output).contains("serve.mcap is a symbolic link"),
        "{}",
        stderr(&output)
    );
    assert!(!serve_target.exists());
}

/// `--force` replaces a trace by removing it and creating a new file: a hard link to the old trace keeps
/// the old contents (writing into the old file would change both).
#[test]
fn force_never_writes_through_a_hard_link() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario(dir.path(), 0.1);
    let out = dir.path().join("run.csv");
    let keep = dir.path().join("keep.csv");
    std::fs::write(&keep, b"precious").unwrap();
    std::fs::hard_link(&keep, &out).unwrap();
    let output = sim(&scenario, &out, true);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_eq!(std::fs::read(&keep).unwrap(), b"precious");
    assert!(read_trace(&out).unwrap().samples.len() >= 100);
}

fn session() -> Session {
    let mut config = SessionConfig::new(DeviceSpec::Sim, SceneSetup::builtin().unwrap());
    config.rt = RtMode::Off;
    config.spin_ns = 20_000;
    let session = Session::start(config).unwrap();
    for _ in 0..400 {
        if session.api().snapshot().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    session
}

#[test]
fn the_api_records_only_a_plain_file_name_in_the_record_dir() {
    let session = session();
    let api = session.api();
    let start = |confined: &dyn SessionApi, path: &str| {
        confined.control(ControlCommand::StartRecording {
            path: PathBuf::from(path),
            format: None,
        })
    };
    // Without --record-dir: off.
    let closed = ConfinedVolumes::new(api.clone(), VolumeDirs::default());
    let error = start(&closed, "run.csv").unwrap_err().to_string();
    assert!(error.contains("--record-dir"), "{error}");

    let root = tempfile::tempdir().unwrap();
    let records = root.path().join("records");
    std::fs::create_dir(&records).unwrap();
    let open = ConfinedVolumes::new(api.clone(), VolumeDirs::default())
        .with_record_dir(RecordDir::new(Some(&records)).unwrap());
    let outside = root.path().join("escape.csv");
    for path in [
        "../escape.csv",
        outside.to_str().unwrap(),
        "/tmp/voxhap-api-escape.csv",
        "sub/run.csv",
        "./run.csv",
        "..",
        "",
    ] {
        let error = start(&open, path).unwrap_err().to_string();
        assert!(error.contains("plain file name"), "{path:?}: {error}");
    }
    assert!(!outside.exists());
    assert!(!Path::new("/tmp/voxhap-api-escape.csv").exists());
    // A dangling symlink in the folder is not followed.
    let target = root.path().join("target.csv");
    std::os::unix::fs::symlink(&target, records.join("link.csv")).unwrap();
    let error = start(&open, "link.csv").unwrap_err().to_string();
    assert!(error.contains("symbolic link"), "{error}");
    assert!(!target.exists());
    // A plain name records into the folder.
    let reply = start(&open, "run.csv").unwrap();
    assert!(reply.message.contains("run.csv"), "{}", reply.message);
    std::thread::sleep(Duration::from_millis(300));
    open.control(ControlCommand::StopRecording).unwrap();
    let trace = read_trace(&records.join("run.csv")).unwrap();
    assert!(!trace.samples.is_empty());
    assert!(trace.warnings.is_empty(), "{:?}", trace.warnings);
    assert_eq!(
        trace.sidecar.unwrap().sample_count,
        trace.samples.len() as u64
    );
}

fn read_sidecar(trace: &Path) -> Sidecar {
    serde_json::from_slice(&std::fs::read(sidecar_path(trace)).unwrap()).unwrap()
}

/// The trace after a failed write: the sidecar says why and counts exactly the samples a reader gets.
fn assert_exact_after_failure(out: &Path) -> u64 {
    let sidecar = read_sidecar(out);
    assert!(!sidecar.complete, "{}", out.display());
    let error = sidecar.error.clone().unwrap_or_default();
    assert!(
        error.contains("File too large"),
        "{}: {error}",
        out.display()
    );
    let trace = read_trace(out).unwrap();
    let read = trace.samples.len() as u64;
    assert!(read > 0, "{}: nothing reached the file", out.display());
    assert_eq!(
        sidecar.sample_count,
        read,
        "{}: the sidecar claims {} samples, the file holds {read}",
        out.display(),
        sidecar.sample_count
    );
    // The reader does not complain about the sidecar (its other warnings: the cut-off end).
    assert!(
        trace.warnings.iter().all(|w| !w.contains("does not match")),
        "{:?}",
        trace.warnings
    );
    read
}

/// A sim whose trace file hits the size limit mid-run: exit non-zero naming the reason, and a trace
/// whose sidecar counts exactly what reached the file. Fails when the sidecar counts the samples still
/// in the writer's buffers (1000 more in Parquet).
#[test]
fn a_full_disk_stops_a_sim_and_the_sidecar_counts_what_reached_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario(dir.path(), 8.0);
    // MCAP starts with about 1 MB of volume mesh, so it gets more room before the limit.
    for (name, limit) in [
        ("run.csv", 192 << 10),
        ("run.mcap", 4 << 20),
        // A Parquet row group is a second of ticks: trace format 3's energy columns make it larger than
        // 192 KiB, so the limit leaves room for a few groups (the file would be over 1 MB).
        ("run.parquet", 512 << 10),
    ] {
        let out = dir.path().join(name);
        let output = voxhap_with_file_limit(
            &[
                "sim".as_ref(),
                scenario.as_os_str(),
                "--out".as_ref(),
                out.as_os_str(),
            ],
            limit,
        );
        assert!(!output.status.success(), "{name}: {}", stderr(&output));
        assert!(
            stderr(&output).contains("File too large"),
            "{name}: {}",
            stderr(&output)
        );
        let read = assert_exact_after_failure(&out);
        assert!(read < 8000, "{name}: {read} samples");
    }
}

/// `serve --record` on a disk that fills: the recording stops, stderr says so at once, the session runs
/// to its end unrecorded, and serve exits non-zero naming the error; the sidecar is exact.
#[test]
fn a_full_disk_stops_the_recording_loudly_and_serve_exits_non_zero() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("serve.csv");
    let output = voxhap_with_file_limit(
        &[
            "serve".as_ref(),
            "--record".as_ref(),
            out.as_os_str(),
            "--duration".as_ref(),
            "1.5".as_ref(),
            "--no-http".as_ref(),
            "--no-foxglove".as_ref(),
        ],
        64 * 1024,
    );
    let text = stderr(&output);
    assert!(!output.status.success(), "{text}");
    assert!(
        text.contains("RECORDING STOPPED, the session goes on unrecorded"),
        "{text}"
    );
    assert!(text.contains("recording failed"), "{text}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("stopped (duration"), "{stdout}");
    assert_exact_after_failure(&out);
}

/// Every reader warns when the sidecar contradicts the data: the count and the modes.
#[test]
fn readers_warn_on_a_lying_sidecar() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario(dir.path(), 0.3);
    for name in ["lie.csv", "lie.mcap", "lie.parquet"] {
        let out = dir.path().join(name);
        let output = sim(&scenario, &out, false);
        assert!(output.status.success(), "{}", stderr(&output));
        let honest = read_trace(&out).unwrap();
        assert!(honest.warnings.is_empty(), "{name}: {:?}", honest.warnings);
        let count = honest.samples.len() as u64;
        let mut sidecar = read_sidecar(&out);
        sidecar.sample_count = count + 986;
        sidecar.meta.mode_names.push("ghost".to_owned());
        std::fs::write(
            sidecar_path(&out),
            serde_json::to_vec_pretty(&sidecar).unwrap(),
        )
        .unwrap();
        let trace = read_trace(&out).unwrap();
        let all = trace.warnings.join("\n");
        assert!(
            all.contains(&format!(
                "it says {} samples, the trace holds {count}",
                count + 986
            )),
            "{name}: {all}"
        );
        assert!(all.contains("ghost"), "{name}: {all}");
        // voxhap plot shows them on stderr.
        let png = dir.path().join(format!("{name}.png"));
        let plotted = voxhap(&[
            "plot".as_ref(),
            out.as_os_str(),
            "--out".as_ref(),
            png.as_os_str(),
        ]);
        assert!(
            stderr(&plotted).contains("does not match the trace"),
            "{name}: {}",
            stderr(&plotted)
        );
    }
}

/// One HTTP request to a server at `addr`; returns the status and the body.
fn http(addr: &str, request: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    stream.write_all(request.as_bytes()).unwrap();
    let mut response = String::new();
    stream.read_to_string(&mut response).unwrap();
    let status = response
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let body = response
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, b)| b.to_owned());
    (status, body)
}

/// After a recording started through the API fails (the file hits its size limit, as on a full disk), a new
/// recording starts at once, without a stop first. Fails when the control side still counts the failed
/// recording as running ("already recording to").
#[test]
fn a_new_recording_starts_after_a_failed_one() {
    use std::io::BufRead;
    let dir = tempfile::tempdir().unwrap();
    let mut command = Command::new(env!("CARGO_BIN_EXE_voxhap"));
    command
        .args([
            "serve",
            "--http",
            "127.0.0.1:0",
            "--no-foxglove",
            "--duration",
            "60",
        ])
        .arg("--record-dir")
        .arg(dir.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    // SAFETY: only async-signal-safe calls (signal, setrlimit) between fork and exec.
    unsafe {
        command.pre_exec(|| {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let limit = libc::rlimit {
                rlim_cur: 64 * 1024,
                rlim_max: 64 * 1024,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = command.spawn().unwrap();
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    let (mut addr, mut token) = (None, None);
    while addr.is_none() || token.is_none() {
        let line = lines
            .next()
            .expect("serve printed its address and token")
            .unwrap();
        if let Some(rest) = line.strip_prefix("http: listening on http://") {
            addr = Some(rest.trim_end_matches('/').to_owned());
        } else if let Some(rest) = line.strip_prefix("http: control token ") {
            token = Some(rest.trim().to_owned());
        }
    }
    let (addr, token) = (addr.unwrap(), token.unwrap());
    let start = |name: &str| {
        let body = format!("{{\"path\": \"{name}\"}}");
        http(
            &addr,
            &format!(
                "POST /api/record/start HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
                body.len()
            ),
        )
    };
    let (status, body) = start("first.csv");
    assert_eq!(status, 200, "{body}");
    // Wait (as long as it takes) for the first recording to fail: its sidecar then names the error.
    let first = dir.path().join("first.csv");
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while std::fs::read(sidecar_path(&first))
        .ok()
        .and_then(|b| serde_json::from_slice::<Sidecar>(&b).ok())
        .is_none_or(|s| s.error.is_none())
    {
        assert!(
            std::time::Instant::now() < deadline,
            "the first recording never failed"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let (status, body) = start("second.csv");
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let output = child.wait_with_output().unwrap();
    assert_eq!(status, 200, "{body}\n{}", stderr(&output));
    assert!(body.contains("second.csv"), "{body}");
    assert!(dir.path().join("second.csv").exists());
    assert_exact_after_failure(&first);
}
