//! Errors of the trace writers ([`TraceError`]) and readers ([`TraceReadError`]). Each names what went
//! wrong and where: the tick for a bad sample, the file, line and column for a bad trace. Errors that
//! wrap a lower-level error (I/O, MCAP, JSON) chain it as `source()` rather than repeating it in their
//! message; print them with `{:#}` (anyhow) or walk the chain.

use std::path::PathBuf;

/// Why a trace could not be written.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// Creating, writing or flushing a file failed.
    #[error("cannot write the trace file {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The MCAP library refused a record.
    #[error("cannot write the MCAP trace {path}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The library's error.
        source: mcap::McapError,
    },
    /// The Parquet library refused to write.
    #[error("cannot write the Parquet trace {path}")]
    Parquet {
        /// The file.
        path: PathBuf,
        /// The library's error.
        source: parquet::errors::ParquetError,
    },
    /// The run metadata is unusable.
    #[error("trace metadata: {0}")]
    Meta(String),
    /// A sample's `mode_count` differs from the number of mode names in the metadata.
    #[error("trace sample at tick {tick}: mode_count {found} but the trace has {expected} modes")]
    ModeCountMismatch {
        /// Tick of the sample.
        tick: u64,
        /// Modes named in the metadata.
        expected: usize,
        /// The sample's `mode_count`.
        found: usize,
    },
    /// Tick numbers must strictly increase.
    #[error("trace sample at tick {tick} follows tick {previous}: ticks must strictly increase")]
    TickOrder {
        /// The previous sample's tick.
        previous: u64,
        /// This sample's tick.
        tick: u64,
    },
    /// A position, force or time is NaN or infinite.
    #[error("trace sample at tick {tick}: {field} is not finite")]
    NonFinite {
        /// Tick of the sample.
        tick: u64,
        /// The field.
        field: &'static str,
    },
    /// Time is negative.
    #[error("trace sample at tick {tick}: t_s = {t_s} is negative")]
    NegativeTime {
        /// Tick of the sample.
        tick: u64,
        /// The time given (s).
        t_s: f64,
    },
    /// The certificate bound is NaN or negative.
    #[error("trace sample at tick {tick}: error_bound_m = {value} must be >= 0 (or +inf)")]
    InvalidErrorBound {
        /// Tick of the sample.
        tick: u64,
        /// The bound given (m).
        value: f64,
    },
    /// `write_sample` or `finish` after `finish`.
    #[error("trace writer already finished")]
    Finished,
    /// The output exists and overwriting was not asked for.
    #[error("{path} exists; pass --force to replace it")]
    Exists {
        /// The existing file.
        path: PathBuf,
    },
    /// The output path's last component is a symbolic link (dangling or not); outputs are never written
    /// through one.
    #[error(
        "{path} is a symbolic link; voxhap never writes a trace or sidecar through one, even with --force: \
         remove it or name the real file"
    )]
    Symlink {
        /// The link.
        path: PathBuf,
    },
    /// The output is one of the run's inputs (same file, perhaps by another name).
    #[error(
        "{path} is an input of this run ({input}); it is never overwritten, even with --force"
    )]
    IsInput {
        /// The output asked for.
        path: PathBuf,
        /// The input it is the same file as.
        input: PathBuf,
    },
}

impl TraceError {
    /// A write error on the trace file (or sidecar) at `path`.
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        TraceError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// An error and its sources joined with `: `, as `voxhap` prints them (`cannot write the trace file
/// x.csv: No space left on device (os error 28)`).
pub fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(inner) = source {
        text.push_str(": ");
        text.push_str(&inner.to_string());
        source = inner.source();
    }
    text
}

/// Why a trace could not be read.
#[derive(Debug, thiserror::Error)]
pub enum TraceReadError {
    /// Opening or reading the file failed.
    #[error("cannot read {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file has no header line.
    #[error("CSV trace is empty: no header line")]
    Empty,
    /// The trace was written by a voxhap with an older trace layout.
    #[error("{path}: written by an older voxhap (trace format {found}, {hint}); this voxhap reads trace format {expected}: record it again")]
    OldFormat {
        /// The file.
        path: PathBuf,
        /// The format version the file has.
        found: u32,
        /// The version this reader reads.
        expected: u32,
        /// How it was recognised.
        hint: &'static str,
    },
    /// The header does not have the expected columns.
    #[error("CSV trace line 1, column {column}: expected {expected}, found {found:?}")]
    Header {
        /// 1-based column.
        column: usize,
        /// What was expected there.
        expected: String,
        /// What the file has (empty when the line ends early).
        found: String,
    },
    /// A row has the wrong number of fields.
    #[error("CSV trace line {line}: {found} fields, expected {expected}")]
    FieldCount {
        /// 1-based line.
        line: usize,
        /// Columns in the header.
        expected: usize,
        /// Fields on the line.
        found: usize,
    },
    /// A field does not parse or breaks a trace rule.
    #[error("CSV trace line {line}, column {column} ({name}): {problem}: {value:?}")]
    Field {
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// Column name.
        name: String,
        /// The text of the field.
        value: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A line is not UTF-8 text.
    #[error("CSV trace line {line}: not UTF-8 text")]
    NotText {
        /// 1-based line.
        line: usize,
    },
    /// The sidecar `TRACE.json` exists but does not parse.
    #[error("cannot parse the trace sidecar {path}")]
    Sidecar {
        /// The sidecar file.
        path: PathBuf,
        /// The JSON error (with its line and column).
        source: serde_json::Error,
    },
    /// The MCAP file is damaged or not a voxhap trace.
    #[error("MCAP trace {path}: {problem}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// The Parquet file is damaged or not a voxhap trace.
    #[error("Parquet trace {path}: {problem}")]
    Parquet {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: Box<ParquetProblem>,
    },
}

/// What is wrong with a Parquet trace (the problem of [`TraceReadError::Parquet`]).
#[derive(Debug, thiserror::Error)]
pub enum ParquetProblem {
    /// Neither a final footer nor the `PAR1` start of a Parquet file.
    #[error("not a Parquet file ({0})")]
    NotParquet(parquet::errors::ParquetError),
    /// A file cut off before its first complete row group, with no sidecar to name its modes.
    #[error("no complete row group and no sidecar to name its modes")]
    NothingToRead,
    /// The Parquet library refused the file.
    #[error(transparent)]
    Library(#[from] parquet::errors::ParquetError),
    /// The Arrow decoder refused a batch.
    #[error(transparent)]
    Arrow(#[from] arrow_schema::ArrowError),
    /// Reading the file failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A column chunk the footer describes does not lie inside the file.
    #[error(
        "row group {group}, column {column}: {compressed} bytes at offset {start} run past the end of the \
         {file_bytes}-byte file"
    )]
    ChunkPastEnd {
        /// Row group (0-based).
        group: usize,
        /// Column (0-based).
        column: usize,
        /// Compressed bytes claimed.
        compressed: u64,
        /// Where the chunk starts.
        start: u64,
        /// The file's real size.
        file_bytes: u64,
    },
    /// A column chunk claims more uncompressed bytes than its compressed bytes can hold.
    #[error(
        "row group {group}, column {column}: claims {uncompressed} uncompressed bytes from {compressed} \
         compressed (more than a {ratio}:1 expansion)"
    )]
    ChunkExpansion {
        /// Row group (0-based).
        group: usize,
        /// Column (0-based).
        column: usize,
        /// Uncompressed bytes claimed.
        uncompressed: u64,
        /// Compressed bytes claimed.
        compressed: u64,
        /// The largest expansion accepted.
        ratio: u64,
    },
    /// A page header claims more uncompressed bytes than its compressed bytes can hold: decoding it would
    /// allocate what the file cannot justify.
    #[error(
        "row group {group}, column {column}, page at offset {offset}: its header claims {uncompressed} \
         uncompressed bytes from {compressed} compressed (more than a {ratio}:1 expansion)"
    )]
    PageExpansion {
        /// Row group (0-based).
        group: usize,
        /// Column (0-based).
        column: usize,
        /// Where the page header starts in the file.
        offset: u64,
        /// Uncompressed bytes claimed.
        uncompressed: u64,
        /// Compressed bytes claimed.
        compressed: u64,
        /// The largest expansion accepted.
        ratio: u64,
    },
    /// A page runs past the end of its column chunk.
    #[error(
        "row group {group}, column {column}, page at offset {offset}: {compressed} compressed bytes run \
         past the end of the column chunk at offset {chunk_end}"
    )]
    PagePastChunk {
        /// Row group (0-based).
        group: usize,
        /// Column (0-based).
        column: usize,
        /// Where the page header starts in the file.
        offset: u64,
        /// Compressed bytes claimed.
        compressed: u64,
        /// Where the column chunk ends.
        chunk_end: u64,
    },
    /// A page header that does not decode.
    #[error("row group {group}, column {column}, page header at offset {offset}: {problem}")]
    PageHeader {
        /// Row group (0-based).
        group: usize,
        /// Column (0-based).
        column: usize,
        /// Where the page header starts in the file.
        offset: u64,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// A column named or typed otherwise than a voxhap trace's.
    #[error("column {index} is {found} ({found_type}), expected {expected} ({expected_type})")]
    ColumnMismatch {
        /// 1-based column.
        index: usize,
        /// The file's column name.
        found: String,
        /// The file's column type.
        found_type: arrow_schema::DataType,
        /// The name expected there.
        expected: String,
        /// The type expected there.
        expected_type: arrow_schema::DataType,
    },
    /// The file has fewer columns than the trace's.
    #[error("column {index} missing, expected {expected}")]
    ColumnMissing {
        /// 1-based column.
        index: usize,
        /// The name expected there.
        expected: String,
    },
    /// The file has more columns than the trace's.
    #[error("{found} columns, expected {expected}")]
    ColumnCount {
        /// Columns in the file.
        found: usize,
        /// Columns of a trace with these modes.
        expected: usize,
    },
    /// A `primitives_<mode>` column whose mode name is invalid or repeated.
    #[error("column {0:?}: not a unique valid mode name")]
    BadModeColumn(String),
    /// More modes than a trace can hold.
    #[error("{count} modes, at most {max}")]
    TooManyModes {
        /// Modes in the file.
        count: usize,
        /// The most a trace holds.
        max: usize,
    },
    /// The first column is not `tick`.
    #[error("not a voxhap trace: the first column is not tick")]
    NotVoxhap,
    /// A column whose Arrow type no trace column has.
    #[error("column {column}: unexpected type {data_type}")]
    UnexpectedType {
        /// 1-based column.
        column: usize,
        /// Its type.
        data_type: arrow_schema::DataType,
    },
    /// A `solver_status` or `force_off_cause` that names no status or cause.
    #[error("row {row}: {status:?} is neither a solver status nor a force-off cause")]
    UnknownStatus {
        /// 1-based row.
        row: usize,
        /// The text found.
        status: String,
    },
    /// A cell that does not fit its column (a missing value, a flag that contradicts `flag_bits`).
    #[error("row {row}, column {column} ({name}): {problem}")]
    BadCell {
        /// 1-based row.
        row: usize,
        /// 1-based column.
        column: usize,
        /// Column name.
        name: String,
        /// What is wrong.
        problem: &'static str,
    },
    /// A row that breaks a trace rule (tick order, mode count).
    #[error("row {row}: {rule}")]
    BadSample {
        /// 1-based row.
        row: usize,
        /// The rule broken.
        rule: TraceError,
    },
}
