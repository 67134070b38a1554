//! Tests of [`super`].

use super::*;
use crate::mcap_read::*;
use crate::test_support::{meta, samples};
use crate::{read_trace, read_trace_as};

/// Wall-clock time of the first sample in the tests' traces (2023-11-14T22:13:20Z).
const WALL_START_NS: u64 = 1_700_000_000_000_000_000;

fn write_mcap(path: &Path, modes: &[&str], data: &[TraceSample]) {
    let mut writer: Box<dyn TraceWriter> =
        Box::new(McapTraceWriter::create_at(path, &meta(modes), WALL_START_NS).unwrap());
    for (i, sample) in data.iter().enumerate() {
        writer.write_sample(sample).unwrap();
        if i == data.len() / 2 {
            writer.flush().unwrap();
        }
    }
    assert_eq!(writer.finish().unwrap().sample_count, data.len() as u64);
    assert!(matches!(writer.finish(), Err(TraceError::Finished)));
}

/// A new temporary folder holding the MCAP trace `name` of `data`, written by [`write_mcap`], and the file's
/// bytes (the folder goes when the returned guard is dropped).
fn temp_mcap(
    name: &str,
    modes: &[&str],
    data: &[TraceSample],
) -> (tempfile::TempDir, PathBuf, Vec<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    write_mcap(&path, modes, data);
    let bytes = std::fs::read(&path).unwrap();
    (dir, path, bytes)
}

#[test]
fn log_times_start_now_for_a_live_trace_and_at_a_set_creation_time_otherwise() {
    assert_eq!(parse_utc_seconds("1970-01-01T00:00:00Z"), Some(0));
    assert_eq!(parse_utc_seconds("2000-03-01T00:00:01Z"), Some(951_868_801));
    assert_eq!(
        parse_utc_seconds("2023-11-14T22:13:20.5Z"),
        Some(1_700_000_000)
    );
    assert_eq!(parse_utc_seconds("2023-13-14T22:13:20Z"), None);
    assert_eq!(parse_utc_seconds("yesterday"), None);
    let set = meta(&["surface"]); // created 2000-01-01T00:00:00Z
    let now = 1_700_000_000_123_456_789;
    assert_eq!(log_time_start_ns(&set, now), 946_684_800_000_000_000);
    let live = TraceMeta {
        created_utc: "2023-11-14T22:13:20Z".to_owned(),
        ..set.clone()
    };
    assert_eq!(log_time_start_ns(&live, now), now);
    let odd = TraceMeta {
        created_utc: "not a time".to_owned(),
        ..set
    };
    assert_eq!(log_time_start_ns(&odd, now), now);
}

#[test]
fn write_then_read_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let data = samples(250, 3);
    let path = dir.path().join("run.mcap");
    write_mcap(&path, &["surface", "friction", "vortex"], &data);
    let trace = read_trace(&path).unwrap();
    assert_eq!(trace.mode_names, ["surface", "friction", "vortex"]);
    assert_eq!(trace.samples.len(), data.len());
    for (read, written) in trace.samples.iter().zip(&data) {
        assert_eq!(read, written, "tick {}", written.tick);
        assert_eq!(read.probe_m.z.to_bits(), written.probe_m.z.to_bits());
    }
    assert!(trace.sidecar.unwrap().complete);
}

#[test]
fn log_times_are_wall_clock_from_the_first_tick_and_voxhap_schemas_are_json() {
    let data = samples(20, 1);
    let (_dir, _, bytes) = temp_mcap("t.mcap", &["surface"], &data);
    let mut count = 0;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let index = message.sequence as usize;
        let since_first_ns = ((data[index].t_s - data[0].t_s) * 1e9).round() as u64;
        assert_eq!(message.log_time, WALL_START_NS + since_first_ns);
        if ![STATE_TOPIC, SOLVER_TOPIC].contains(&message.channel.topic.as_str()) {
            continue;
        }
        assert_eq!(message.channel.message_encoding, "json");
        let schema = message.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "jsonschema");
        let _: serde_json::Value = serde_json::from_slice(&schema.data).unwrap();
        count += 1;
    }
    assert_eq!(count, 2 * data.len());
}

#[test]
fn foxglove_topics_carry_every_tick_with_sdk_schemas() {
    use ::foxglove::Decode;
    let data = samples(30, 2);
    let (_dir, path, bytes) = temp_mcap("f.mcap", &["surface", "friction"], &data);
    let (mut probes, mut proxies, mut forces) = (Vec::new(), Vec::new(), Vec::new());
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let topic = message.channel.topic.as_str();
        let schema = message.channel.schema.as_ref().map(|s| s.name.as_str());
        let sample = &data[message.sequence as usize];
        match topic {
            PROBE_TOPIC | PROXY_TOPIC => {
                assert_eq!(schema, Some("foxglove.FrameTransform"));
                assert_eq!(message.channel.message_encoding, "protobuf");
                let transform = FrameTransform::decode(&message.data[..]).unwrap();
                assert_eq!(transform.timestamp.unwrap().total_nanos(), message.log_time);
                assert_eq!(transform.parent_frame_id, "world");
                let expected = if topic == PROBE_TOPIC {
                    assert_eq!(transform.child_frame_id, "probe");
                    sample.probe_m
                } else {
                    assert_eq!(transform.child_frame_id, "proxy");
                    sample.proxy_m
                };
                assert_eq!(transform.translation, Some(vector3(expected)));
                if topic == PROBE_TOPIC {
                    probes.push(sample.tick);
                } else {
                    proxies.push(sample.tick);
                }
            }
            FORCE_TOPIC => {
                assert_eq!(schema, Some("foxglove.Vector3"));
                let force = Vector3::decode(&message.data[..]).unwrap();
                assert_eq!(force, vector3(sample.sent_force_n));
                forces.push(sample.tick);
            }
            _ => {}
        }
    }
    let ticks: Vec<u64> = data.iter().map(|s| s.tick).collect();
    assert_eq!(probes, ticks);
    assert_eq!(proxies, ticks);
    assert_eq!(forces, ticks);
    // voxhap's own reader ignores the extra topics.
    assert_eq!(
        read_trace_as(&path, TraceFormat::Mcap).unwrap().samples,
        data
    );
}

#[test]
fn truncated_or_foreign_files_give_errors() {
    let data = samples(50, 1);
    let (dir, _, bytes) = temp_mcap("t.mcap", &["surface"], &data);
    // Cut in half (a crash): read up to the last complete chunk, with a warning.
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let partial = read_trace_as(&cut, TraceFormat::Mcap).unwrap();
    assert_eq!(partial.warnings.len(), 1, "{:?}", partial.warnings);
    assert!(partial.warnings[0].contains("trace repair"));
    assert!(!partial.samples.is_empty() && partial.samples.len() < data.len());
    assert_eq!(partial.samples[..], data[..partial.samples.len()]);

    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, mcap::MAGIC).unwrap();
    assert!(read_trace_as(&empty, TraceFormat::Mcap).is_err());
}

/// A writer that dies without finishing (SIGKILL) leaves every flushed chunk readable, by voxhap and
/// (after `voxhap trace repair`) as a finished file.
#[test]
fn a_killed_writer_leaves_its_flushed_chunks_readable_and_repairable() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.mcap");
    let data = samples(300, 2);
    let mut writer = McapTraceWriter::create(&path, &meta(&["surface", "friction"])).unwrap();
    for (i, sample) in data.iter().enumerate() {
        writer.write_sample(sample).unwrap();
        if i == 199 {
            writer.flush().unwrap();
        }
    }
    // As a kill would: no finish, no destructor.
    std::mem::forget(writer);
    let trace = read_trace_as(&path, TraceFormat::Mcap).unwrap();
    assert_eq!(trace.samples, data[..200]);
    assert_eq!(trace.warnings.len(), 1);
    let repaired = dir.path().join("repaired.mcap");
    let report =
        crate::repair::repair_trace(&path, &repaired, None, &crate::OutputPolicy::default())
            .unwrap();
    assert_eq!(report.sample_count, 200);
    let fixed = read_trace_as(&repaired, TraceFormat::Mcap).unwrap();
    assert!(fixed.warnings.is_empty());
    assert_eq!(fixed.samples, data[..200]);
    let sidecar = fixed.sidecar.unwrap();
    assert!(sidecar.complete);
    assert!(sidecar.repaired.unwrap().contains("recovered 200 samples"));
    // The input is never the output, even when asked to overwrite.
    let err = crate::repair::repair_trace(
        &path,
        &path,
        None,
        &crate::OutputPolicy {
            overwrite: true,
            inputs: Vec::new(),
        },
    )
    .unwrap_err();
    assert!(crate::error_chain(&err).contains("is an input"));
}

/// A crash can cut a tick in two. Besides every flush, the mcap writer closes a chunk when it passes its size
/// limit (1 MiB), which may fall between one tick's messages; a kill before the next chunk is complete
/// leaves the first part of that tick alone. Cut at every chunk's end (and a little past it, into the next
/// record), an unfinished file reads as a prefix of the samples, whole ticks only. (Regression: a
/// killed `voxhap sim` read as "6772 state messages but 6771 solver messages".)
#[test]
fn an_unfinished_file_cut_after_any_chunk_reads_whole_ticks() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("long.mcap");
    let data = samples(6000, 1);
    let mut writer = McapTraceWriter::create(&path, &meta(&["surface"])).unwrap();
    for sample in &data {
        writer.write_sample(sample).unwrap();
    }
    writer.flush().unwrap();
    std::mem::forget(writer);
    let bytes = std::fs::read(&path).unwrap();
    // The ends of the top-level chunk records (opcode 0x06) after the metadata record (0x0C, which names
    // the trace; the writer puts it after the first chunk): opcode, u64 length, body.
    let mut metadata_seen = false;
    let mut chunk_ends = Vec::new();
    let mut at = mcap::MAGIC.len();
    while at + 9 <= bytes.len() {
        let length = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        let next = at + 9 + length;
        if next > bytes.len() {
            break;
        }
        metadata_seen |= bytes[at] == 0x0C;
        if bytes[at] == 0x06 && metadata_seen {
            chunk_ends.push(next);
        }
        at = next;
    }
    assert!(chunk_ends.len() >= 3, "{} chunks", chunk_ends.len());
    let mut lengths = Vec::new();
    for &end in &chunk_ends {
        for cut in [end, end + 5, end + 100] {
            let (_, read) = parse_mcap_trace(&bytes[..cut.min(bytes.len())])
                .unwrap_or_else(|e| panic!("cut at {cut} of {}: {e}", bytes.len()));
            assert_eq!(read[..], data[..read.len()], "cut at {cut}");
            lengths.push(read.len());
        }
    }
    assert!(lengths.windows(2).all(|w| w[0] <= w[1]), "{lengths:?}");
    assert!(*lengths.last().unwrap() > data.len() / 2, "{lengths:?}");
}

/// Regression: a record inside an uncompressed chunk claiming more bytes than the chunk holds made
/// the mcap crate panic (subtract overflow); it must be an error.
#[test]
fn record_longer_than_its_chunk_is_an_error_not_a_panic() {
    let (_dir, path, mut bytes) = temp_mcap("m.mcap", &["surface"], &samples(8, 1));
    overlong_record_in_first_chunk(&mut bytes);
    std::fs::write(&path, &bytes).unwrap();
    assert!(read_trace_as(&path, TraceFormat::Mcap).is_err());
}

/// Regression (fuzz target mcap_trace): a string length inside a record claiming gigabytes made the mcap
/// crate reserve them; every length-prefixed field is checked against its record first.
#[test]
fn a_string_longer_than_its_record_is_an_error_not_an_allocation() {
    let (_dir, _, mut bytes) = temp_mcap("m.mcap", &["surface"], &samples(8, 1));
    // The header record's first field, the profile string: its u32 length.
    let at = mcap::MAGIC.len() + 9;
    bytes[at..at + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    let message = parse_mcap_trace(&bytes).unwrap_err().to_string();
    assert!(
        message.contains("a record's field runs past the record"),
        "{message}"
    );
}

/// Makes the first record inside the first chunk claim more bytes than the chunk holds, and clears the
/// chunk's CRC (0 = not checked), so the reader reaches the overlong record. Found by the proptest
/// below as a one-byte edit; written out here so it does not depend on the file's layout.
fn overlong_record_in_first_chunk(bytes: &mut [u8]) {
    let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let u32_at = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let mut at = mcap::MAGIC.len();
    while bytes[at] != 0x06 {
        at += 9 + u64_at(bytes, at + 1) as usize;
    }
    // Chunk: start time, end time, uncompressed size, CRC, compression string, records byte array.
    let content = at + 9;
    let crc_at = content + 24;
    bytes[crc_at..crc_at + 4].fill(0);
    let compression_len = u32_at(bytes, crc_at + 4) as usize;
    assert_eq!(compression_len, 0, "the writer leaves chunks uncompressed");
    let records_len_at = crc_at + 8;
    let records_len = u64_at(bytes, records_len_at);
    let first_record = records_len_at + 8;
    bytes[first_record + 1..first_record + 9].copy_from_slice(&(records_len + 118).to_le_bytes());
}

/// The edit above still breaks the mcap crate's reader (so the regression test tests something).
#[test]
fn the_overlong_record_edit_makes_the_mcap_crate_fail() {
    let (_dir, _, mut bytes) = temp_mcap("m.mcap", &["surface"], &samples(8, 1));
    overlong_record_in_first_chunk(&mut bytes);
    let outcome = std::panic::catch_unwind(|| {
        mcap::MessageStream::new(&bytes).map(|stream| {
            stream
                .map(|m| m.map(|_| ()))
                .collect::<Result<Vec<()>, _>>()
        })
    });
    // mcap 0.26 panics here (subtract overflow); a fixed version may return an error instead.
    assert!(
        !matches!(outcome, Ok(Ok(Ok(_)))),
        "the edited file reads cleanly"
    );
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
    /// A valid MCAP trace with bytes overwritten never panics the reader.
    #[test]
    fn mutated_mcap_never_panics(
        edits in proptest::collection::vec((0usize..100_000, proptest::prelude::any::<u8>()), 1..6)
    ) {
        let (_dir, path, mut bytes) = temp_mcap("m.mcap", &["surface"], &samples(8, 1));
        for (position, byte) in edits {
            let at = position % bytes.len();
            bytes[at] = byte;
        }
        std::fs::write(&path, &bytes).unwrap();
        let _ = read_trace_as(&path, TraceFormat::Mcap);
    }
}

/// Lichtblick's and Foxglove Studio's JSON-schema reader (`parseJsonSchema` in their `mcap-support`
/// package), rule for rule: the root and every nested object is `"type": "object"` with `properties`; a
/// field's `type` is one of boolean, string, number, integer, object, array (one string: a list such as
/// `["number", "null"]` or a missing type is refused, which drops the whole topic); an array's `items` has
/// one of boolean, string, number, integer, object. Returns the first problem.
pub(crate) fn viewer_refuses(schema: &serde_json::Value, path: &str) -> Option<String> {
    if schema["type"] != "object" {
        return Some(format!(
            "{path}: \"type\" is {} (not \"object\")",
            schema["type"]
        ));
    }
    let Some(properties) = schema["properties"].as_object() else {
        return Some(format!("{path}: an object without \"properties\""));
    };
    for (name, field) in properties {
        let at = format!("{path}.{name}");
        match field["type"].as_str() {
            Some("boolean" | "string" | "number" | "integer") => {}
            Some("object") => {
                if let Some(problem) = viewer_refuses(field, &at) {
                    return Some(problem);
                }
            }
            Some("array") => match field["items"]["type"].as_str() {
                Some("boolean" | "string" | "number" | "integer") => {}
                Some("object") => {
                    if let Some(problem) = viewer_refuses(&field["items"], &at) {
                        return Some(problem);
                    }
                }
                _ => return Some(format!("{at}: array item type {}", field["items"]["type"])),
            },
            _ => return Some(format!("{at}: field type {}", field["type"])),
        }
    }
    None
}

#[test]
fn the_viewer_rule_refuses_what_lichtblick_refuses() {
    let ok = serde_json::json!({"type": "object", "properties": {"a": {"type": "number"}}});
    assert_eq!(viewer_refuses(&ok, "t"), None);
    for field in [
        serde_json::json!({"type": ["number", "null"]}),
        serde_json::json!({"enum": ["a", "b"]}),
        serde_json::json!({"type": "array", "items": {"type": ["integer", "null"]}}),
        serde_json::json!({"type": "null"}),
    ] {
        let schema = serde_json::json!({"type": "object", "properties": {"a": field}});
        assert!(viewer_refuses(&schema, "t").is_some(), "{schema}");
    }
}

/// Foxglove Studio and the `@mcap/core` Lichtblick pins stop on a chunk without a message index ("Chunks
/// without message indexes are not currently supported") and take the smallest chunk start time as the
/// recording's start: every chunk must hold messages, with their index, and start at its first message;
/// the statistics' start and end are the first and last message's log times. Every JSON schema passes the
/// viewers' reader. Without the fix (metadata written after the channels) the first chunk held only the
/// schemas and channels, with start time 0.
#[test]
fn every_chunk_holds_indexed_messages_and_the_times_are_the_messages_times() {
    let data = samples(300, 2);
    let (_dir, _, bytes) = temp_mcap("v.mcap", &["surface", "friction"], &data);
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert!(
        summary.chunk_indexes.len() >= 2,
        "{}",
        summary.chunk_indexes.len()
    );
    let log_times: Vec<u64> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap().log_time)
        .collect();
    let (first, last) = (log_times[0], *log_times.last().unwrap());
    assert_eq!(first, WALL_START_NS);
    for chunk in &summary.chunk_indexes {
        assert!(!chunk.message_index_offsets.is_empty(), "{chunk:?}");
        assert!(chunk.message_start_time >= first, "{chunk:?}");
        assert!(chunk.message_end_time <= last, "{chunk:?}");
    }
    assert_eq!(summary.chunk_indexes[0].message_start_time, first);
    let stats = summary.stats.unwrap();
    assert_eq!(
        (stats.message_start_time, stats.message_end_time),
        (first, last)
    );
    assert_eq!(stats.message_count, log_times.len() as u64);
    for schema in summary.schemas.values() {
        if schema.encoding == "jsonschema" {
            let value: serde_json::Value = serde_json::from_slice(&schema.data).unwrap();
            assert_eq!(viewer_refuses(&value, &schema.name), None);
        }
    }
}

/// A recording stopped before its first sample has no chunk at all (not one without messages).
#[test]
fn a_trace_without_samples_has_no_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.mcap");
    let mut writer = McapTraceWriter::create_at(&path, &meta(&["surface"]), WALL_START_NS).unwrap();
    writer.flush().unwrap();
    assert_eq!(writer.finish().unwrap().sample_count, 0);
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert!(
        summary.chunk_indexes.is_empty(),
        "{:?}",
        summary.chunk_indexes
    );
    assert_eq!(summary.stats.unwrap().metadata_count, 1);
}

/// A recording made before the force topic's rename (`/voxhap/servo_cf`, now `/voxhap/setpoint_cf`) reads as
/// the same recording with the new name: the file below is the test's recording with only that channel's topic
/// changed.
#[test]
fn a_recording_with_the_old_force_topic_name_reads_the_same() {
    use voxhap_view::topics::{SERVO_CF_TOPIC, SETPOINT_CF_TOPIC};
    let data = samples(50, 1);
    let (dir, _, bytes) = temp_mcap("new.mcap", &["surface"], &data);
    let old = dir.path().join("old.mcap");
    let file = std::io::BufWriter::new(std::fs::File::create(&old).unwrap());
    let mut writer = mcap::Writer::new(file).unwrap();
    for record in mcap::read::LinearReader::new(&bytes).unwrap() {
        if let mcap::records::Record::Metadata(metadata) = record.unwrap() {
            writer.write_metadata(&metadata).unwrap();
        }
    }
    let mut renamed = 0;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let mut message = message.unwrap();
        if message.channel.topic == SETPOINT_CF_TOPIC {
            let mut channel = (*message.channel).clone();
            channel.topic = SERVO_CF_TOPIC.to_owned();
            message.channel = std::sync::Arc::new(channel);
            renamed += 1;
        }
        writer.write(&message).unwrap();
    }
    writer.finish().unwrap();
    assert_eq!(renamed, data.len());
    assert_eq!(
        read_trace_as(&old, TraceFormat::Mcap).unwrap().samples,
        data
    );
}
