//! Force traces: one record per servo tick, written as CSV or MCAP with a JSON sidecar, and read back.
//!
//! Where it sits (docs/design.md, "Threads"): the servo thread fills a [`TraceSample`] every tick (a `Copy`
//! struct with no heap data, so it can travel through an SPSC ring without allocating) and the recorder
//! thread drains the ring into a [`TraceWriter`] made by [`create_trace_writer`]. A trace `TRACE` always
//! comes with a sidecar `TRACE.json` ([`Sidecar`]: the run's metadata, column units and flag bits).
//! Replay, `voxhap compare`, `voxhap trace` and the tests read any trace back with [`read_trace`] (the format
//! from the file's first bytes) or [`read_trace_as`]; `voxhap plot` reads it in batches ([`plot`]).
//!
//! Determinism: everything written is a function of the samples and the [`TraceMeta`], and only
//! `TraceMeta::created_utc` and an MCAP trace's log times (wall-clock UTC, so recordings line up with other
//! instruments) depend on the wall clock, so two runs of the same scenario write identical files apart from
//! those. Floats are written in shortest round-trip form, so reading a CSV trace
//! gives back the exact bits written.

mod cell;
mod columns;
pub mod compare;
mod csv;
mod error;
mod flags;
mod formats;
pub mod foxglove_scene;
mod mcap_check;
mod mcap_read;
mod mcap_stream;
mod mcap_trace;
mod meta;
mod output;
mod parquet_limits;
mod parquet_read;
mod parquet_recover;
mod parquet_schema;
mod parquet_trace;
pub mod plot;
pub mod repair;
mod sample;
#[cfg(test)]
mod test_support;
mod trace;
mod truth_columns;
mod writer;

pub use self::columns::{columns, ColumnDoc, ColumnType};
pub use self::csv::{parse_csv_trace, CsvTraceWriter};
pub use self::error::{error_chain, ParquetProblem, TraceError, TraceReadError};
pub use self::flags::{FlagDoc, FLAG_COUNT, FLAG_DOCS};
pub use self::formats::{
    create_trace_writer, create_trace_writer_with, estimate_trace_bytes, read_trace, read_trace_as,
};
pub use self::mcap_read::parse_mcap_trace;
pub use self::mcap_trace::{McapTraceWriter, SOLVER_TOPIC, STATE_TOPIC};
pub use self::meta::{utc_now_ns, Sidecar, TraceMeta, TraceSummary, TRACE_FORMAT_VERSION};
pub use self::output::{
    check_output_path, create_new_file, create_or_replace_file, sidecar_path, OutputPolicy,
};
pub use self::parquet_schema::SIDECAR_KEY as PARQUET_SIDECAR_KEY;
pub use self::parquet_trace::ParquetTraceWriter;
pub use self::sample::{SolverStatus, TraceSample};
pub use self::trace::{sidecar_warnings, Trace};
pub use self::writer::TraceWriter;
pub use voxhap_api::{ForceOffCause, TickEnergy, TickTruth};

pub use voxhap_api::TraceFormat;
pub use voxhap_core::haptics::modes::MAX_MODES;
pub use voxhap_core::haptics::tick::ModeBreakdown;
pub use voxhap_core::status::flags::*;
