//! Reading a Parquet trace back ([`for_each_parquet_sample`], for [`crate::read_trace`] and `voxhap plot`),
//! batch by batch from the file, after the sizes its footer and page headers claim are checked against the
//! file's real size ([`crate::parquet_limits`]). A file cut off before its final footer is read up to its last
//! complete row group ([`crate::parquet_recover`]), with a warning.

use std::path::Path;
use std::sync::Arc;

use arrow_array::{
    Array, BooleanArray, Float64Array, Int64Array, RecordBatch, StringArray, UInt64Array,
};
use arrow_schema::Schema;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReaderBuilder,
};
use parquet::file::metadata::ParquetMetaDataReader;
use parquet::file::reader::{ChunkReader, Length};

use crate::columns::{sample_from_cells, Cell};
use crate::csv::read_sidecar;
use crate::error::{ParquetProblem, TraceReadError};
use crate::output::sidecar_path;
use crate::parquet_limits::{check_claimed_sizes, check_page_headers};
use crate::parquet_schema::{embedded_sidecar, trace_schema, MAGIC};
use crate::sample::{check_sample, TraceSample};
use crate::trace::Trace;
use voxhap_api::TraceFormat;

/// Rows per batch.
const BATCH_ROWS: usize = 8 * 1024;

/// Reads a Parquet trace, and its sidecar `path.json` when that file exists, handing each sample to `sink` in
/// file order. A file without its final footer (cut off by a crash) is read up to its last complete row
/// group, with a warning. The file is read page by page, batch by batch ([`BATCH_ROWS`] rows), so the
/// samples' memory does not grow with the trace's length, a file cut off before its final footer included;
/// only the row groups' metadata (the footer, or what was recovered) is held whole. Returns the
/// trace without its samples, and how many were read.
pub(crate) fn for_each_parquet_sample(
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<(Trace, u64), TraceReadError> {
    let problem = |problem: ParquetProblem| TraceReadError::Parquet {
        path: path.to_path_buf(),
        problem: Box::new(problem),
    };
    let (file, _) = crate::trace::open_trace_file(path)?;
    let sidecar = read_sidecar(&sidecar_path(path))?;
    let mut warnings = Vec::new();
    let (metadata, embedded) = match ParquetMetaDataReader::new().parse_and_finish(&file) {
        Ok(metadata) => {
            let embedded = embedded_sidecar(&metadata);
            (Some(metadata), embedded)
        }
        Err(error) => {
            let starts_with_magic = file
                .get_bytes(0, MAGIC.len())
                .is_ok_and(|b| b[..] == MAGIC[..]);
            if !starts_with_magic {
                return Err(problem(ParquetProblem::NotParquet(error)));
            }
            let (recovered, skipped_bytes) = crate::parquet_recover::recover_row_groups(&file);
            warnings.push(format!(
                "{}: the file has no final footer (the recording was cut off: {error}); read {} complete row groups ({} rows), skipped the last {skipped_bytes} bytes",
                path.display(),
                recovered.as_ref().map_or(0, |m| m.num_row_groups()),
                recovered.as_ref().map_or(0, |m| m.file_metadata().num_rows()),
            ));
            (recovered, None)
        }
    };
    let sidecar = sidecar.or(embedded);
    let Some(metadata) = metadata else {
        // Nothing complete: the modes come from the sidecar.
        let sidecar = sidecar.ok_or_else(|| problem(ParquetProblem::NothingToRead))?;
        let mode_names = sidecar.meta.mode_names.clone();
        return Ok((finish(path, mode_names, Some(sidecar), warnings, 0), 0));
    };
    check_claimed_sizes(&metadata, file.len()).map_err(problem)?;
    check_page_headers(&file, &metadata).map_err(problem)?;
    let reader_metadata =
        ArrowReaderMetadata::try_new(Arc::new(metadata), ArrowReaderOptions::new())
            .map_err(|e| problem(e.into()))?;
    let (mode_names, expected) = trace_schema(reader_metadata.schema()).map_err(problem)?;
    let start_utc_ns = sidecar.as_ref().map(|s| s.meta.start_utc_ns);
    let reader = ParquetRecordBatchReaderBuilder::new_with_metadata(file, reader_metadata)
        .with_batch_size(BATCH_ROWS)
        .build()
        .map_err(|e| problem(e.into()))?;
    let count =
        for_each_row(reader, &mode_names, &expected, start_utc_ns, sink).map_err(problem)?;
    Ok((finish(path, mode_names, sidecar, warnings, count), count))
}

/// The trace without its samples, with the sidecar's contradictions added to `warnings`.
fn finish(
    path: &Path,
    mode_names: Vec<String>,
    sidecar: Option<crate::meta::Sidecar>,
    mut warnings: Vec<String>,
    count: u64,
) -> Trace {
    warnings.extend(crate::trace::sidecar_warnings(
        sidecar.as_ref(),
        path,
        TraceFormat::Parquet,
        &mode_names,
        count,
    ));
    Trace {
        mode_names,
        samples: Vec::new(),
        sidecar,
        warnings,
    }
}

/// Converts and checks every row of `reader`'s batches, in order, handing each sample to `sink`.
fn for_each_row(
    reader: impl Iterator<Item = Result<RecordBatch, arrow_schema::ArrowError>>,
    mode_names: &[String],
    expected: &Schema,
    start_utc_ns: Option<i64>,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<u64, ParquetProblem> {
    let mut last_tick = None;
    let mut row = Vec::with_capacity(expected.fields().len());
    let mut row_number = 0usize;
    for batch in reader {
        let batch = batch?;
        let columns = batch_columns(&batch)?;
        for i in 0..batch.num_rows() {
            row_number += 1;
            row.clear();
            for column in &columns {
                row.push(column.cell(i, row_number)?);
            }
            let sample = sample_from_cells(&row, mode_names.len(), start_utc_ns).map_err(|e| {
                ParquetProblem::BadCell {
                    row: row_number,
                    column: e.index + 1,
                    name: expected
                        .field(e.index.min(expected.fields().len() - 1))
                        .name()
                        .clone(),
                    problem: e.problem,
                }
            })?;
            check_sample(&sample, mode_names.len(), last_tick).map_err(|rule| {
                ParquetProblem::BadSample {
                    row: row_number,
                    rule,
                }
            })?;
            last_tick = Some(sample.tick);
            sink(&sample);
        }
    }
    Ok(row_number as u64)
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
    /// The cell at index `i` of the batch, row `row` (1-based) of the file.
    fn cell(&self, i: usize, row: usize) -> Result<Cell, ParquetProblem> {
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
                match crate::truth_columns::static_text(text) {
                    Some(name) => Cell::Text(name),
                    None => {
                        return Err(ParquetProblem::UnknownStatus {
                            row,
                            status: text.to_owned(),
                        })
                    }
                }
            }
        })
    }
}

fn batch_columns(batch: &RecordBatch) -> Result<Vec<TypedColumn<'_>>, ParquetProblem> {
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
                return Err(ParquetProblem::UnexpectedType {
                    column: index + 1,
                    data_type: array.data_type().clone(),
                });
            };
            Ok(typed)
        })
        .collect()
}
