//! Parquet force traces: the writer ([`ParquetTraceWriter`]) and the reader ([`read_parquet_trace`]).
//!
//! Where it sits: one of the three trace formats behind [`crate::writer::TraceWriter`] (chosen by a `.parquet`
//! name or `--format parquet`). The columns are `crate::columns::columns`, the same names, order and
//! values as CSV, with Parquet types: `UInt64` counts and ticks, `Int64` `utc_ns` (null when `t_s` is not
//! finite), `Float64` quantities (NaN and infinities kept), `Boolean` flag columns, a UTF-8
//! `solver_status`, and nullable `UInt64` device sequence and time. The finished file's metadata holds
//! the sidecar's JSON under the key [`SIDECAR_KEY`], so a Parquet trace describes itself even without its
//! `TRACE.json`. Pages are Snappy-compressed (what pandas and pyarrow write by default).
//!
//! Crash safety: rows are buffered and written as one row group per second of trace time (at most
//! [`ROW_GROUP_MAX_ROWS`] rows, and at most about one second of wall-clock time when the recorder
//! flushes), so a crash loses at most the last second. A Parquet reader needs the footer, which is only
//! written at the end; so after every row group the writer also writes a *row-group footer*: a Parquet
//! footer (metadata, length) that describes only that row group, ending in `VXRG` instead of `PAR1` so
//! no reader mistakes a cut-off file for a finished one holding only its last row group. Readers ignore
//! bytes between row groups. A file cut off by a crash ends without the final footer; [`read_parquet_trace`]
//! then finds the last row-group footer whose row group ends exactly where the footer starts, follows
//! the chain back to the first row group (each row group starts right after the previous one's footer),
//! reads those row groups, and reports what it skipped in `Trace::warnings`. `voxhap trace repair`
//! uses that to write a finished file.
//!
//! Compaction: one-second row groups cost readers time (pyarrow reads 3 600 of them about 2.5 times
//! slower than a few large ones) and space. So a trace that finishes cleanly is rewritten once, into a
//! temporary file next to it, with row groups of up to [`COMPACT_ROW_GROUP_ROWS`] rows, and renamed over
//! the original; a crash during that leaves the original (and perhaps the temporary file) intact.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use arrow_array::builder::{
    BooleanBuilder, Float64Builder, Int64Builder, StringBuilder, UInt64Builder,
};
use arrow_array::{
    Array, ArrayRef, BooleanArray, Float64Array, Int64Array, RecordBatch, StringArray, UInt64Array,
};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use bytes::Bytes;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReaderBuilder,
};
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::metadata::{
    FileMetaData, KeyValue, ParquetMetaData, ParquetMetaDataReader, ParquetMetaDataWriter,
    RowGroupMetaData,
};
use parquet::file::properties::WriterProperties;

use crate::columns::{cells, columns, sample_from_cells, Cell, ColumnType, PRIMITIVES_PREFIX};
use crate::csv::read_sidecar;
use crate::error::{TraceError, TraceReadError};
use crate::meta::is_valid_mode_name;
use crate::meta::{Sidecar, TraceMeta, TraceSummary};
use crate::output::sidecar_path;
use crate::output::{OutputFile, StopSwitch};
use crate::sample::{check_sample, SampleChecker, SolverStatus, TraceSample};
use crate::trace::Trace;
use crate::writer::TraceWriter;
use voxhap_api::TraceFormat;
use voxhap_core::haptics::modes::MAX_MODES;

/// The file-metadata key holding the sidecar's JSON (the final sidecar, in a finished file).
pub const SIDECAR_KEY: &str = "voxhap.sidecar";
/// A row group holds at most this much trace time (s): a crash loses at most this.
pub const ROW_GROUP_MAX_SPAN_S: f64 = 1.0;
/// A row group holds at most this many rows (bounds memory at very high rates).
pub const ROW_GROUP_MAX_ROWS: usize = 100_000;
/// A finished trace is rewritten with row groups of up to this many rows (fewer, larger row groups load
/// several times faster and compress better).
pub const COMPACT_ROW_GROUP_ROWS: usize = 1 << 20;
/// A flush closes an open row group at least this long after it was opened (wall clock), so a paused or
/// slow producer still loses at most about a second.
const ROW_GROUP_MAX_AGE: Duration = Duration::from_secs(1);
/// `PAR1`, which starts a Parquet file and ends its footer.
const MAGIC: &[u8; 4] = b"PAR1";
/// Ends a row-group footer in place of `PAR1`, so a file cut off after a row-group footer is not taken
/// for a finished file holding only its last row group (pyarrow refuses it; `voxhap trace repair` reads
/// it).
const ROW_GROUP_FOOTER_MAGIC: &[u8; 4] = b"VXRG";

/// A column being filled, one builder per column type.
enum ColumnBuilder {
    U64(UInt64Builder),
    I64(Int64Builder),
    F64(Float64Builder),
    Bool(BooleanBuilder),
    Text(StringBuilder),
}

impl ColumnBuilder {
    fn new(column_type: ColumnType) -> Self {
        match column_type {
            ColumnType::U64 | ColumnType::OptionalU64 => ColumnBuilder::U64(UInt64Builder::new()),
            ColumnType::I64 => ColumnBuilder::I64(Int64Builder::new()),
            ColumnType::F64 => ColumnBuilder::F64(Float64Builder::new()),
            ColumnType::Bool => ColumnBuilder::Bool(BooleanBuilder::new()),
            ColumnType::Text => ColumnBuilder::Text(StringBuilder::new()),
        }
    }

    fn append(&mut self, cell: Cell) {
        match (self, cell) {
            (ColumnBuilder::U64(b), Cell::U64(v)) => b.append_value(v),
            (ColumnBuilder::I64(b), Cell::I64(v)) => b.append_value(v),
            (ColumnBuilder::F64(b), Cell::F64(v)) => b.append_value(v),
            (ColumnBuilder::Bool(b), Cell::Bool(v)) => b.append_value(v),
            (ColumnBuilder::Text(b), Cell::Text(v)) => b.append_value(v),
            (ColumnBuilder::U64(b), _) => b.append_null(),
            (ColumnBuilder::I64(b), _) => b.append_null(),
            (ColumnBuilder::F64(b), _) => b.append_null(),
            (ColumnBuilder::Bool(b), _) => b.append_null(),
            (ColumnBuilder::Text(b), _) => b.append_null(),
        }
    }

    fn finish(&mut self) -> ArrayRef {
        match self {
            ColumnBuilder::U64(b) => Arc::new(b.finish()),
            ColumnBuilder::I64(b) => Arc::new(b.finish()),
            ColumnBuilder::F64(b) => Arc::new(b.finish()),
            ColumnBuilder::Bool(b) => Arc::new(b.finish()),
            ColumnBuilder::Text(b) => Arc::new(b.finish()),
        }
    }
}

/// The Arrow type of a column type, and whether it may be null.
fn arrow_type(column_type: ColumnType) -> (DataType, bool) {
    match column_type {
        ColumnType::U64 => (DataType::UInt64, false),
        ColumnType::OptionalU64 => (DataType::UInt64, true),
        // utc_ns is null when t_s is not finite (only in a sample flagged invalid_values).
        ColumnType::I64 => (DataType::Int64, true),
        ColumnType::F64 => (DataType::Float64, false),
        ColumnType::Bool => (DataType::Boolean, false),
        ColumnType::Text => (DataType::Utf8, false),
    }
}

/// The Arrow schema of a trace with these modes.
fn arrow_schema(mode_names: &[String]) -> SchemaRef {
    let fields: Vec<Field> = columns(mode_names)
        .into_iter()
        .map(|c| {
            let (data_type, nullable) = arrow_type(c.column_type);
            Field::new(c.name.into_owned(), data_type, nullable)
        })
        .collect();
    Arc::new(Schema::new(fields))
}

/// Writes a Parquet trace and its sidecar.
pub struct ParquetTraceWriter {
    path: PathBuf,
    writer: Option<ArrowWriter<BufWriter<OutputFile>>>,
    /// Stops the file at the first failure, so nothing reaches it afterwards.
    stop: StopSwitch,
    /// Rows in row groups whose bytes and footer reached the file: the count the sidecar gives.
    committed_rows: u64,
    schema: SchemaRef,
    builders: Vec<ColumnBuilder>,
    row: Vec<Cell>,
    /// Rows in the open row group, its first sample's time, and when it was opened.
    group_rows: usize,
    group_start_t_s: f64,
    group_opened: Instant,
    checker: SampleChecker,
    start_utc_ns: i64,
    sidecar: Sidecar,
}

impl ParquetTraceWriter {
    /// Creates (truncates) `path` and `path.json` and writes a provisional sidecar. Callers check first
    /// whether the files may be replaced (`create_trace_writer_with`).
    pub fn create(path: &Path, meta: &TraceMeta) -> Result<Self, TraceError> {
        meta.validate()?;
        let stop = StopSwitch::default();
        let file = OutputFile::new(crate::output::create_new_file(path)?, &stop);
        let schema = arrow_schema(&meta.mode_names);
        let properties = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_max_row_group_row_count(Some(ROW_GROUP_MAX_ROWS))
            .set_created_by(format!("voxhap {}", env!("CARGO_PKG_VERSION")))
            .build();
        let writer = ArrowWriter::try_new(
            BufWriter::with_capacity(256 * 1024, file),
            schema.clone(),
            Some(properties),
        )
        .map_err(|source| TraceError::Parquet {
            path: path.to_path_buf(),
            source,
        })?;
        let sidecar = Sidecar::new(meta, TraceFormat::Parquet, path);
        sidecar.write_new(&sidecar_path(path))?;
        let builders = columns(&meta.mode_names)
            .iter()
            .map(|c| ColumnBuilder::new(c.column_type))
            .collect();
        Ok(ParquetTraceWriter {
            path: path.to_path_buf(),
            writer: Some(writer),
            stop,
            committed_rows: 0,
            schema,
            builders,
            row: Vec::with_capacity(128),
            group_rows: 0,
            group_start_t_s: 0.0,
            group_opened: Instant::now(),
            checker: SampleChecker::new(meta.mode_names.len()),
            start_utc_ns: meta.start_utc_ns,
            sidecar,
        })
    }

    fn parquet_error(&self, source: parquet::errors::ParquetError) -> TraceError {
        TraceError::Parquet {
            path: self.path.clone(),
            source,
        }
    }

    fn io_error(&self, source: std::io::Error) -> TraceError {
        TraceError::Io {
            path: self.path.clone(),
            source,
        }
    }

    /// Writes the buffered rows as one row group, then its row-group footer, and hands the bytes to the
    /// file.
    fn close_row_group(&mut self) -> Result<(), TraceError> {
        if self.group_rows == 0 {
            return Ok(());
        }
        let arrays: Vec<ArrayRef> = self
            .builders
            .iter_mut()
            .map(ColumnBuilder::finish)
            .collect();
        let rows = self.group_rows as u64;
        self.group_rows = 0;
        let batch = RecordBatch::try_new(self.schema.clone(), arrays)
            .map_err(|e| self.parquet_error(parquet::errors::ParquetError::from(e)))?;
        let Some(writer) = self.writer.as_mut() else {
            return Err(TraceError::Finished);
        };
        let result = writer
            .write(&batch)
            .and_then(|()| writer.flush())
            .and_then(|()| {
                let group = writer.flushed_row_groups().last().cloned().ok_or_else(|| {
                    parquet::errors::ParquetError::General("no row group was written".into())
                })?;
                let footer = row_group_footer(group)?;
                writer.write_all(&footer)?;
                Ok(())
            });
        result.map_err(|e| self.parquet_error(e))?;
        let sync = self.writer.as_mut().map(|w| w.sync());
        if let Some(Err(e)) = sync {
            return Err(self.io_error(e));
        }
        // The row group and its footer are in the file: a reader recovers them.
        self.committed_rows += rows;
        Ok(())
    }
}

/// Rewrites the finished Parquet file at `path` with row groups of up to [`COMPACT_ROW_GROUP_ROWS`] rows
/// (same schema, values and key-value metadata), through a temporary file renamed over it. A file with one
/// row group or none is left as it is.
fn compact(path: &Path, schema: &SchemaRef) -> Result<(), parquet::errors::ParquetError> {
    let input = File::open(path)?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(input)?;
    if builder.metadata().num_row_groups() <= 1 {
        return Ok(());
    }
    let key_values = builder
        .metadata()
        .file_metadata()
        .key_value_metadata()
        .cloned()
        .unwrap_or_default();
    let reader = builder.with_batch_size(64 * 1024).build()?;
    let mut temporary_name = std::ffi::OsString::from(".");
    temporary_name.push(path.file_name().unwrap_or_default());
    temporary_name.push(format!(".compacting.{}", std::process::id()));
    let temporary = path.with_file_name(temporary_name);
    let result = (|| {
        let output = crate::output::create_new_file(&temporary)
            .map_err(|e| parquet::errors::ParquetError::General(crate::error::error_chain(&e)))?;
        let properties = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_max_row_group_row_count(Some(COMPACT_ROW_GROUP_ROWS))
            .set_created_by(format!("voxhap {}", env!("CARGO_PKG_VERSION")))
            .build();
        let mut writer = ArrowWriter::try_new(
            BufWriter::with_capacity(256 * 1024, output),
            schema.clone(),
            Some(properties),
        )?;
        for batch in reader {
            writer.write(&batch?)?;
        }
        for kv in key_values {
            // The writer adds its own ARROW:schema entry.
            if kv.key != "ARROW:schema" {
                writer.append_key_value_metadata(kv);
            }
        }
        let file = writer
            .into_inner()?
            .into_inner()
            .map_err(|e| parquet::errors::ParquetError::from(e.into_error()))?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// A Parquet footer (metadata, length, [`ROW_GROUP_FOOTER_MAGIC`]) describing only `group`.
fn row_group_footer(group: RowGroupMetaData) -> Result<Vec<u8>, parquet::errors::ParquetError> {
    let file_metadata = FileMetaData::new(
        1,
        group.num_rows(),
        None,
        None,
        group.schema_descr_ptr(),
        None,
    );
    let metadata = ParquetMetaData::new(file_metadata, vec![group]);
    let mut footer = Vec::new();
    ParquetMetaDataWriter::new(&mut footer, &metadata).finish()?;
    let magic_at = footer.len() - MAGIC.len();
    footer[magic_at..].copy_from_slice(ROW_GROUP_FOOTER_MAGIC);
    Ok(footer)
}

impl TraceWriter for ParquetTraceWriter {
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        if self.writer.is_none() {
            return Err(TraceError::Finished);
        }
        let Some(sample) = self.checker.admit(sample)? else {
            return Ok(());
        };
        // A sample more than a second after the group's first closes the group first (a NaN time never
        // does; it is bounded by the row count).
        if self.group_rows > 0
            && (self.group_rows >= ROW_GROUP_MAX_ROWS
                || sample.t_s - self.group_start_t_s >= ROW_GROUP_MAX_SPAN_S)
        {
            self.close_row_group()?;
        }
        if self.group_rows == 0 {
            self.group_start_t_s = sample.t_s;
            self.group_opened = Instant::now();
        }
        self.row.clear();
        cells(
            &sample,
            self.checker.mode_count,
            self.start_utc_ns,
            &mut self.row,
        );
        for (builder, cell) in self.builders.iter_mut().zip(self.row.iter()) {
            builder.append(*cell);
        }
        self.group_rows += 1;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        if self.group_rows > 0 && self.group_opened.elapsed() >= ROW_GROUP_MAX_AGE {
            self.close_row_group()?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<TraceSummary, TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        self.close_row_group()?;
        let Some(mut writer) = self.writer.take() else {
            return Err(TraceError::Finished);
        };
        self.checker.finished = true;
        self.sidecar.samples_rejected = self.checker.rejected;
        // The final sidecar goes into the file's metadata as well.
        let mut final_sidecar = self.sidecar.clone();
        final_sidecar.complete = true;
        final_sidecar.sample_count = self.committed_rows;
        let json = serde_json::to_string(&final_sidecar)
            .map_err(|e| TraceError::Meta(format!("cannot encode the sidecar: {e}")))?;
        writer.append_key_value_metadata(KeyValue::new(SIDECAR_KEY.to_owned(), json));
        let file = writer
            .into_inner()
            .map_err(|e| self.parquet_error(e))?
            .into_inner()
            .map_err(|e| self.io_error(e.into_error()))?;
        file.file().sync_all().map_err(|e| self.io_error(e))?;
        drop(file);
        compact(&self.path, &self.schema).map_err(|e| self.parquet_error(e))?;
        self.sidecar.complete(&self.path, self.committed_rows)
    }

    fn fail(&mut self, error: &str) -> Result<(), TraceError> {
        self.checker.finished = true;
        // Stopped, then dropped without its final footer: nothing buffered reaches the file, and what was
        // written reads back up to the last whole row group, exactly `committed_rows` rows.
        self.stop.stop();
        self.writer = None;
        self.group_rows = 0;
        self.sidecar.samples_rejected = self.checker.rejected;
        self.sidecar.fail(&self.path, self.committed_rows, error)
    }

    fn sample_count(&self) -> u64 {
        self.committed_rows
    }
}

/// Reads a Parquet trace, and its sidecar `path.json` when that file exists. A file without its final
/// footer (cut off by a crash) is read up to its last complete row group, with a warning.
pub fn read_parquet_trace(path: &Path) -> Result<Trace, TraceReadError> {
    let bytes = Bytes::from(crate::trace::read_trace_file(path)?);
    let sidecar = read_sidecar(&sidecar_path(path))?;
    let problem = |problem: String| TraceReadError::Parquet {
        path: path.to_path_buf(),
        problem,
    };
    let mut warnings = Vec::new();
    let (metadata, embedded_sidecar) = match ParquetMetaDataReader::new().parse_and_finish(&bytes) {
        Ok(metadata) => {
            let embedded = metadata
                .file_metadata()
                .key_value_metadata()
                .and_then(|kv| kv.iter().find(|kv| kv.key == SIDECAR_KEY))
                .and_then(|kv| kv.value.as_deref())
                .and_then(|json| serde_json::from_str::<Sidecar>(json).ok());
            (Some(metadata), embedded)
        }
        Err(error) => {
            if !bytes.starts_with(MAGIC) {
                return Err(problem(format!("not a Parquet file ({error})")));
            }
            let (recovered, skipped_bytes) = recover_row_groups(&bytes);
            warnings.push(format!(
                    "{}: the file has no final footer (the recording was cut off: {error}); read {} complete row groups ({} rows), skipped the last {skipped_bytes} bytes",
                    path.display(),
                    recovered.as_ref().map_or(0, |m| m.num_row_groups()),
                    recovered.as_ref().map_or(0, |m| m.file_metadata().num_rows()),
                ));
            (recovered, None)
        }
    };
    let sidecar = sidecar.or(embedded_sidecar);
    let Some(metadata) = metadata else {
        // Nothing complete: the modes come from the sidecar.
        let Some(sidecar) = sidecar else {
            return Err(problem(
                "no complete row group and no sidecar to name its modes".to_owned(),
            ));
        };
        let trace = Trace {
            mode_names: sidecar.meta.mode_names.clone(),
            samples: Vec::new(),
            sidecar: Some(sidecar),
            warnings,
        };
        return Ok(crate::trace::check_sidecar(
            trace,
            path,
            TraceFormat::Parquet,
        ));
    };
    check_claimed_sizes(&metadata, bytes.len() as u64).map_err(problem)?;
    let reader_metadata =
        ArrowReaderMetadata::try_new(Arc::new(metadata), ArrowReaderOptions::new())
            .map_err(|e| problem(e.to_string()))?;
    let (mode_names, expected) = trace_schema(reader_metadata.schema()).map_err(problem)?;
    let start_utc_ns = sidecar.as_ref().map(|s| s.meta.start_utc_ns);
    let reader = ParquetRecordBatchReaderBuilder::new_with_metadata(bytes, reader_metadata)
        .with_batch_size(64 * 1024)
        .build()
        .map_err(|e| problem(e.to_string()))?;
    let mut samples = Vec::new();
    for_each_row(
        reader,
        &mode_names,
        &expected,
        start_utc_ns,
        &problem,
        &mut |sample| samples.push(*sample),
    )?;
    let trace = Trace {
        mode_names,
        samples,
        sidecar,
        warnings,
    };
    Ok(crate::trace::check_sidecar(
        trace,
        path,
        TraceFormat::Parquet,
    ))
}

/// Checks that `schema` is a voxhap trace's (every column named and typed as written); returns the mode names
/// and the expected schema.
fn trace_schema(schema: &SchemaRef) -> Result<(Vec<String>, SchemaRef), String> {
    let mode_names = mode_names_from_schema(schema)?;
    let expected = arrow_schema(&mode_names);
    for (index, want) in expected.fields().iter().enumerate() {
        match schema.fields().get(index) {
            Some(got) if got.name() == want.name() && got.data_type() == want.data_type() => {}
            Some(got) => {
                return Err(format!(
                    "column {} is {} ({}), expected {} ({})",
                    index + 1,
                    got.name(),
                    got.data_type(),
                    want.name(),
                    want.data_type()
                ))
            }
            None => {
                return Err(format!(
                    "column {} missing, expected {}",
                    index + 1,
                    want.name()
                ))
            }
        }
    }
    if schema.fields().len() != expected.fields().len() {
        return Err(format!(
            "{} columns, expected {}",
            schema.fields().len(),
            expected.fields().len()
        ));
    }
    Ok((mode_names, expected))
}

/// Converts and checks every row of `reader`'s batches, in order, handing each sample to `sink`.
fn for_each_row(
    reader: impl Iterator<Item = Result<RecordBatch, arrow_schema::ArrowError>>,
    mode_names: &[String],
    expected: &Schema,
    start_utc_ns: Option<i64>,
    problem: &dyn Fn(String) -> TraceReadError,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<u64, TraceReadError> {
    let mut last_tick = None;
    let mut row = Vec::with_capacity(expected.fields().len());
    let mut row_number = 0usize;
    for batch in reader {
        let batch = batch.map_err(|e| problem(e.to_string()))?;
        let columns = batch_columns(&batch).map_err(problem)?;
        for i in 0..batch.num_rows() {
            row_number += 1;
            row.clear();
            for column in &columns {
                row.push(
                    column
                        .cell(i)
                        .map_err(|e| problem(format!("row {row_number}: {e}")))?,
                );
            }
            let sample = sample_from_cells(&row, mode_names.len(), start_utc_ns).map_err(|e| {
                problem(format!(
                    "row {row_number}, column {} ({}): {}",
                    e.index + 1,
                    expected
                        .field(e.index.min(expected.fields().len() - 1))
                        .name(),
                    e.problem
                ))
            })?;
            check_sample(&sample, mode_names.len(), last_tick)
                .map_err(|e| problem(format!("row {row_number}: {e}")))?;
            last_tick = Some(sample.tick);
            sink(&sample);
        }
    }
    Ok(row_number as u64)
}

/// Rows per batch when streaming ([`for_each_parquet_sample`]).
const STREAM_BATCH_ROWS: usize = 8 * 1024;

/// Reads a Parquet trace as [`read_parquet_trace`] does, but hands each sample to `sink` in file order
/// instead of collecting them: the file is read page by page, batch by batch ([`STREAM_BATCH_ROWS`] rows),
/// so memory does not grow with the trace's length. Returns the trace without its samples, and how many were
/// read. A file without its final footer (cut off by a crash) is recovered as [`read_parquet_trace`] does,
/// which holds it whole.
pub(crate) fn for_each_parquet_sample(
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<(Trace, u64), TraceReadError> {
    let (file, _) = crate::trace::open_trace_file(path)?;
    let problem = |problem: String| TraceReadError::Parquet {
        path: path.to_path_buf(),
        problem,
    };
    let Ok(metadata) = ParquetMetaDataReader::new().parse_and_finish(&file) else {
        let mut trace = read_parquet_trace(path)?;
        let samples = std::mem::take(&mut trace.samples);
        samples.iter().for_each(&mut *sink);
        return Ok((trace, samples.len() as u64));
    };
    let embedded_sidecar = metadata
        .file_metadata()
        .key_value_metadata()
        .and_then(|kv| kv.iter().find(|kv| kv.key == SIDECAR_KEY))
        .and_then(|kv| kv.value.as_deref())
        .and_then(|json| serde_json::from_str::<Sidecar>(json).ok());
    let sidecar = read_sidecar(&sidecar_path(path))?.or(embedded_sidecar);
    let file_bytes = file.metadata().map_err(|e| problem(e.to_string()))?.len();
    check_claimed_sizes(&metadata, file_bytes).map_err(problem)?;
    let reader_metadata =
        ArrowReaderMetadata::try_new(Arc::new(metadata), ArrowReaderOptions::new())
            .map_err(|e| problem(e.to_string()))?;
    let (mode_names, expected) = trace_schema(reader_metadata.schema()).map_err(problem)?;
    let start_utc_ns = sidecar.as_ref().map(|s| s.meta.start_utc_ns);
    let reader = ParquetRecordBatchReaderBuilder::new_with_metadata(file, reader_metadata)
        .with_batch_size(STREAM_BATCH_ROWS)
        .build()
        .map_err(|e| problem(e.to_string()))?;
    let count = for_each_row(reader, &mode_names, &expected, start_utc_ns, &problem, sink)?;
    let warnings = crate::trace::sidecar_warnings(
        sidecar.as_ref(),
        path,
        TraceFormat::Parquet,
        &mode_names,
        count,
    );
    Ok((
        Trace {
            mode_names,
            samples: Vec::new(),
            sidecar,
            warnings,
        },
        count,
    ))
}

/// Snappy's largest expansion (a 3-byte copy tag yields at most 64 bytes), with margin: a column chunk
/// cannot hold more uncompressed bytes than this many times its compressed bytes.
const MAX_DECOMPRESSION_RATIO: u64 = 32;

/// Checks the sizes the metadata claims against the file's real size before any page is decoded, so a
/// crafted footer cannot make the reader allocate far more than the file can supply: every column chunk
/// lies inside the file and claims at most [`MAX_DECOMPRESSION_RATIO`] times its compressed size (plus
/// 64 KiB for page headers) once uncompressed.
fn check_claimed_sizes(metadata: &ParquetMetaData, file_bytes: u64) -> Result<(), String> {
    for (g, group) in metadata.row_groups().iter().enumerate() {
        for (c, column) in group.columns().iter().enumerate() {
            let compressed = u64::try_from(column.compressed_size()).unwrap_or(u64::MAX);
            let uncompressed = u64::try_from(column.uncompressed_size()).unwrap_or(u64::MAX);
            let (start, _) = column.byte_range();
            if start.saturating_add(compressed) > file_bytes {
                return Err(format!(
                    "row group {g}, column {c}: {compressed} bytes at offset {start} run past the end \
                     of the {file_bytes}-byte file"
                ));
            }
            if uncompressed > compressed.saturating_mul(MAX_DECOMPRESSION_RATIO) + (64 << 10) {
                return Err(format!(
                    "row group {g}, column {c}: claims {uncompressed} uncompressed bytes from \
                     {compressed} compressed (more than a {MAX_DECOMPRESSION_RATIO}:1 expansion)"
                ));
            }
        }
    }
    Ok(())
}

/// The mode names in a trace's schema (the `primitives_<mode>` columns, in order).
fn mode_names_from_schema(schema: &Schema) -> Result<Vec<String>, String> {
    let mut names: Vec<String> = Vec::new();
    for field in schema.fields() {
        if let Some(name) = field.name().strip_prefix(PRIMITIVES_PREFIX) {
            if !is_valid_mode_name(name) || names.iter().any(|n| n == name) {
                return Err(format!(
                    "column {:?}: not a unique valid mode name",
                    field.name()
                ));
            }
            names.push(name.to_owned());
        }
    }
    if names.len() > MAX_MODES {
        return Err(format!("{} modes, at most {MAX_MODES}", names.len()));
    }
    if schema.fields().first().map(|f| f.name().as_str()) != Some("tick") {
        return Err("not a voxhap trace: the first column is not tick".to_owned());
    }
    Ok(names)
}

/// One column of a batch, typed.
enum TypedColumn<'a> {
    U64(&'a UInt64Array),
    I64(&'a Int64Array),
    F64(&'a Float64Array),
    Bool(&'a BooleanArray),
    Text(&'a StringArray),
}

impl TypedColumn<'_> {
    fn cell(&self, i: usize) -> Result<Cell, String> {
        let null = match self {
            TypedColumn::U64(a) => a.is_null(i),
            TypedColumn::I64(a) => a.is_null(i),
            TypedColumn::F64(a) => a.is_null(i),
            TypedColumn::Bool(a) => a.is_null(i),
            TypedColumn::Text(a) => a.is_null(i),
        };
        if null {
            return Ok(Cell::Missing);
        }
        Ok(match self {
            TypedColumn::U64(a) => Cell::U64(a.value(i)),
            TypedColumn::I64(a) => Cell::I64(a.value(i)),
            TypedColumn::F64(a) => Cell::F64(a.value(i)),
            TypedColumn::Bool(a) => Cell::Bool(a.value(i)),
            TypedColumn::Text(a) => {
                let text = a.value(i);
                match SolverStatus::from_name(text) {
                    Some(status) => Cell::Text(status.name()),
                    None => return Err(format!("unknown solver status {text:?}")),
                }
            }
        })
    }
}

fn batch_columns(batch: &RecordBatch) -> Result<Vec<TypedColumn<'_>>, String> {
    batch
        .columns()
        .iter()
        .enumerate()
        .map(|(index, array)| {
            let any = array.as_any();
            let typed = if let Some(a) = any.downcast_ref::<UInt64Array>() {
                TypedColumn::U64(a)
            } else if let Some(a) = any.downcast_ref::<Int64Array>() {
                TypedColumn::I64(a)
            } else if let Some(a) = any.downcast_ref::<Float64Array>() {
                TypedColumn::F64(a)
            } else if let Some(a) = any.downcast_ref::<BooleanArray>() {
                TypedColumn::Bool(a)
            } else if let Some(a) = any.downcast_ref::<StringArray>() {
                TypedColumn::Text(a)
            } else {
                return Err(format!(
                    "column {}: unexpected type {}",
                    index + 1,
                    array.data_type()
                ));
            };
            Ok(typed)
        })
        .collect()
}

/// Finds the row groups a crash left whole: the last row-group footer whose row group ends where the
/// footer starts, then the chain of footers before it back to the first row group. Returns their
/// metadata (`None` when there is no complete row group) and how many bytes at the end were skipped.
fn recover_row_groups(bytes: &[u8]) -> (Option<ParquetMetaData>, usize) {
    // The last row-group footer: scan back from the end for its magic.
    let mut end = bytes.len();
    let mut last = None;
    while end >= 12 {
        if &bytes[end - 4..end] == ROW_GROUP_FOOTER_MAGIC {
            if let Some(found) = footer_ending_at(bytes, end) {
                last = Some((found, end));
                break;
            }
        }
        end -= 1;
    }
    let Some(((group, group_start), footer_end)) = last else {
        return (None, bytes.len().saturating_sub(MAGIC.len()));
    };
    let mut groups = vec![group];
    let mut start = group_start;
    while start > MAGIC.len() {
        match footer_ending_at(bytes, start) {
            Some((group, group_start)) if group_start < start => {
                groups.push(group);
                start = group_start;
            }
            // A broken chain: keep the contiguous run found from the end... which would not start at
            // the file's first row group; report nothing rather than a trace with a hole.
            _ => return (None, bytes.len().saturating_sub(MAGIC.len())),
        }
    }
    groups.reverse();
    let schema = groups[0].schema_descr_ptr();
    let rows = groups.iter().map(|g| g.num_rows()).sum();
    let metadata =
        ParquetMetaData::new(FileMetaData::new(1, rows, None, None, schema, None), groups);
    (Some(metadata), bytes.len() - footer_end)
}

/// The row group described by a row-group footer ending at `end` (just after its magic), and where
/// that row group starts, if the footer decodes and its one row group ends exactly where the footer
/// begins.
fn footer_ending_at(bytes: &[u8], end: usize) -> Option<(RowGroupMetaData, usize)> {
    if end < 12 || &bytes[end - 4..end] != ROW_GROUP_FOOTER_MAGIC {
        return None;
    }
    let length = u32::from_le_bytes(bytes[end - 8..end - 4].try_into().ok()?) as usize;
    let footer_start = (end - 8).checked_sub(length)?;
    if footer_start < MAGIC.len() {
        return None;
    }
    let metadata = ParquetMetaDataReader::decode_metadata(&bytes[footer_start..end - 8]).ok()?;
    let [group] = metadata.row_groups() else {
        return None;
    };
    let mut first = u64::MAX;
    let mut last = 0u64;
    for column in group.columns() {
        let (start, length) = column.byte_range();
        first = first.min(start);
        last = last.max(start.checked_add(length)?);
    }
    (last == footer_start as u64 && first >= MAGIC.len() as u64 && first < last)
        .then(|| (group.clone(), first as usize))
}

#[cfg(test)]
#[path = "parquet_trace_tests.rs"]
mod tests;
