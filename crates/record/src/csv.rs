//! CSV force traces: the writer ([`CsvTraceWriter`]) and the reader (`for_each_csv_sample`, behind
//! [`crate::read_trace_as`]).
//!
//! Layout: a header line, then one line per tick, fields separated by `,` with no quoting (no field can
//! contain a comma: mode names are restricted to `[A-Za-z0-9_-]`) and `\n` line ends. The columns are
//! `crate::columns::columns` (documented with units and types in the sidecar): tick and times, probe,
//! velocity, proxy, rendered and sent force, per mode its primitive count and force, solver status,
//! sweeps, bound, device sequence and time (empty when the device has none), `flag_bits` and one
//! `true`/`false` column per flag. Floats are written with Rust's `{:?}` formatting, the shortest text
//! that parses back to the same bits (`0.001`, `-0.0`, `1e-17`, `inf`, `NaN`), so write-then-read is
//! exact.
//!
//! Crash safety: rows are formatted into a buffer and handed to the file only as whole lines (when the
//! buffer passes 64 KiB, and on every flush), so a crash loses at most the lines since the last flush and
//! leaves at most one partial line at the end. The reader skips such a partial last line with a warning
//! (`Trace::warnings`); anywhere else a bad line is an error naming the line and column. A trace written
//! in the old layout (format 1, column `flags`) is refused with an error saying so.

use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use crate::columns::{columns, refill, sample_from_cells, Cell, ColumnType, PRIMITIVES_PREFIX};
use crate::error::{TraceError, TraceReadError};
use crate::meta::is_valid_mode_name;
use crate::meta::{Sidecar, TraceMeta, TraceSummary, TRACE_FORMAT_VERSION};
use crate::output::sidecar_path;
use crate::sample::{check_sample, SampleChecker, TraceSample};
use crate::trace::Trace;
use crate::writer::TraceWriter;
use voxhap_api::TraceFormat;
use voxhap_core::haptics::modes::MAX_MODES;

/// Buffered bytes (whole lines) after which the writer hands them to the file.
const WRITE_CHUNK_BYTES: usize = 64 * 1024;

/// Writes a CSV trace and its sidecar.
pub struct CsvTraceWriter {
    path: PathBuf,
    file: Option<File>,
    buffer: Vec<u8>,
    row: Vec<Cell>,
    checker: SampleChecker,
    /// Rows in `buffer`, not yet handed to the file.
    buffered_rows: u64,
    /// Rows whose whole line reached the file: the count the sidecar gives.
    committed_rows: u64,
    start_utc_ns: i64,
    sidecar: Sidecar,
}

impl CsvTraceWriter {
    /// Creates `path` and `path.json` (new files, never through a symlink), writes the header and a
    /// provisional sidecar. `create_trace_writer_with` removes files that `--force` replaces first.
    pub fn create(path: &Path, meta: &TraceMeta) -> Result<Self, TraceError> {
        meta.validate()?;
        let io_error = |source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = crate::output::create_new_file(path)?;
        let header: Vec<String> = columns(&meta.mode_names)
            .into_iter()
            .map(|c| c.name.into_owned())
            .collect();
        file.write_all(format!("{}\n", header.join(",")).as_bytes())
            .map_err(io_error)?;
        let sidecar = Sidecar::create(meta, TraceFormat::Csv, path)?;
        Ok(CsvTraceWriter {
            path: path.to_path_buf(),
            file: Some(file),
            buffer: Vec::with_capacity(WRITE_CHUNK_BYTES + 4096),
            row: Vec::with_capacity(128),
            checker: SampleChecker::new(meta.mode_names.len()),
            buffered_rows: 0,
            committed_rows: 0,
            start_utc_ns: meta.start_utc_ns,
            sidecar,
        })
    }

    fn io_error(&self, source: std::io::Error) -> TraceError {
        TraceError::io(&self.path, source)
    }

    /// Hands the buffered whole lines to the file, counting the lines that reached it. After a failed
    /// write (a full disk takes part of the buffer, then refuses the rest) nothing more is written, and
    /// only the lines that reached the file whole are counted (the reader skips the partial one).
    fn write_buffer(&mut self) -> Result<(), TraceError> {
        let Some(file) = self.file.as_mut() else {
            return Err(TraceError::Finished);
        };
        let mut written = 0;
        let mut result = Ok(());
        while written < self.buffer.len() {
            match file.write(&self.buffer[written..]) {
                Ok(0) => {
                    result = Err(std::io::Error::from(std::io::ErrorKind::WriteZero));
                    break;
                }
                Ok(n) => written += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        match result {
            Ok(()) => self.committed_rows += self.buffered_rows,
            Err(_) => {
                let whole_lines = self.buffer[..written]
                    .iter()
                    .filter(|&&b| b == b'\n')
                    .count();
                self.committed_rows += whole_lines as u64;
                self.file = None;
            }
        }
        self.buffered_rows = 0;
        self.buffer.clear();
        result.map_err(|e| self.io_error(e))
    }
}

/// Appends one row of cells and a newline.
fn write_cells(out: &mut Vec<u8>, row: &[Cell]) {
    for (i, cell) in row.iter().enumerate() {
        if i > 0 {
            out.push(b',');
        }
        // Writing into a Vec cannot fail.
        let _ = match cell {
            Cell::U64(v) => write!(out, "{v}"),
            Cell::I64(v) => write!(out, "{v}"),
            Cell::F64(v) => write!(out, "{v:?}"),
            Cell::Bool(v) => write!(out, "{v}"),
            Cell::Text(v) => write!(out, "{v}"),
            Cell::Missing => Ok(()),
        };
    }
    out.push(b'\n');
}

#[cfg(test)]
fn write_row(out: &mut Vec<u8>, s: &TraceSample, start_utc_ns: i64) {
    let mut row = Vec::new();
    write_cells(out, refill(&mut row, s, s.modes.count(), start_utc_ns));
}

impl TraceWriter for CsvTraceWriter {
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        let open = self.file.is_some();
        let Some(sample) = self.checker.admit_to(open, sample)? else {
            return Ok(());
        };
        let row = refill(
            &mut self.row,
            &sample,
            self.checker.mode_count,
            self.start_utc_ns,
        );
        write_cells(&mut self.buffer, row);
        self.buffered_rows += 1;
        if self.buffer.len() >= WRITE_CHUNK_BYTES {
            self.write_buffer()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        self.write_buffer()
    }

    fn finish(&mut self) -> Result<TraceSummary, TraceError> {
        if self.checker.finished {
            return Err(TraceError::Finished);
        }
        self.write_buffer()?;
        if let Some(file) = self.file.take() {
            file.sync_all().map_err(|e| self.io_error(e))?;
        }
        self.checker.finished = true;
        self.sidecar.samples_rejected = self.checker.rejected;
        self.sidecar.complete(&self.path, self.committed_rows)
    }

    fn fail(&mut self, error: &str) -> Result<(), TraceError> {
        self.checker.finished = true;
        self.file = None;
        self.buffer.clear();
        self.buffered_rows = 0;
        self.sidecar.samples_rejected = self.checker.rejected;
        self.sidecar.fail(&self.path, self.committed_rows, error)
    }

    fn sample_count(&self) -> u64 {
        self.committed_rows
    }
}

/// Reads a sidecar if it exists; a missing file is `None`, a malformed one an error.
pub(crate) fn read_sidecar(path: &Path) -> Result<Option<Sidecar>, TraceReadError> {
    let read = voxhap_io::read_regular(
        path,
        voxhap_io::MAX_TEXT_FILE_BYTES,
        "a trace sidecar (16 MiB)",
    )
    .map_err(|error| match error {
        voxhap_io::FileError::Io(source) => source,
        other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
    });
    match read {
        Ok(bytes) => {
            serde_json::from_slice(&bytes)
                .map(Some)
                .map_err(|source| TraceReadError::Sidecar {
                    path: path.to_path_buf(),
                    source,
                })
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Parses CSV trace text from any reader; returns the mode names and the samples (a partial last line
/// is skipped).
pub fn parse_csv_trace(
    reader: impl BufRead,
) -> Result<(Vec<String>, Vec<TraceSample>), TraceReadError> {
    parse_csv_lines(reader, Path::new("<input>"), None).map(|(modes, samples, _)| (modes, samples))
}

type Parsed = (Vec<String>, Vec<TraceSample>, Vec<String>);

fn parse_csv_lines(
    reader: impl BufRead,
    path: &Path,
    start_utc_ns: Option<i64>,
) -> Result<Parsed, TraceReadError> {
    let mut samples = Vec::new();
    let (mode_names, warnings, _) = for_each_csv_line(reader, path, start_utc_ns, &mut |sample| {
        samples.push(*sample)
    })?;
    Ok((mode_names, samples, warnings))
}

/// Reads a CSV trace, and its sidecar `path.json` when that file exists, handing each sample to `sink` in file
/// order (memory does not grow with the trace's length); a partial last line is skipped with a warning. A
/// regular file only; reading stops at the size it had when opened. Returns the trace without its samples,
/// and how many were read.
pub(crate) fn for_each_csv_sample(
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<(Trace, u64), TraceReadError> {
    let (file, size_bytes) = crate::trace::open_trace_file(path)?;
    let sidecar = read_sidecar(&sidecar_path(path))?;
    let start_utc_ns = sidecar.as_ref().map(|s| s.meta.start_utc_ns);
    let (mode_names, warnings, count) = for_each_csv_line(
        BufReader::new(std::io::Read::take(file, size_bytes)),
        path,
        start_utc_ns,
        sink,
    )?;
    let mut warnings = warnings;
    warnings.extend(crate::trace::sidecar_warnings(
        sidecar.as_ref(),
        path,
        voxhap_api::TraceFormat::Csv,
        &mode_names,
        count,
    ));
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

/// The mode names, the warnings and the count of samples handed to `sink`.
type Streamed = (Vec<String>, Vec<String>, u64);

fn for_each_csv_line(
    mut reader: impl BufRead,
    path: &Path,
    start_utc_ns: Option<i64>,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<Streamed, TraceReadError> {
    let mut buffer = Vec::new();
    let mut line_number = 0usize;
    // Returns the line number and whether the line ended with a newline.
    let mut next_line = |buffer: &mut Vec<u8>| -> Result<Option<(usize, bool)>, TraceReadError> {
        buffer.clear();
        let read = reader
            .read_until(b'\n', buffer)
            .map_err(|source| TraceReadError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            return Ok(None);
        }
        line_number += 1;
        let complete = buffer.last() == Some(&b'\n');
        if complete {
            buffer.pop();
            if buffer.last() == Some(&b'\r') {
                buffer.pop();
            }
        }
        Ok(Some((line_number, complete)))
    };

    let Some(_) = next_line(&mut buffer)? else {
        return Err(TraceReadError::Empty);
    };
    let header = std::str::from_utf8(&buffer).map_err(|_| TraceReadError::NotText { line: 1 })?;
    let mode_names = parse_header(header, path)?;
    let docs = columns(&mode_names);
    let names: Vec<String> = docs.iter().map(|c| c.name.to_string()).collect();
    let types: Vec<ColumnType> = docs.iter().map(|c| c.column_type).collect();

    let mut count = 0u64;
    let mut warnings = Vec::new();
    let mut last_tick = None;
    let mut row = Vec::with_capacity(names.len());
    while let Some((line, complete)) = next_line(&mut buffer)? {
        let parsed = std::str::from_utf8(&buffer)
            .map_err(|_| TraceReadError::NotText { line })
            .and_then(|text| {
                let sample = parse_row(
                    text,
                    line,
                    &names,
                    &types,
                    &mut row,
                    mode_names.len(),
                    start_utc_ns,
                )?;
                match check_sample(&sample, mode_names.len(), last_tick) {
                    Ok(()) => Ok(sample),
                    Err(problem) => Err(rule_error(problem, text, line, &names)),
                }
            });
        match parsed {
            Ok(sample) => {
                last_tick = Some(sample.tick);
                count += 1;
                sink(&sample);
            }
            // A crash leaves at most one partial line, at the end and without a newline.
            Err(error) if !complete => {
                warnings.push(format!(
                    "{}: skipped the partial last line {line} (the recording was cut off): {error}",
                    path.display()
                ));
                break;
            }
            Err(error) => return Err(error),
        }
    }
    Ok((mode_names, warnings, count))
}

fn parse_header(header: &str, path: &Path) -> Result<Vec<String>, TraceReadError> {
    let fields: Vec<&str> = header.split(',').collect();
    if fields.contains(&"flag_bits") && !fields.contains(&crate::truth_columns::FORCE_OFF_CAUSE) {
        return Err(TraceReadError::OldFormat {
            path: path.to_path_buf(),
            found: 2,
            expected: TRACE_FORMAT_VERSION,
            hint: "it has no energy ledger or force_off_cause columns",
        });
    }
    if fields.contains(&crate::truth_columns::FORCE_OFF_CAUSE)
        && !fields.contains(&crate::truth_columns::PASSIVITY_COLUMN.0)
    {
        return Err(TraceReadError::OldFormat {
            path: path.to_path_buf(),
            found: 3,
            expected: TRACE_FORMAT_VERSION,
            hint: "it has no passivity_dissipated_j, device_force or external_force columns",
        });
    }
    if fields.contains(&crate::truth_columns::PASSIVITY_COLUMN.0)
        && !fields.contains(&crate::truth_columns::LOCAL_MODEL_SEQUENCE)
    {
        return Err(TraceReadError::OldFormat {
            path: path.to_path_buf(),
            found: 4,
            expected: TRACE_FORMAT_VERSION,
            hint: "it has no device_proxy or local_model columns",
        });
    }
    if fields.last() == Some(&"flags") && !fields.contains(&"flag_bits") {
        return Err(TraceReadError::OldFormat {
            path: path.to_path_buf(),
            found: 1,
            expected: TRACE_FORMAT_VERSION,
            hint: "its last column is `flags`",
        });
    }
    let mismatch = |column: usize, expected: &str| TraceReadError::Header {
        column: column + 1,
        expected: expected.to_string(),
        found: fields.get(column).copied().unwrap_or("").to_string(),
    };
    let mut mode_names = Vec::new();
    for (column, field) in fields.iter().enumerate() {
        if let Some(name) = field.strip_prefix(PRIMITIVES_PREFIX) {
            if !is_valid_mode_name(name) || mode_names.iter().any(|m| m == name) {
                return Err(mismatch(
                    column,
                    "primitives_<mode> with a unique mode name of letters, digits, '_' or '-'",
                ));
            }
            if mode_names.len() == MAX_MODES {
                return Err(mismatch(column, "at most 8 primitives_<mode> columns"));
            }
            mode_names.push(name.to_string());
        }
    }
    let expected = columns(&mode_names);
    for (column, doc) in expected.iter().enumerate() {
        if fields.get(column) != Some(&doc.name.as_ref()) {
            return Err(mismatch(column, &doc.name));
        }
    }
    if fields.len() > expected.len() {
        return Err(mismatch(expected.len(), "the end of the line"));
    }
    Ok(mode_names)
}

/// Parses one field of a column of type `column_type`.
fn parse_cell(text: &str, column_type: ColumnType) -> Result<Cell, &'static str> {
    // Rust's integer parsing accepts a leading '+'; the format never writes one.
    let integer = |problem| {
        if text.starts_with('+') {
            Err(problem)
        } else {
            Ok(())
        }
    };
    let unsigned = |problem| {
        integer(problem)?;
        text.parse().map(Cell::U64).map_err(|_| problem)
    };
    match column_type {
        ColumnType::U64 => unsigned("not an unsigned integer"),
        ColumnType::OptionalU64 if text.is_empty() => Ok(Cell::Missing),
        ColumnType::OptionalU64 => unsigned("not an unsigned integer or empty"),
        ColumnType::I64 if text.is_empty() => Ok(Cell::Missing),
        ColumnType::I64 => {
            integer("not an integer")?;
            text.parse().map(Cell::I64).map_err(|_| "not an integer")
        }
        ColumnType::F64 => text.parse().map(Cell::F64).map_err(|_| "not a number"),
        ColumnType::Bool => match text {
            "true" => Ok(Cell::Bool(true)),
            "false" => Ok(Cell::Bool(false)),
            _ => Err("not true or false"),
        },
        ColumnType::Text => crate::truth_columns::static_text(text)
            .map(Cell::Text)
            .ok_or("not a solver status or force-off cause"),
    }
}

fn parse_row(
    text: &str,
    line: usize,
    names: &[String],
    types: &[ColumnType],
    row: &mut Vec<Cell>,
    mode_count: usize,
    start_utc_ns: Option<i64>,
) -> Result<TraceSample, TraceReadError> {
    let found = text.split(',').count();
    if found != names.len() {
        return Err(TraceReadError::FieldCount {
            line,
            expected: names.len(),
            found,
        });
    }
    let field_error = |index: usize, problem: &'static str| TraceReadError::Field {
        line,
        column: index + 1,
        name: names[index].clone(),
        value: text.split(',').nth(index).unwrap_or("").to_string(),
        problem,
    };
    row.clear();
    for (index, (field, column_type)) in text.split(',').zip(types).enumerate() {
        row.push(parse_cell(field, *column_type).map_err(|problem| field_error(index, problem))?);
    }
    sample_from_cells(row, mode_count, start_utc_ns).map_err(|e| field_error(e.index, e.problem))
}

/// Turns a broken trace rule into an error naming the line and the first column concerned.
fn rule_error(problem: TraceError, text: &str, line: usize, columns: &[String]) -> TraceReadError {
    let (column_name, message): (&str, &'static str) = match problem {
        TraceError::TickOrder { .. } => ("tick", "tick does not increase"),
        TraceError::NegativeTime { .. } => ("t_s", "negative time"),
        TraceError::InvalidErrorBound { .. } => ("error_bound_m", "must be >= 0 or inf"),
        TraceError::NonFinite { field, .. } => (
            match field {
                "probe_m" => "probe_x_m",
                "probe_velocity_m_per_s" => "probe_vx_m_per_s",
                "proxy_m" => "proxy_x_m",
                "rendered_force_n" => "rendered_force_x_n",
                "force_n" => "force_x_n",
                other => other,
            },
            "not finite without flag_invalid_values (checked from this column on)",
        ),
        _ => ("tick", "invalid sample"),
    };
    let index = columns.iter().position(|c| c == column_name).unwrap_or(0);
    TraceReadError::Field {
        line,
        column: index + 1,
        name: columns[index].clone(),
        value: text.split(',').nth(index).unwrap_or("").to_string(),
        problem: message,
    }
}

#[cfg(test)]
#[path = "csv_tests.rs"]
mod tests;
