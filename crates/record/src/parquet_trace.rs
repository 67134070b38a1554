//! Parquet force traces: the writer ([`ParquetTraceWriter`]); the reader is [`crate::parquet_read`].
//!
//! Where it sits: one of the three trace formats behind [`crate::writer::TraceWriter`] (chosen by a `.parquet`
//! name or `--format parquet`). The columns are `crate::columns::columns`, the same names, order and
//! values as CSV, with Parquet types: `UInt64` counts and ticks, `Int64` `utc_ns` (null when `t_s` is not
//! finite), `Float64` quantities (NaN and infinities kept), `Boolean` flag columns, a UTF-8
//! `solver_status`, and nullable `UInt64` device sequence and time. The finished file's metadata holds
//! the sidecar's JSON under the key [`SIDECAR_KEY`] ([`crate::parquet_schema`]), so a Parquet trace describes itself even without its
//! `TRACE.json`. Pages are Snappy-compressed (what pandas and pyarrow write by default); float columns are
//! BYTE_STREAM_SPLIT, integer columns DELTA_BINARY_PACKED ([`writer_properties`], measured).
//!
//! Crash safety: rows are buffered and written as one row group per second of trace time (at most
//! [`ROW_GROUP_MAX_ROWS`] rows, and at most about one second of wall-clock time when the recorder
//! flushes), so a crash loses at most the last second. A Parquet reader needs the footer, which is only
//! written at the end; so after every row group the writer also writes a *row-group footer*: a Parquet
//! footer (metadata, length) that describes only that row group, ending in `VXRG` instead of `PAR1` so
//! no reader mistakes a cut-off file for a finished one holding only its last row group. Readers ignore
//! bytes between row groups. A file cut off by a crash ends without the final footer; [`crate::parquet_read`]
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
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::DataType;
use arrow_schema::SchemaRef;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, Encoding};
use parquet::file::metadata::{
    FileMetaData, KeyValue, ParquetMetaData, ParquetMetaDataWriter, RowGroupMetaData,
};
use parquet::file::properties::WriterProperties;
use parquet::schema::types::ColumnPath;

use crate::columns::{columns, refill, Cell, ColumnType};
use crate::error::TraceError;
use crate::meta::{Sidecar, TraceMeta, TraceSummary};
use crate::output::{OutputFile, StopSwitch};
use crate::parquet_schema::{arrow_schema, MAGIC, ROW_GROUP_FOOTER_MAGIC, SIDECAR_KEY};
use crate::sample::{SampleChecker, TraceSample};
use crate::writer::TraceWriter;
use voxhap_api::TraceFormat;

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
        let properties = writer_properties(&schema, ROW_GROUP_MAX_ROWS);
        let writer = ArrowWriter::try_new(
            BufWriter::with_capacity(256 * 1024, file),
            schema.clone(),
            Some(properties),
        )
        .map_err(|source| TraceError::Parquet {
            path: path.to_path_buf(),
            source,
        })?;
        let sidecar = Sidecar::create(meta, TraceFormat::Parquet, path)?;
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
        TraceError::io(&self.path, source)
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

/// The writer's properties: Snappy pages, row groups of up to `max_rows` rows, and per column the encoding
/// that stores a moving trace smallest among those measured (`python/bench/parquet_encodings.py` on a
/// one-hour sims/multimodal.toml trace, docs/traces.md): float columns BYTE_STREAM_SPLIT (their bytes
/// regrouped by significance, which Snappy then compresses; dictionaries of float time series overflow and
/// fall back to PLAIN), integer columns DELTA_BINARY_PACKED (ticks, times and counts change by small
/// steps), no dictionary but for the text columns (`solver_status`, `force_off_cause`: a handful of values each).
fn writer_properties(schema: &SchemaRef, max_rows: usize) -> WriterProperties {
    let mut builder = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_max_row_group_row_count(Some(max_rows))
        .set_created_by(format!("voxhap {}", env!("CARGO_PKG_VERSION")))
        .set_dictionary_enabled(false);
    for field in schema.fields() {
        let path = ColumnPath::from(field.name().as_str());
        builder = match field.data_type() {
            DataType::Float64 | DataType::Float32 => {
                builder.set_column_encoding(path, Encoding::BYTE_STREAM_SPLIT)
            }
            DataType::Int64 | DataType::UInt64 => {
                builder.set_column_encoding(path, Encoding::DELTA_BINARY_PACKED)
            }
            DataType::Utf8 => builder.set_column_dictionary_enabled(path, true),
            _ => builder,
        };
    }
    builder.build()
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
        let properties = writer_properties(schema, COMPACT_ROW_GROUP_ROWS);
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
        let open = self.writer.is_some();
        let Some(sample) = self.checker.admit_to(open, sample)? else {
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
        let row = refill(
            &mut self.row,
            &sample,
            self.checker.mode_count,
            self.start_utc_ns,
        );
        for (builder, cell) in self.builders.iter_mut().zip(row) {
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

#[cfg(test)]
#[path = "parquet_trace_tests.rs"]
mod tests;
