//! Tests of [`super`].

use super::*;
use crate::test_support::{meta, samples, write_trace};
use crate::{read_trace_as, FLAG_INVALID_VALUES};

#[test]
fn write_then_read_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.csv");
    let data = samples(500, 3);
    write_trace(&path, &["surface", "friction", "vector-follow"], &data);
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    assert_eq!(trace.mode_names, ["surface", "friction", "vector-follow"]);
    assert_eq!(trace.samples.len(), data.len());
    for (read, written) in trace.samples.iter().zip(&data) {
        // Bit-exact, including -0.0 and inf.
        assert_eq!(read.t_s.to_bits(), written.t_s.to_bits());
        for (a, b) in [
            (read.probe_m, written.probe_m),
            (read.modes.forces_n()[2], written.modes.forces_n()[2]),
            (read.proxy_m, written.proxy_m),
            (read.sent_force_n, written.sent_force_n),
        ] {
            assert_eq!(
                a.to_array().map(f64::to_bits),
                b.to_array().map(f64::to_bits)
            );
        }
        assert_eq!(
            read.error_bound_m.to_bits(),
            written.error_bound_m.to_bits()
        );
        assert_eq!(read, written);
    }
    let sidecar = trace.sidecar.expect("sidecar written");
    assert!(sidecar.complete);
    assert_eq!(sidecar.sample_count, 500);
    assert_eq!(sidecar.trace_file, "run.csv");
    assert_eq!(
        sidecar.meta,
        meta(&["surface", "friction", "vector-follow"])
    );
    assert_eq!(
        sidecar.columns.len(),
        columns(&["surface".into(), "friction".into(), "vector-follow".into()]).len()
    );
}

#[test]
fn zero_modes_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.csv");
    let data = samples(10, 0);
    write_trace(&path, &[], &data);
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    assert!(trace.mode_names.is_empty());
    assert_eq!(trace.samples, data);
}

#[test]
fn bad_samples_are_recorded_flagged_and_never_end_the_trace() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.csv");
    let mut writer = CsvTraceWriter::create(&path, &meta(&["surface"])).unwrap();
    let mut sample = TraceSample::zeroed(1);
    sample.tick = 5;
    writer.write_sample(&sample).unwrap();
    // A repeated tick is left out and counted.
    writer.write_sample(&sample).unwrap();
    sample.tick = 6;
    sample.proxy_m.y = f64::NAN;
    sample.error_bound_m = f64::NAN;
    writer.write_sample(&sample).unwrap();
    sample.tick = 7;
    sample.proxy_m.y = 1e300;
    sample.modes.set_count(2);
    writer.write_sample(&sample).unwrap();
    sample.tick = 8;
    sample.modes.set_count(1);
    sample.error_bound_m = -1.0;
    writer.write_sample(&sample).unwrap();
    sample.tick = 9;
    sample.error_bound_m = 0.0;
    writer.write_sample(&sample).unwrap();
    let summary = writer.finish().unwrap();
    assert_eq!(summary.sample_count, 5);
    assert!(matches!(
        writer.write_sample(&sample),
        Err(TraceError::Finished)
    ));
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    let flagged: Vec<u64> = trace
        .samples
        .iter()
        .filter(|s| s.flags & FLAG_INVALID_VALUES != 0)
        .map(|s| s.tick)
        .collect();
    assert_eq!(flagged, [6, 7, 8]);
    assert!(trace.samples[1].proxy_m.y.is_nan());
    assert_eq!(trace.samples.last().unwrap().tick, 9);
    assert_eq!(trace.sidecar.unwrap().samples_rejected, 1);
}

fn valid_text() -> String {
    let mut out = Vec::new();
    let header: Vec<String> = columns(&["surface".to_string()])
        .into_iter()
        .map(|c| c.name.into_owned())
        .collect();
    writeln!(out, "{}", header.join(",")).unwrap();
    for sample in samples(4, 1) {
        write_row(&mut out, &sample, 0);
    }
    String::from_utf8(out).unwrap()
}

fn read_err(text: &str) -> String {
    parse_csv_trace(text.as_bytes()).unwrap_err().to_string()
}

#[test]
fn malformed_csv_errors_name_the_line_and_column() {
    let good = valid_text();
    assert_eq!(parse_csv_trace(good.as_bytes()).unwrap().1.len(), 4);

    let lines: Vec<&str> = good.lines().collect();
    // A bad float on line 3, column 5 (probe_y_m).
    let mut fields: Vec<&str> = lines[2].split(',').collect();
    fields[4] = "0.0x1";
    let broken = [lines[0], lines[1], &fields.join(","), lines[3]].join("\n") + "\n";
    let err = read_err(&broken);
    assert!(
        err.contains("line 3, column 5 (probe_y_m)") && err.contains("0.0x1"),
        "{err}"
    );
    // A missing field on line 3 (not the last line).
    let short = lines[2].rsplit_once(',').unwrap().0;
    let err = read_err(&([lines[0], lines[1], short, lines[3]].join("\n") + "\n"));
    assert!(err.contains("line 3") && err.contains("fields"), "{err}");
    // Ticks going backwards on line 3.
    let err = read_err(&([lines[0], lines[2], lines[1]].join("\n") + "\n"));
    assert!(err.contains("line 3") && err.contains("tick"), "{err}");
    // A NaN position without the invalid-values flag.
    let nan_row = lines[1].replacen(",0.02,", ",NaN,", 1);
    assert_ne!(nan_row, lines[1]);
    let err = read_err(&([lines[0], &nan_row].join("\n") + "\n"));
    assert!(
        err.contains("line 2") && err.contains("not finite"),
        "{err}"
    );
    // A wrong header.
    let err = read_err(&good.replacen("probe_x_m", "probe_x_mm", 1));
    assert!(err.contains("line 1, column 4"), "{err}");
    // An empty file.
    assert!(matches!(
        parse_csv_trace(&b""[..]),
        Err(TraceReadError::Empty)
    ));
    // Negative primitive count.
    let index = columns(&["surface".to_string()])
        .iter()
        .position(|c| c.name == "primitives_surface")
        .unwrap();
    let mut fields: Vec<&str> = lines[1].split(',').collect();
    fields[index] = "-1";
    let err = read_err(&([lines[0], &fields.join(",")].join("\n") + "\n"));
    assert!(
        err.contains(&format!("column {} (primitives_surface)", index + 1)),
        "{err}"
    );
    // A flag column that disagrees with flag_bits.
    let flipped = lines[1].replacen(",false", ",true", 1);
    let err = read_err(&([lines[0], &flipped].join("\n") + "\n"));
    assert!(err.contains("disagrees with flag_bits"), "{err}");
}

#[test]
fn a_partial_last_line_is_skipped_with_a_warning() {
    let good = valid_text();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.csv");
    // Cut in the middle of the last line, as a crash leaves it.
    let cut = good.len() - 9;
    std::fs::write(&path, &good[..cut]).unwrap();
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    assert_eq!(trace.samples.len(), 3);
    assert_eq!(trace.warnings.len(), 1);
    assert!(
        trace.warnings[0].contains("partial last line 5"),
        "{:?}",
        trace.warnings
    );
    // The same damage in the middle of the file is an error.
    let lines: Vec<&str> = good.lines().collect();
    let middle = [lines[0], &lines[1][..20], lines[2]].join("\n") + "\n";
    assert!(parse_csv_trace(middle.as_bytes()).is_err());
}

#[test]
fn an_old_format_trace_is_refused_with_a_clear_error() {
    let old = "tick,t_s,probe_x_m,probe_y_m,probe_z_m,proxy_x_m,proxy_y_m,proxy_z_m,force_x_n,force_y_n,force_z_n,primitives_surface,sweeps,error_bound_m,flags\n0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,1,2,0.0,0\n";
    let err = read_err(old);
    assert!(
        err.contains("older voxhap") && err.contains("format 1"),
        "{err}"
    );
}

/// A format-4 trace (today's columns without format 5's six) is refused, naming the format and what it lacks.
#[test]
fn a_format_4_trace_is_refused_naming_the_missing_columns() {
    let names: Vec<String> = crate::columns::columns(&["surface".to_string()])
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(names[names.len() - 6], "device_proxy_x_m");
    let header = names[..names.len() - 6].join(",") + "\n";
    let err = read_err(&header);
    assert!(
        err.contains("older voxhap")
            && err.contains("format 4")
            && err.contains("device_proxy or local_model"),
        "{err}"
    );
}

#[test]
fn lines_reach_the_file_whole_on_flush() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("live.csv");
    let mut writer = CsvTraceWriter::create(&path, &meta(&["surface"])).unwrap();
    for sample in samples(10, 1) {
        writer.write_sample(&sample).unwrap();
    }
    writer.flush().unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.ends_with('\n'));
    assert_eq!(text.lines().count(), 11);
    // Readable while the writer is still open (the sidecar says incomplete).
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    assert_eq!(trace.samples.len(), 10);
    assert!(!trace.sidecar.unwrap().complete);
}

/// A full disk mid-trace: the rows flushed before it stay, the sidecar counts exactly the rows a reader
/// gets back, and nothing is written after the failure. The writer's file is switched to /dev/full
/// (which fails every write with ENOSPC, as a full disk does) after 1000 rows were flushed.
#[test]
fn a_full_disk_is_an_error_with_the_os_reason_and_the_sidecar_counts_what_reached_the_file() {
    use std::os::unix::io::AsRawFd;
    let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
        eprintln!("skipped: /dev/full cannot be opened on this system");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.csv");
    let mut writer = CsvTraceWriter::create(&path, &meta(&["surface"])).unwrap();
    let data = samples(3000, 1);
    for sample in &data[..1000] {
        writer.write_sample(sample).unwrap();
    }
    writer.flush().unwrap();
    let fd = writer.file.as_ref().unwrap().as_raw_fd();
    // SAFETY: both descriptors are open; dup2 makes the writer's descriptor refer to /dev/full.
    assert_eq!(unsafe { libc::dup2(full.as_raw_fd(), fd) }, fd);
    let mut failure = None;
    for sample in &data[1000..] {
        if let Err(error) = writer.write_sample(sample) {
            failure = Some(error);
            break;
        }
    }
    let error = match failure {
        Some(error) => error,
        None => writer.flush().unwrap_err(),
    };
    let text = crate::error_chain(&error);
    assert!(text.contains("No space left on device"), "{text}");
    writer.fail(&text).unwrap();
    let trace = read_trace_as(&path, TraceFormat::Csv).unwrap();
    assert_eq!(trace.samples.len(), 1000);
    let sidecar = trace.sidecar.unwrap();
    assert!(!sidecar.complete);
    assert_eq!(
        sidecar.sample_count, 1000,
        "rows buffered when the disk filled are not counted"
    );
    assert!(sidecar.error.unwrap().contains("No space left on device"));
}

#[test]
fn crlf_line_ends_are_accepted() {
    let text = valid_text().replace('\n', "\r\n");
    assert_eq!(parse_csv_trace(text.as_bytes()).unwrap().1.len(), 4);
}

proptest::proptest! {
    /// Arbitrary bytes never panic the reader.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
        let _ = parse_csv_trace(&bytes[..]);
    }

    /// A valid trace with bytes overwritten, inserted or deleted never panics the reader, and
    /// whatever it accepts obeys the trace rules.
    #[test]
    fn mutated_traces_never_panic(
        edits in proptest::collection::vec((0usize..10_000, proptest::prelude::any::<u8>(), 0u8..3), 1..8)
    ) {
        let mut bytes = valid_text().into_bytes();
        for (position, byte, kind) in edits {
            let at = position % (bytes.len() + 1);
            match kind {
                0 if at < bytes.len() => bytes[at] = byte,
                1 => bytes.insert(at, byte),
                _ if at < bytes.len() => { bytes.remove(at); }
                _ => {}
            }
        }
        if let Ok((modes, samples)) = parse_csv_trace(&bytes[..]) {
            let mut last = None;
            for sample in &samples {
                proptest::prop_assert!(check_sample(sample, modes.len(), last).is_ok());
                last = Some(sample.tick);
            }
        }
    }
}
