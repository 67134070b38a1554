//! `voxhap plot` on long traces, as a separate process: its peak memory does not grow with the trace's length
//! (its VmHWM, read from /proc while it runs), and the extents it draws are the data's, computed here from
//! the samples as they were written.

use glam::DVec3;
use std::path::Path;
use std::process::Command;
use voxhap::record::{create_trace_writer, TraceFormat, TraceMeta, TraceSample};

/// Writes `seconds` of a 1 kHz trace in `format`: the probe runs a 20 mm circle every 3 s with a slow drift
/// in z, the proxy follows 1 mm below, and the force is a slowly modulated spring. Returns the smallest and
/// largest value of each series `voxhap plot --extents` names, in its order.
fn write_trace(path: &Path, format: TraceFormat, seconds: u64) -> Vec<(&'static str, f64, f64)> {
    write_trace_ending(path, format, seconds, true)
}

/// [`write_trace`], finished or (`finish` false) left as a crash leaves it: what reached the file, no final
/// footer or summary.
fn write_trace_ending(
    path: &Path,
    format: TraceFormat,
    seconds: u64,
    finish: bool,
) -> Vec<(&'static str, f64, f64)> {
    let meta = TraceMeta::new(
        vec!["surface".to_string()],
        1000.0,
        serde_json::json!({"name": "long circle"}),
        "procedural:sphere",
        "exact",
    );
    let mut writer = create_trace_writer(path, format, &meta).unwrap();
    let names = [
        "|F|", "Fx", "Fy", "Fz", "probe x", "probe y", "probe z", "proxy x", "proxy y", "proxy z",
    ];
    let mut extents: Vec<(&'static str, f64, f64)> = names
        .iter()
        .map(|&n| (n, f64::INFINITY, f64::NEG_INFINITY))
        .collect();
    let mut sample = TraceSample::zeroed(1);
    for i in 0..seconds * 1000 {
        let t = i as f64 * 1e-3;
        let angle = std::f64::consts::TAU * t / 3.0;
        sample.tick = i;
        sample.t_s = t;
        sample.probe_m = DVec3::new(
            0.02 * angle.cos(),
            0.02 * angle.sin(),
            0.005 * (t / 600.0).sin(),
        );
        sample.proxy_m = sample.probe_m - DVec3::new(0.0, 0.0, 0.001);
        sample.sent_force_n =
            (sample.proxy_m - sample.probe_m) * 500.0 * (1.0 + 0.5 * (t * 0.37).sin())
                + DVec3::new(0.3 * (t * 1.1).cos(), 0.0, 0.0);
        sample.sweeps = (i % 7) as u32;
        sample.error_bound_m = 1e-9 * (1.0 + (i % 13) as f64);
        let values = [
            sample.sent_force_n.length(),
            sample.sent_force_n.x,
            sample.sent_force_n.y,
            sample.sent_force_n.z,
            sample.probe_m.x * 1e3,
            sample.probe_m.y * 1e3,
            sample.probe_m.z * 1e3,
            sample.proxy_m.x * 1e3,
            sample.proxy_m.y * 1e3,
            sample.proxy_m.z * 1e3,
        ];
        for (extent, value) in extents.iter_mut().zip(values) {
            extent.1 = extent.1.min(value);
            extent.2 = extent.2.max(value);
        }
        writer.write_sample(&sample).unwrap();
    }
    if finish {
        writer.finish().unwrap();
    } else {
        writer.flush().unwrap();
        std::mem::forget(writer);
    }
    extents
}

/// The process's peak resident memory so far (KiB), `VmHWM` in /proc/PID/status; `None` once it has exited.
fn peak_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Runs `voxhap plot TRACE --out OUT --extents`; returns its stderr and its peak resident memory (KiB): the
/// largest VmHWM read from /proc while it ran (every millisecond). VmHWM belongs to the program after exec;
/// the child's rusage would also count the test process it was spawned from.
fn plot(trace: &Path, out: &Path) -> (String, u64) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_voxhap"))
        .arg("plot")
        .arg(trace)
        .arg("--out")
        .arg(out)
        .arg("--extents")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run voxhap plot");
    let pid = child.id();
    let mut stderr = child.stderr.take().expect("stderr is piped");
    // Read stderr on a thread, so a full pipe never blocks the child while we watch it.
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut text).unwrap();
        text
    });
    let mut peak = 0;
    let status = loop {
        // Before exec the child is a copy of this process: only values read after exec count, which the
        // program's name in /proc tells.
        let exec_done = std::fs::read_to_string(format!("/proc/{pid}/comm"))
            .is_ok_and(|comm| comm.trim() == "voxhap");
        if exec_done {
            if let Some(kib) = peak_kib(pid) {
                peak = peak.max(kib);
            }
        }
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    let text = reader.join().unwrap();
    assert!(status.success(), "voxhap plot failed ({status}): {text}");
    assert!(peak > 0, "no VmHWM read for voxhap plot");
    (text, peak)
}

/// `drawn NAME: LOW to HIGH UNIT` lines of `voxhap plot --extents`.
fn drawn_extents(text: &str) -> Vec<(String, f64, f64)> {
    text.lines()
        .filter_map(|line| {
            let rest = line.strip_prefix("drawn ")?;
            let (name, values) = rest.split_once(": ")?;
            let mut words = values.split(' ');
            let low = words.next()?.parse().ok()?;
            let _to = words.next()?;
            let high = words.next()?.parse().ok()?;
            Some((name.to_string(), low, high))
        })
        .collect()
}

#[test]
fn plotting_a_long_parquet_trace_streams_in_bounded_memory_and_draws_the_data_extents() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.parquet");
    let long = dir.path().join("long.parquet");
    write_trace(&short, TraceFormat::Parquet, 60);
    // 20 minutes at 1 kHz: 1.2 million samples. Read whole, as before, its samples alone took about 0.9 GB.
    let expected = write_trace(&long, TraceFormat::Parquet, 1200);
    let (_, short_kib) = plot(&short, &dir.path().join("short.png"));
    let (text, long_kib) = plot(&long, &dir.path().join("long.png"));
    eprintln!("voxhap plot peak memory: 1 minute {short_kib} KiB, 20 minutes {long_kib} KiB");
    assert!(
        text.contains("(1200000 samples)"),
        "not every sample was read: {text}"
    );
    // Bounded independently of the length: twenty times the samples, at most 48 MiB more (row-group
    // metadata and page buffers), and under 256 MiB in all.
    assert!(
        long_kib <= short_kib + 96 * 1024,
        "peak memory grew with the trace: {short_kib} KiB for 1 minute, {long_kib} KiB for 20"
    );
    assert!(long_kib < 256 * 1024, "peak memory {long_kib} KiB");
    let drawn = drawn_extents(&text);
    assert_eq!(drawn.len(), expected.len(), "{text}");
    for ((name, low, high), (want, want_low, want_high)) in drawn.iter().zip(&expected) {
        assert_eq!(name, want);
        assert_eq!(
            (*low, *high),
            (*want_low, *want_high),
            "{name}: drawn {low}..{high}, the data spans {want_low}..{want_high}"
        );
    }
}

#[test]
fn plotting_a_long_csv_trace_draws_the_data_extents() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("long.csv");
    let expected = write_trace(&trace, TraceFormat::Csv, 300);
    let (text, kib) = plot(&trace, &dir.path().join("long.svg"));
    eprintln!("voxhap plot peak memory, 5 minutes of CSV: {kib} KiB");
    assert!(text.contains("(300000 samples)"), "{text}");
    assert!(kib < 128 * 1024, "peak memory {kib} KiB");
    let drawn = drawn_extents(&text);
    assert_eq!(drawn.len(), expected.len(), "{text}");
    for ((name, low, high), (want, want_low, want_high)) in drawn.iter().zip(&expected) {
        assert_eq!(name, want);
        assert_eq!((*low, *high), (*want_low, *want_high), "{name}");
    }
}

/// A Parquet trace cut off by a crash (no final footer: 1 200 one-second row groups, each followed by its
/// row-group footer) streams its samples like a finished one. Fails when such a file is read whole (about
/// 0.9 GB of samples for these 20 minutes). What does grow is the metadata of the recovered row groups, held
/// for the whole read as for a finished file's footer: about 44 KiB per one-second group at 69 columns (52 MiB
/// measured for these 20 minutes), so the bound allows 96 MiB.
#[test]
fn plotting_a_long_cut_off_parquet_trace_streams_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.parquet");
    let long = dir.path().join("long.parquet");
    write_trace_ending(&short, TraceFormat::Parquet, 60, false);
    write_trace_ending(&long, TraceFormat::Parquet, 1200, false);
    let (_, short_kib) = plot(&short, &dir.path().join("short.png"));
    let (text, long_kib) = plot(&long, &dir.path().join("long.png"));
    eprintln!(
        "voxhap plot peak memory, cut off: 1 minute {short_kib} KiB, 20 minutes {long_kib} KiB"
    );
    assert!(text.contains("no final footer"), "{text}");
    // The last second may still have been in the writer's buffer: at least 1199 whole row groups.
    assert!(
        text.contains("(1199000 samples)") || text.contains("(1200000 samples)"),
        "{text}"
    );
    assert!(
        long_kib <= short_kib + 96 * 1024,
        "peak memory grew with the trace: {short_kib} KiB for 1 minute, {long_kib} KiB for 20"
    );
}

/// An MCAP trace's file is held while it is read, its samples are not: plotting 5 minutes of MCAP needs at
/// most the file's size plus 64 MiB more than plotting 10 seconds. Fails when the samples are collected (300 000
/// of them, about 0.2 GB, plus their decoded messages).
#[test]
fn plotting_a_long_mcap_trace_streams_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.mcap");
    let long = dir.path().join("long.mcap");
    write_trace(&short, TraceFormat::Mcap, 10);
    let expected = write_trace(&long, TraceFormat::Mcap, 300);
    let (_, short_kib) = plot(&short, &dir.path().join("short.png"));
    let (text, long_kib) = plot(&long, &dir.path().join("long.png"));
    let file_kib = std::fs::metadata(&long).unwrap().len() / 1024;
    eprintln!("voxhap plot peak memory, MCAP: 10 s {short_kib} KiB, 5 minutes {long_kib} KiB (file {file_kib} KiB)");
    assert!(text.contains("(300000 samples)"), "{text}");
    // Read one record (a chunk of about 1 MiB) at a time: thirty times the samples, at most 16 MiB more,
    // under a quarter of the file, which the reader used to hold whole.
    assert!(
        long_kib <= short_kib + 16 * 1024 && 16 * 1024 < file_kib / 4,
        "peak memory {long_kib} KiB against {short_kib} KiB for 10 s and a {file_kib} KiB file"
    );
    let drawn = drawn_extents(&text);
    assert_eq!(drawn.len(), expected.len(), "{text}");
    for ((name, low, high), (want, want_low, want_high)) in drawn.iter().zip(&expected) {
        assert_eq!(name, want);
        assert_eq!((*low, *high), (*want_low, *want_high), "{name}");
    }
}
