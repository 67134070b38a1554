//! Tests of [`super`].

use super::*;
use crate::output::sidecar_path;
use crate::test_support::{meta, samples, temp_trace};
use crate::{create_trace_writer, read_trace, read_trace_as, FLAG_INVALID_VALUES};
use bytes::Bytes;
use parquet::file::metadata::ParquetMetaDataReader;

/// Writes `samples` and then crashes: nothing more is written (no final footer, the open row group lost).
fn write_and_crash(path: &Path, samples: &[TraceSample]) {
    let mut writer = create_trace_writer(path, TraceFormat::Parquet, &meta(&["surface"])).unwrap();
    for s in samples {
        writer.write_sample(s).unwrap();
    }
    std::mem::forget(writer);
}

#[test]
fn round_trip_is_exact_and_a_finished_trace_is_compacted() {
    // 2 500 samples 1 ms apart at even ticks: 2.5 s of trace time (all of them written: temp_trace checks).
    let written = samples(2500, 2);
    let (dir, path) = temp_trace("t.parquet", &["surface", "friction"], &written);
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

/// Every column chunk, in the row-group footers while recording and after compaction, carries the encoding
/// measured smallest for it: BYTE_STREAM_SPLIT for floats, DELTA_BINARY_PACKED for integers, a dictionary
/// only for the text column.
#[test]
fn columns_are_written_with_the_measured_encodings() {
    use parquet::basic::{Encoding, Type};
    let (_dir, path) = temp_trace("t.parquet", &["surface"], &samples(2500, 1));
    let metadata = ParquetMetaDataReader::new()
        .parse_and_finish(&Bytes::from(std::fs::read(&path).unwrap()))
        .unwrap();
    let group = metadata.row_group(0);
    for column in group.columns() {
        let name = column.column_path().string();
        let encodings: Vec<Encoding> = column.encodings().collect();
        let expected = match column.column_type() {
            Type::DOUBLE => Some(Encoding::BYTE_STREAM_SPLIT),
            Type::INT64 => Some(Encoding::DELTA_BINARY_PACKED),
            Type::BYTE_ARRAY => Some(Encoding::RLE_DICTIONARY),
            _ => None,
        };
        if let Some(expected) = expected {
            assert!(encodings.contains(&expected), "{name}: {encodings:?}");
        }
        if column.column_type() != Type::BYTE_ARRAY {
            assert!(
                !encodings.contains(&Encoding::RLE_DICTIONARY),
                "{name}: {encodings:?}"
            );
        }
        assert_eq!(column.compression(), parquet::basic::Compression::SNAPPY);
    }
}

#[test]
fn a_bad_sample_is_flagged_and_kept() {
    let mut written = samples(5, 1);
    written[2].sent_force_n.x = f64::NAN;
    written[3].t_s = f64::INFINITY;
    let (_dir, path) = temp_trace("t.parquet", &["surface"], &written);
    let trace = read_trace(&path).unwrap();
    assert_eq!(trace.samples.len(), 5);
    assert!(trace.samples[2].sent_force_n.x.is_nan());
    assert_ne!(trace.samples[2].flags & FLAG_INVALID_VALUES, 0);
    assert_eq!(trace.samples[3].t_s, f64::INFINITY);
}

#[test]
fn a_file_cut_anywhere_reads_back_its_complete_row_groups() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let written = samples(3500, 1);
    // Three row groups (1 s each) are on disk; the last 500 samples are still buffered.
    write_and_crash(&path, &written);
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
        let result = read_trace_as(&cut, TraceFormat::Parquet);
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
    let trace = read_trace_as(&repaired, TraceFormat::Parquet).unwrap();
    assert!(trace.warnings.is_empty());
    assert_eq!(trace.samples[..], written[..3000]);
    let sidecar = trace.sidecar.unwrap();
    assert!(sidecar.complete);
    assert!(sidecar.repaired.unwrap().contains("recovered 3000 samples"));
    assert_eq!(std::fs::read(&path).unwrap(), bytes);
}

#[test]
fn damaged_files_are_errors_not_panics() {
    let (dir, path) = temp_trace("t.parquet", &["surface"], &samples(1200, 1));
    let bytes = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.parquet");
    std::fs::write(&bad, b"PAR1 this is not parquet").unwrap();
    // No sidecar and nothing complete: an error naming the problem.
    let error = read_trace_as(&bad, TraceFormat::Parquet)
        .unwrap_err()
        .to_string();
    assert!(error.contains("no complete row group"), "{error}");
    // Flipped bytes in the middle: an error or fewer samples, never a panic.
    for position in (4..bytes.len()).step_by(997) {
        let mut damaged = bytes.clone();
        damaged[position] ^= 0x5a;
        std::fs::write(&bad, &damaged).unwrap();
        let _ = read_trace_as(&bad, TraceFormat::Parquet);
    }
}

/// A page header that claims far more uncompressed bytes than its compressed bytes can hold is refused,
/// naming the page, before the Parquet library sizes a buffer from it. The header is patched in place by the
/// Thrift compact protocol's layout (parquet-format's `PageHeader`: `0x15` opens i32 field 1, the page type,
/// then `0x15` opens field 2, `uncompressed_page_size`, a zigzag varint), keeping the varint's length so every
/// offset in the file stays right.
#[test]
fn a_page_header_claiming_a_huge_page_is_refused() {
    let (_dir, path) = temp_trace("t.parquet", &["surface"], &samples(1000, 1));
    let mut bytes = std::fs::read(&path).unwrap();
    let metadata = ParquetMetaDataReader::new()
        .parse_and_finish(&Bytes::from(bytes.clone()))
        .unwrap();
    // A page whose uncompressed size takes a two-byte varint and whose compressed size is small: patch its
    // claim to 8191 bytes, the largest two-byte value (zigzag 16382 = 0xFE 0x7F).
    let mut patched = None;
    for column in metadata.row_group(0).columns() {
        let at = column.byte_range().0 as usize;
        let h: [u8; 8] = bytes[at..at + 8].try_into().unwrap();
        let two_byte_claim = h[0] == 0x15 && h[2] == 0x15 && h[3] >= 0x80 && h[4] < 0x80;
        // Field 3, compressed_page_size, a one-byte varint: under 64 bytes.
        if two_byte_claim && h[5] == 0x15 && h[6] < 0x80 {
            bytes[at + 3] = 0xFE;
            bytes[at + 4] = 0x7F;
            patched = Some((at, u64::from(h[6] >> 1)));
            break;
        }
    }
    let (at, compressed) = patched.expect("a small page with a two-byte size in the test trace");
    std::fs::write(&path, &bytes).unwrap();
    let error = read_trace_as(&path, TraceFormat::Parquet)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains(&format!(
            "page at offset {at}: its header claims 8191 uncompressed bytes from {compressed} compressed"
        )),
        "{error}"
    );
}

/// A trace cut off before its final footer streams batch by batch like a finished one: the same samples,
/// handed over one at a time, and the same warning as the whole read.
#[test]
fn a_cut_off_file_streams_its_complete_row_groups() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let written = samples(3500, 1);
    write_and_crash(&path, &written); // three one-second row groups on disk, no final footer
    let mut streamed = Vec::new();
    let (trace, count) =
        crate::parquet_read::for_each_parquet_sample(&path, &mut |s| streamed.push(*s)).unwrap();
    assert_eq!(count, 3000);
    assert_eq!(streamed[..], written[..3000]);
    assert!(trace.samples.is_empty());
    assert!(
        trace.warnings[0].contains("no final footer"),
        "{:?}",
        trace.warnings
    );
}
