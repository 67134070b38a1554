//! Tests of [`super`]: the streamed reader against the samples written, and against the in-memory reader
//! (which the mcap crate parses) on the same files, whole and cut at many places.

use super::*;
use crate::mcap_read::parse_mcap_trace;
use crate::mcap_trace::McapTraceWriter;
use crate::test_support::{meta, samples, temp_trace};
use crate::{read_trace_as, TraceFormat, TraceWriter};

fn streamed(path: &Path) -> Result<(Trace, Vec<TraceSample>), TraceReadError> {
    let mut read = Vec::new();
    let (trace, count) = stream_mcap_samples(path, &mut |sample| read.push(*sample))?;
    assert_eq!(count, read.len() as u64);
    Ok((trace, read))
}

/// Writes `data` and leaves the file as a kill leaves it after a flush.
fn write_and_kill(path: &Path, modes: &[&str], data: &[TraceSample]) {
    let mut writer = McapTraceWriter::create(path, &meta(modes)).unwrap();
    for sample in data {
        writer.write_sample(sample).unwrap();
    }
    writer.flush().unwrap();
    std::mem::forget(writer);
}

#[test]
fn a_finished_file_streams_the_samples_written() {
    // Several chunks: the writer closes one every 1 000 ticks.
    let data = samples(3500, 2);
    let (_dir, path) = temp_trace("t.mcap", &["surface", "friction"], &data);
    let (trace, read) = streamed(&path).unwrap();
    assert_eq!(read, data);
    assert_eq!(trace.mode_names, ["surface", "friction"]);
    assert!(trace.warnings.is_empty(), "{:?}", trace.warnings);
    let whole = read_trace_as(&path, TraceFormat::Mcap).unwrap();
    assert_eq!(whole.samples, read);
    assert_eq!(whole.warnings, trace.warnings);
}

#[test]
fn an_unfinished_file_streams_what_the_in_memory_reader_recovers_with_its_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.mcap");
    let data = samples(2500, 1);
    write_and_kill(&path, &["surface"], &data);
    let (trace, read) = streamed(&path).unwrap();
    let whole = read_trace_as(&path, TraceFormat::Mcap).unwrap();
    assert_eq!(read, whole.samples);
    assert_eq!(read[..], data[..read.len()]);
    assert!(read.len() >= 2000, "{} samples", read.len());
    assert_eq!(trace.warnings, whole.warnings);
    assert!(
        trace.warnings[0].contains("the file was not finished"),
        "{:?}",
        trace.warnings
    );
}

/// Cut anywhere (a crash at any byte), the streamed reader reads exactly the samples the in-memory reader
/// reads, or fails where it fails.
#[test]
fn cut_anywhere_the_streamed_reader_agrees_with_the_in_memory_reader() {
    let data = samples(1500, 2);
    let (dir, full) = temp_trace("full.mcap", &["surface", "friction"], &data);
    let bytes = std::fs::read(&full).unwrap();
    let cut_path = dir.path().join("cut.mcap");
    let mut compared = 0;
    let mut read_some = 0;
    for cut in (0..bytes.len())
        .step_by(bytes.len() / 600)
        .chain(bytes.len() - 20..bytes.len())
    {
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        let memory = parse_mcap_trace(&bytes[..cut]);
        let stream = streamed(&cut_path);
        match (&memory, &stream) {
            (Ok((_, expected)), Ok((_, read))) => {
                assert_eq!(read, expected, "cut at {cut}");
                read_some += usize::from(!read.is_empty());
            }
            (Err(_), Err(_)) => {}
            _ => panic!(
                "cut at {cut} of {}: in memory {:?}, streamed {:?}",
                bytes.len(),
                memory.map(|(_, s)| s.len()),
                stream.map(|(_, s)| s.len())
            ),
        }
        compared += 1;
    }
    assert!(
        compared > 600 && read_some > 300,
        "{compared} cuts, {read_some} with samples"
    );
}

#[test]
fn a_damaged_length_is_an_error_naming_it_not_an_allocation() {
    let (_dir, path) = temp_trace("t.mcap", &["surface"], &samples(50, 1));
    let mut bytes = std::fs::read(&path).unwrap();
    // The first record's length (after the 8-byte magic and its opcode) claims far more than the file holds.
    bytes[9..17].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let error = streamed(&path).unwrap_err().to_string();
    assert!(error.contains("claims"), "{error}");
    std::fs::write(&path, b"not an mcap file").unwrap();
    let error = streamed(&path).unwrap_err().to_string();
    assert!(error.contains("not an MCAP file"), "{error}");
}
