//! What depends on the trace format: creating a writer ([`create_trace_writer`]), reading any trace back
//! ([`read_trace`], chosen by the file's first bytes, or [`read_trace_as`] a given format) and estimating a
//! trace's size ([`estimate_trace_bytes`]).

use crate::csv::{for_each_csv_sample, CsvTraceWriter};
use crate::error::{TraceError, TraceReadError};
use crate::mcap_read::for_each_mcap_sample;
use crate::mcap_trace::McapTraceWriter;
use crate::meta::TraceMeta;
use crate::output::{self, check_output_path, OutputPolicy};
use crate::parquet_read::for_each_parquet_sample;
use crate::parquet_trace::ParquetTraceWriter;
use crate::trace::{collect_samples, open_trace_file, ForEachSample, Trace};
use crate::writer::TraceWriter;
use std::path::Path;
use voxhap_api::TraceFormat;

/// Creates `path` (and `path.json`) in `format` for a run described by `meta`, refusing to replace an
/// existing file ([`create_trace_writer_with`] with [`OutputPolicy::default`]).
pub fn create_trace_writer(
    path: &Path,
    format: TraceFormat,
    meta: &TraceMeta,
) -> Result<Box<dyn TraceWriter>, TraceError> {
    create_trace_writer_with(path, format, meta, &OutputPolicy::default())
}

/// Creates `path` (and `path.json`) in `format` for a run described by `meta`, after checking `policy`:
/// an existing trace or sidecar is replaced only with `policy.overwrite` (removed, then created anew), a
/// file that is one of `policy.inputs` never is, and a symlink is never followed (see `output`).
pub fn create_trace_writer_with(
    path: &Path,
    format: TraceFormat,
    meta: &TraceMeta,
    policy: &OutputPolicy,
) -> Result<Box<dyn TraceWriter>, TraceError> {
    check_output_path(path, policy)?;
    if policy.overwrite {
        output::remove_replaced(path)?;
    }
    Ok(match format {
        TraceFormat::Csv => Box::new(CsvTraceWriter::create(path, meta)?),
        TraceFormat::Mcap => Box::new(McapTraceWriter::create(path, meta)?),
        TraceFormat::Parquet => Box::new(ParquetTraceWriter::create(path, meta)?),
    })
}

/// Reads a CSV, MCAP or Parquet trace, choosing by the file's first bytes ([`sniff_format`]) rather than its
/// name.
pub fn read_trace(path: &Path) -> Result<Trace, TraceReadError> {
    read_trace_as(path, sniff_format(path)?)
}

/// Reads the trace at `path` as `format`, whatever its first bytes say, and its sidecar `path.json` when that
/// file exists. A regular file only; a file cut off by a crash is read up to its last complete part (CSV
/// line, MCAP chunk, Parquet row group), with a warning.
pub fn read_trace_as(path: &Path, format: TraceFormat) -> Result<Trace, TraceReadError> {
    let for_each: ForEachSample = match format {
        TraceFormat::Csv => for_each_csv_sample,
        TraceFormat::Mcap => for_each_mcap_sample,
        TraceFormat::Parquet => for_each_parquet_sample,
    };
    collect_samples(path, for_each)
}

/// A trace's format from its first bytes: the MCAP magic, `PAR1` (Parquet), else CSV.
pub(crate) fn sniff_format(path: &Path) -> Result<TraceFormat, TraceReadError> {
    use std::io::Read;
    let (file, _) = open_trace_file(path)?;
    let mut magic = Vec::with_capacity(8);
    file.take(8)
        .read_to_end(&mut magic)
        .map_err(|source| TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(if magic[..] == *mcap::MAGIC {
        TraceFormat::Mcap
    } else if magic.starts_with(b"PAR1") {
        TraceFormat::Parquet
    } else {
        TraceFormat::Csv
    })
}

/// A generous estimate of the bytes a trace of `ticks` samples at `rate_hz` with `mode_count` modes takes
/// in `format` (the sidecar not included). Measured row sizes with margin: CSV writes shortest round-trip
/// floats (up to 24 characters each), MCAP five messages per tick plus the scene topics
/// ([`crate::foxglove_scene::recorded_scene_bytes`]: slices, scene updates, the volume picture).
pub fn estimate_trace_bytes(
    format: TraceFormat,
    mode_count: usize,
    ticks: u64,
    rate_hz: f64,
) -> u64 {
    let per_tick: u64 = match format {
        // 23 float columns + 4 per mode at up to 24 bytes, integers, status, 12 flags at 6 bytes.
        TraceFormat::Csv => 23 * 24 + mode_count as u64 * (4 * 24) + 60 + 12 * 6,
        // JSON state and solver messages plus three protobuf messages and their record headers.
        TraceFormat::Mcap => 900 + mode_count as u64 * 90,
        // Uncompressed column values (8 bytes per number) plus row-group footers; Snappy makes it smaller.
        TraceFormat::Parquet => 23 * 8 + mode_count as u64 * (4 * 8) + 60 + 17,
    };
    let scene = match format {
        // Only MCAP carries the Foxglove scene topics.
        TraceFormat::Csv | TraceFormat::Parquet => 0,
        TraceFormat::Mcap => {
            crate::foxglove_scene::recorded_scene_bytes(ticks as f64 / rate_hz, mode_count)
        }
    };
    4096u64
        .saturating_add(per_tick.saturating_mul(ticks))
        .saturating_add(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{samples, temp_trace, write_trace};

    #[test]
    fn two_identical_runs_give_identical_files() {
        let data = samples(300, 2);
        for format in [TraceFormat::Csv, TraceFormat::Mcap] {
            let (a_name, b_name) = (format!("a.{format}"), format!("b.{format}"));
            let (dir, a) = temp_trace(&a_name, &["surface", "viscosity"], &data);
            let b = dir.path().join(&b_name);
            write_trace(&b, &["surface", "viscosity"], &data);
            assert_eq!(
                std::fs::read(&a).unwrap(),
                std::fs::read(&b).unwrap(),
                "{format}"
            );
            // The sidecars differ only in the trace file name.
            let sa = std::fs::read_to_string(output::sidecar_path(&a)).unwrap();
            let sb = std::fs::read_to_string(output::sidecar_path(&b)).unwrap();
            assert_eq!(sa.replace(&a_name, &b_name), sb, "{format}");
        }
    }

    #[test]
    fn estimates_grow_with_ticks_and_modes() {
        let small = estimate_trace_bytes(TraceFormat::Csv, 1, 1000, 1000.0);
        assert!(small > 1000 * 500);
        assert!(estimate_trace_bytes(TraceFormat::Csv, 3, 1000, 1000.0) > small);
        // 1e9 Hz for 60 s would be hundreds of GB: far over a 2 GB limit.
        assert!(estimate_trace_bytes(TraceFormat::Mcap, 1, 60_000_000_000, 1e9) > 2_000_000_000);
        // The scene topics are per second, not per tick: the same ticks at a tenth of the rate last ten
        // times as long and carry ten times the slices.
        let fast = estimate_trace_bytes(TraceFormat::Mcap, 1, 10_000, 1000.0);
        assert!(estimate_trace_bytes(TraceFormat::Mcap, 1, 10_000, 100.0) > fast + 9 * 390_000);
    }
}
