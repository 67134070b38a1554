//! The trace functions of `voxhap._voxhap`: what `voxhap.read_trace` needs from voxhap's own trace code.
//!
//! Parquet and CSV traces are read by pandas/pyarrow themselves (python/voxhap/trace.py); from here they
//! take only the column list of a trace ([`trace_columns`], the one every writer uses), the sidecar and its
//! check against the file ([`sidecar_check`]), and the header check of a CSV trace ([`csv_mode_names`]).
//! An MCAP trace, or a Parquet trace cut off by a crash, is read by voxhap's own reader
//! ([`read_trace_columns`]), which hands the samples back as columns of raw little-endian values, in memory:
//! nothing is written to disk.

use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use std::path::{Path, PathBuf};
use voxhap_record::{
    columns, error_chain, sidecar_path, sidecar_warnings, ColumnType, ForceOffCause, Sidecar,
    SolverStatus, TraceFormat, TraceMeta, TraceReadError, TraceSample, FLAG_DOCS, MAX_MODES,
};

/// The name of a column type as the sidecar writes it (`u64`, `i64`, `f64`, `bool`, `text`,
/// `optionalu64`).
fn type_name(column_type: ColumnType) -> PyResult<String> {
    match serde_json::to_value(column_type) {
        Ok(serde_json::Value::String(name)) => Ok(name),
        _ => Err(PyValueError::new_err("a column type without a name")),
    }
}

/// The columns of a trace with these modes, in file order: (name, type), as every trace writer writes
/// them. Bad mode names (empty, not letters/digits/`_`/`-`, repeated, more than 8) are a `ValueError`.
#[pyfunction]
pub fn trace_columns(mode_names: Vec<String>) -> PyResult<Vec<(String, String)>> {
    let meta = TraceMeta::new(mode_names, 1000.0, serde_json::Value::Null, "", "");
    meta.validate()
        .map_err(|e| PyValueError::new_err(error_chain(&e)))?;
    columns(&meta.mode_names)
        .into_iter()
        .map(|doc| Ok((doc.name.into_owned(), type_name(doc.column_type)?)))
        .collect()
}

/// The mode names of a CSV trace, from its header line (with or without the newline), checked exactly as
/// voxhap's CSV reader checks it: an older trace format, a missing or misplaced column is a `ValueError`
/// naming the column.
#[pyfunction]
pub fn csv_mode_names(path: PathBuf, header: &[u8]) -> PyResult<Vec<String>> {
    let mut line = header.to_vec();
    if !line.ends_with(b"\n") {
        line.push(b'\n');
    }
    voxhap_record::parse_csv_trace(line.as_slice())
        .map(|(modes, _)| modes)
        .map_err(|e| {
            let text = error_chain(&e).replace("<input>", &path.display().to_string());
            PyValueError::new_err(text)
        })
}

/// The trace's sidecar (the file `TRACE.json` when it exists, else `embedded`, the JSON a finished Parquet
/// trace holds in its metadata) as JSON text, and what it says that the file contradicts (the warnings of
/// voxhap's readers: sample count, modes, columns, format, format version). A sidecar that does not parse
/// is a `ValueError`, as in voxhap's readers.
#[pyfunction]
#[pyo3(signature = (path, format, mode_names, sample_count, embedded = None))]
pub fn sidecar_check(
    path: PathBuf,
    format: &str,
    mode_names: Vec<String>,
    sample_count: u64,
    embedded: Option<&str>,
) -> PyResult<(Option<String>, Vec<String>)> {
    let format = match format {
        "csv" => TraceFormat::Csv,
        "parquet" => TraceFormat::Parquet,
        "mcap" => TraceFormat::Mcap,
        other => {
            return Err(PyValueError::new_err(format!(
                "format {other:?}: expected csv, parquet or mcap"
            )))
        }
    };
    let sidecar = match read_sidecar_file(&sidecar_path(&path))? {
        Some(sidecar) => Some(sidecar),
        // A malformed embedded sidecar is ignored, as voxhap's Parquet reader ignores it.
        None => embedded.and_then(|json| serde_json::from_str::<Sidecar>(json).ok()),
    };
    let warnings = sidecar_warnings(sidecar.as_ref(), &path, format, &mode_names, sample_count);
    let json = sidecar
        .map(|s| serde_json::to_string(&s))
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("cannot encode the sidecar: {e}")))?;
    Ok((json, warnings))
}

/// Reads `TRACE.json`: `None` when it does not exist, an error when it cannot be read or parsed (a regular
/// file of at most 16 MiB, as voxhap's readers require).
fn read_sidecar_file(path: &Path) -> PyResult<Option<Sidecar>> {
    let bytes = match voxhap_io::read_regular(
        path,
        voxhap_io::MAX_TEXT_FILE_BYTES,
        "a trace sidecar (16 MiB)",
    ) {
        Ok(bytes) => bytes,
        Err(voxhap_io::FileError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => {
            return Ok(None)
        }
        Err(e) => {
            return Err(PyOSError::new_err(format!(
                "cannot read {}: {e}",
                path.display()
            )))
        }
    };
    serde_json::from_slice(&bytes).map(Some).map_err(|source| {
        let error = TraceReadError::Sidecar {
            path: path.to_path_buf(),
            source,
        };
        PyValueError::new_err(error_chain(&error))
    })
}

/// One column's values as raw little-endian bytes, with a validity mask (one byte per row, 1 = present)
/// for the columns that can be missing.
enum Column {
    U64(Vec<u8>),
    I64(Vec<u8>, Vec<u8>),
    F64(Vec<u8>),
    Bool(Vec<u8>),
    /// Indices into the text names: [`SolverStatus::ALL`], then [`ForceOffCause::ALL`].
    Text(Vec<u8>),
    OptionalU64(Vec<u8>, Vec<u8>),
}

impl Column {
    fn new(column_type: ColumnType, rows: usize) -> Self {
        match column_type {
            ColumnType::U64 => Column::U64(Vec::with_capacity(rows * 8)),
            ColumnType::I64 => Column::I64(Vec::with_capacity(rows * 8), Vec::with_capacity(rows)),
            ColumnType::F64 => Column::F64(Vec::with_capacity(rows * 8)),
            ColumnType::Bool => Column::Bool(Vec::with_capacity(rows)),
            ColumnType::Text => Column::Text(Vec::with_capacity(rows)),
            ColumnType::OptionalU64 => {
                Column::OptionalU64(Vec::with_capacity(rows * 8), Vec::with_capacity(rows))
            }
        }
    }
}

/// Fills the columns of a trace row by row, in the order of [`columns`]; a value of the wrong kind for its
/// column (this file out of step with the record crate's column list) is an error, never a shifted table.
struct RowWriter<'a> {
    columns: &'a mut [Column],
    index: usize,
    mismatch: Option<usize>,
}

impl RowWriter<'_> {
    fn next(&mut self) -> Option<&mut Column> {
        let i = self.index;
        self.index += 1;
        let column = self.columns.get_mut(i);
        if column.is_none() && self.mismatch.is_none() {
            self.mismatch = Some(i);
        }
        column
    }
    fn fail(&mut self) {
        if self.mismatch.is_none() {
            self.mismatch = Some(self.index - 1);
        }
    }
    fn u64(&mut self, value: u64) {
        match self.next() {
            Some(Column::U64(data)) => data.extend_from_slice(&value.to_le_bytes()),
            _ => self.fail(),
        }
    }
    fn f64(&mut self, value: f64) {
        match self.next() {
            Some(Column::F64(data)) => data.extend_from_slice(&value.to_le_bytes()),
            _ => self.fail(),
        }
    }
    fn vector(&mut self, value: glam::DVec3) {
        self.f64(value.x);
        self.f64(value.y);
        self.f64(value.z);
    }
    fn i64(&mut self, value: Option<i64>) {
        match self.next() {
            Some(Column::I64(data, valid)) => {
                data.extend_from_slice(&value.unwrap_or(0).to_le_bytes());
                valid.push(u8::from(value.is_some()));
            }
            _ => self.fail(),
        }
    }
    fn optional_u64(&mut self, value: Option<u64>) {
        match self.next() {
            Some(Column::OptionalU64(data, valid)) => {
                data.extend_from_slice(&value.unwrap_or(0).to_le_bytes());
                valid.push(u8::from(value.is_some()));
            }
            _ => self.fail(),
        }
    }
    fn bool(&mut self, value: bool) {
        match self.next() {
            Some(Column::Bool(data)) => data.push(u8::from(value)),
            _ => self.fail(),
        }
    }
    fn status(&mut self, value: SolverStatus) {
        let code = SolverStatus::ALL.iter().position(|s| *s == value);
        self.text(code);
    }
    /// A force-off cause: its code after the solver statuses in the one text dictionary (`text_names`).
    fn cause(&mut self, value: ForceOffCause) {
        self.text(Some(SolverStatus::ALL.len() + value as usize));
    }
    fn text(&mut self, code: Option<usize>) {
        match (self.next(), code) {
            (Some(Column::Text(data)), Some(code)) => data.push(code as u8),
            _ => self.fail(),
        }
    }
}

/// The `utc_ns` value of a sample: the run's start plus `t_s`, rounded to the nanosecond and saturating;
/// missing when `t_s` is not finite or the trace has no sidecar to date it (as voxhap's writers do).
fn utc_ns(start_utc_ns: Option<i64>, t_s: f64) -> Option<i64> {
    let start = start_utc_ns?;
    t_s.is_finite()
        .then(|| start.saturating_add((t_s * 1e9).round() as i64))
}

/// Writes one sample's values in column order (the order of [`columns`]).
fn write_row(row: &mut RowWriter<'_>, s: &TraceSample, modes: usize, start: Option<i64>) {
    row.u64(s.tick);
    row.f64(s.t_s);
    row.i64(utc_ns(start, s.t_s));
    row.vector(s.probe_m);
    row.vector(s.probe_velocity_m_per_s);
    row.vector(s.proxy_m);
    row.vector(s.rendered_force_n);
    row.vector(s.sent_force_n);
    for mode in 0..modes.min(MAX_MODES) {
        let (primitives, force_n) = s.modes.slot(mode);
        row.u64(u64::from(primitives));
        row.vector(force_n);
    }
    row.status(s.solver_status);
    row.u64(u64::from(s.sweeps));
    row.f64(s.error_bound_m);
    row.optional_u64(s.device_sequence);
    row.optional_u64(s.device_time_us);
    row.u64(u64::from(s.flags));
    for doc in FLAG_DOCS.iter() {
        row.bool(s.flags & (1 << doc.bit) != 0);
    }
    // The tick's truth (voxhap_record's truth columns, in their order).
    let energy = &s.truth.energy;
    for value in [
        energy.work_on_probe_j,
        energy.coupling_energy_j,
        energy.generated_j,
        energy.active_work_j,
        energy.device_dissipation_j,
        energy.net_generated_j,
    ] {
        row.f64(value);
    }
    row.cause(s.truth.force_off_cause);
    row.u64(u64::from(s.truth.device_fault_bits));
    row.u64(u64::from(s.truth.sample_age_ticks));
    row.f64(energy.passivity_dissipated_j);
    row.vector(s.truth.device_force_n.unwrap_or(glam::DVec3::NAN));
    for value in s.truth.external_force_n.to_array() {
        row.f64(value);
    }
    // A local-model device's own loop: NaN (sequence 0) on ticks without one.
    let local = s.truth.device_local;
    row.vector(local.map_or(glam::DVec3::NAN, |l| l.proxy_m));
    row.f64(local.map_or(f64::NAN, |l| l.proxy_bound_m));
    row.u64(local.map_or(0, |l| u64::from(l.model_sequence)));
    row.f64(local.map_or(f64::NAN, |l| l.model_age_s));
    if row.index != row.columns.len() && row.mismatch.is_none() {
        row.mismatch = Some(row.index);
    }
}

/// Reads a trace (CSV, MCAP or Parquet, also one cut off by a crash) with voxhap's own reader and returns
/// it as a dict: `columns` (a list of (name, type, data bytes, validity bytes or None)), `statuses` (the
/// solver status names the text column's bytes index), `sidecar` (JSON text or None) and `warnings` (what
/// was skipped, and what the sidecar says that the file contradicts).
#[pyfunction]
pub fn read_trace_columns<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let trace = py
        .detach(|| voxhap_record::read_trace(&path))
        .map_err(|e| PyValueError::new_err(error_chain(&e)))?;
    let docs = columns(&trace.mode_names);
    let rows = trace.samples.len();
    let start = trace.sidecar.as_ref().map(|s| s.meta.start_utc_ns);
    let modes = trace.mode_names.len();
    let mut built: Vec<Column> = docs
        .iter()
        .map(|doc| Column::new(doc.column_type, rows))
        .collect();
    let mut mismatch = None;
    for sample in &trace.samples {
        let mut row = RowWriter {
            columns: &mut built,
            index: 0,
            mismatch: None,
        };
        write_row(&mut row, sample, modes, start);
        if let Some(at) = row.mismatch {
            mismatch = Some(at);
            break;
        }
    }
    if let Some(at) = mismatch {
        return Err(PyValueError::new_err(format!(
            "voxhap._voxhap is out of step with the trace columns at column {} ({})",
            at + 1,
            docs.get(at).map_or("past the end", |d| d.name.as_ref())
        )));
    }
    let out = PyDict::new(py);
    let mut list = Vec::with_capacity(docs.len());
    for (doc, column) in docs.iter().zip(built) {
        let (data, valid) = match column {
            Column::U64(d) | Column::F64(d) | Column::Bool(d) | Column::Text(d) => (d, None),
            Column::I64(d, v) | Column::OptionalU64(d, v) => (d, Some(v)),
        };
        list.push((
            doc.name.to_string(),
            type_name(doc.column_type)?,
            PyBytes::new(py, &data),
            valid.map(|v| PyBytes::new(py, &v)),
        ));
    }
    out.set_item("columns", list)?;
    // The names the text columns' codes index: the solver statuses, then the force-off causes.
    let statuses: Vec<&str> = SolverStatus::ALL
        .iter()
        .map(|s| s.name())
        .chain(ForceOffCause::ALL.iter().map(|c| c.name()))
        .collect();
    out.set_item("statuses", statuses)?;
    let sidecar = trace
        .sidecar
        .as_ref()
        .map(serde_json::to_string)
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("cannot encode the sidecar: {e}")))?;
    out.set_item("sidecar", sidecar)?;
    out.set_item("warnings", trace.warnings)?;
    Ok(out)
}

/// The flags: (bit, name) for each, as the trace's `flag_<name>` columns and `flag_bits` carry them.
#[pyfunction]
pub fn flag_bits() -> Vec<(u32, String)> {
    FLAG_DOCS
        .iter()
        .map(|doc| (doc.bit, doc.name.to_string()))
        .collect()
}
