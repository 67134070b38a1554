//! Tests of [`super`].

use super::*;
use crate::test_support::{meta, samples};
use crate::{create_trace_writer, read_trace, FLAG_INVALID_VALUES};

fn write(path: &Path, modes: &[&str], samples: &[TraceSample]) -> TraceSummary {
    let mut writer = create_trace_writer(path, TraceFormat::Parquet, &meta(modes)).unwrap();
    for s in samples {
        writer.write_sample(s).unwrap();
    }
    writer.finish().unwrap()
}

#[test]
fn round_trip_is_exact_and_a_finished_trace_is_compacted() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    // 2 500 samples 1 ms apart at even ticks: 2.5 s of trace time.
    let written = samples(2500, 2);
    let summary = write(&path, &["surface", "friction"], &written);
    assert_eq!(summary.sample_count, 2500);
    let trace = read_trace(&path).unwrap();
    assert!(trace.warnings.is_empty(), "{:?}", trace.warnings);
    assert_eq!(trace.mode_names, ["surface", "friction"]);
    assert_eq!(trace.samples.len(), written.len());
    for (a, b) in trace.samples.iter().zip(&written) {
        // Bit-exact, including -0.0 and infinite bounds.
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
    }
    let metadata = ParquetMetaDataReader::new()
        .parse_and_finish(&Bytes::from(std::fs::read(&path).unwrap()))
        .unwrap();
    // Written as three one-second row groups, compacted into one when finished.
    assert_eq!(metadata.num_row_groups(), 1);
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        2,
        "trace and sidecar only, no temporary file left"
    );
    let embedded = metadata
        .file_metadata()
        .key_value_metadata()
        .unwrap()
        .iter()
        .find(|kv| kv.key == SIDECAR_KEY)
        .unwrap();
    let sidecar: Sidecar = serde_json::from_str(embedded.value.as_deref().unwrap()).unwrap();
    assert!(sidecar.complete);
    assert_eq!(sidecar.sample_count, 2500);
    assert_eq!(sidecar.trace_format, TraceFormat::Parquet);
}

#[test]
fn a_bad_sample_is_flagged_and_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let mut written = samples(5, 1);
    written[2].force_n.x = f64::NAN;
    written[3].t_s = f64::INFINITY;
    write(&path, &["surface"], &written);
    let trace = read_trace(&path).unwrap();
    assert_eq!(trace.samples.len(), 5);
    assert!(trace.samples[2].force_n.x.is_nan());
    assert_ne!(trace.samples[2].flags & FLAG_INVALID_VALUES, 0);
    assert_eq!(trace.samples[3].t_s, f64::INFINITY);
}

#[test]
fn a_file_cut_anywhere_reads_back_its_complete_row_groups() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let written = samples(3500, 1);
    let mut writer = create_trace_writer(&path, TraceFormat::Parquet, &meta(&["surface"])).unwrap();
    for s in &written {
        writer.write_sample(s).unwrap();
    }
    // Three row groups (1 s each) are on disk; the last 500 samples are still buffered. A crash now
    // (nothing more is written):
    std::mem::forget(writer);
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.parquet");
    std::fs::copy(sidecar_path(&path), sidecar_path(&cut)).unwrap();
    let mut previous = usize::MAX;
    for length in [
        bytes.len(),
        bytes.len() - 1,
        bytes.len() * 2 / 3,
        bytes.len() / 3,
        4,
        0,
    ] {
        std::fs::write(&cut, &bytes[..length]).unwrap();
        let result = read_parquet_trace(&cut);
        if length < 4 {
            assert!(result.is_err());
            continue;
        }
        let trace = result.unwrap();
        assert_eq!(trace.warnings.len(), 1, "{:?}", trace.warnings);
        let n = trace.samples.len();
        assert_eq!(n % 1000, 0, "whole row groups only: {n} at {length} bytes");
        assert!(n <= previous);
        previous = n;
        assert_eq!(trace.samples[..], written[..n]);
        if length == bytes.len() {
            assert_eq!(n, 3000);
        }
    }
    assert_eq!(previous, 0);

    // `voxhap trace repair` writes what was recovered as a finished Parquet file, never over the input.
    let repaired = dir.path().join("t.repaired.parquet");
    let report =
        crate::repair::repair_trace(&path, &repaired, None, &crate::OutputPolicy::default())
            .unwrap();
    assert_eq!(report.sample_count, 3000);
    assert_eq!(report.warnings.len(), 1);
    let trace = read_parquet_trace(&repaired).unwrap();
    assert!(trace.warnings.is_empty());
    assert_eq!(trace.samples[..], written[..3000]);
    let sidecar = trace.sidecar.unwrap();
    assert!(sidecar.complete);
    assert!(sidecar.repaired.unwrap().contains("recovered 3000 samples"));
    assert_eq!(std::fs::read(&path).unwrap(), bytes);
}

#[test]
fn damaged_files_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    write(&path, &["surface"], &samples(1200, 1));
    let bytes = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.parquet");
    std::fs::write(&bad, b"PAR1 this is not parquet").unwrap();
    // No sidecar and nothing complete: an error naming the problem.
    let error = read_parquet_trace(&bad).unwrap_err().to_string();
    assert!(error.contains("no complete row group"), "{error}");
    // Flipped bytes in the middle: an error or fewer samples, never a panic.
    for position in (4..bytes.len()).step_by(997) {
        let mut damaged = bytes.clone();
        damaged[position] ^= 0x5a;
        std::fs::write(&bad, &damaged).unwrap();
        let _ = read_parquet_trace(&bad);
    }
}
