//! Run metadata ([`TraceMeta`]) and the JSON sidecar ([`Sidecar`]) written next to every trace.
//!
//! The sidecar `TRACE.json` repeats the metadata and makes the trace self-describing: the columns with
//! their units and types, the flag bits, the format, and (once the writer finished) the sample count. A
//! writer that fails says so in the sidecar (`complete: false` and `error`), rewriting it in place: the
//! provisional sidecar is padded with spaces so that the final one fits even on a full disk.
//! `created_utc` and `start_utc_ns` are the only fields that depend on the wall clock.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::columns::{columns, ColumnDoc};
use crate::error::TraceError;
use crate::flags::{FlagDoc, FLAG_DOCS};
use crate::output::sidecar_path;
use voxhap_api::TraceFormat;
use voxhap_core::haptics::modes::MAX_MODES;

/// Version of the trace layout (columns, topics, sidecar keys); bumped on incompatible changes.
/// Version 2 added the velocity, rendered force, per-mode force, solver status, device sequence and time,
/// UTC and per-flag columns and renamed `flags` to `flag_bits`. Version 3 added the tick's truth after the
/// flag columns: the energy ledger, the force-off cause, the device's fault bits and the age of the rendered
/// sample. Version 4 added, after those, what the passivity controller dissipated, the force the device
/// itself reports (`device_force_<axis>_n`, NaN where none) and the external force added to the rendered
/// force (`external_force_<axis>_n`). Version 5 (this one) added, after those, what a local-model device
/// reported of its own loop (`device_proxy_<axis>_m`, `device_proxy_bound_m`, `local_model_age_s`: NaN
/// where none; `local_model_sequence`: 0 where none).
pub const TRACE_FORMAT_VERSION: u32 = 5;

/// What a run was: written into the sidecar and the MCAP metadata record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceMeta {
    /// [`TRACE_FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// The voxhap version that wrote the trace.
    pub voxhap_version: String,
    /// When the trace was created, RFC 3339 UTC (`2026-01-31T12:00:00Z`). The only non-deterministic field.
    pub created_utc: String,
    /// Wall-clock UTC at the run's `t_s = 0`, ns since 1970: each tick's `utc_ns` is this plus its `t_s`.
    #[serde(default)]
    pub start_utc_ns: i64,
    /// Servo rate (Hz).
    pub rate_hz: f64,
    /// The haptic modes, in the order of `TraceSample::modes`. At most [`MAX_MODES`];
    /// each name is non-empty ASCII letters, digits, `_` or `-`, and names are unique.
    pub mode_names: Vec<String>,
    /// The scenario that ran, as given (any JSON).
    pub scenario: serde_json::Value,
    /// The volume(s) rendered, e.g. a file path or `procedural:sphere`.
    pub volume: String,
    /// The solver and its settings, e.g. `exact-dual`.
    pub solver: String,
}

impl TraceMeta {
    /// Metadata for a run starting now: fills `format_version`, `voxhap_version` and `created_utc`.
    pub fn new(
        mode_names: Vec<String>,
        rate_hz: f64,
        scenario: serde_json::Value,
        volume: impl Into<String>,
        solver: impl Into<String>,
    ) -> Self {
        TraceMeta {
            format_version: TRACE_FORMAT_VERSION,
            voxhap_version: env!("CARGO_PKG_VERSION").to_string(),
            created_utc: utc_now_rfc3339(),
            start_utc_ns: utc_now_ns(),
            rate_hz,
            mode_names,
            scenario,
            volume: volume.into(),
            solver: solver.into(),
        }
    }

    /// Checks the rate and the mode names.
    pub fn validate(&self) -> Result<(), TraceError> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(TraceError::Meta(format!(
                "rate_hz = {} must be finite and > 0",
                self.rate_hz
            )));
        }
        if self.mode_names.len() > MAX_MODES {
            return Err(TraceError::Meta(format!(
                "{} modes, at most {MAX_MODES} can be recorded",
                self.mode_names.len()
            )));
        }
        for (i, name) in self.mode_names.iter().enumerate() {
            if !is_valid_mode_name(name) {
                return Err(TraceError::Meta(format!(
                    "mode name {name:?} must be non-empty ASCII letters, digits, '_' or '-'"
                )));
            }
            if self.mode_names[..i].contains(name) {
                return Err(TraceError::Meta(format!(
                    "mode name {name:?} appears twice"
                )));
            }
        }
        Ok(())
    }
}

pub(crate) fn is_valid_mode_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// What a finished trace wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TraceSummary {
    /// The trace file.
    pub trace_path: PathBuf,
    /// Its JSON sidecar.
    pub sidecar_path: PathBuf,
    /// Samples written.
    pub sample_count: u64,
}

/// The JSON sidecar `TRACE.json`: the metadata plus what a reader needs to interpret the trace.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    /// The run's metadata (its keys appear at the top level of the JSON object).
    #[serde(flatten)]
    pub meta: TraceMeta,
    /// `csv` or `mcap`.
    pub trace_format: TraceFormat,
    /// File name of the trace this sidecar describes.
    pub trace_file: String,
    /// `false` while the run is recording (or if it died), `true` once the writer finished.
    pub complete: bool,
    /// Samples in the trace (final once `complete`).
    pub sample_count: u64,
    /// Samples the writer left out because their tick did not increase (a producer bug; normally 0).
    #[serde(default)]
    pub samples_rejected: u64,
    /// Why the recording stopped early (the writer's error with the OS reason), if it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// What `voxhap trace repair` did to this trace, if it was repaired.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub repaired: Option<String>,
    /// The columns (CSV, Parquet) in order, with units and types.
    pub columns: Vec<ColumnDoc>,
    /// The flag bits.
    pub flag_bits: Vec<FlagDoc>,
}

impl Sidecar {
    pub(crate) fn new(meta: &TraceMeta, format: TraceFormat, trace_path: &Path) -> Self {
        Sidecar {
            meta: meta.clone(),
            trace_format: format,
            trace_file: trace_path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            complete: false,
            sample_count: 0,
            samples_rejected: 0,
            error: None,
            repaired: None,
            columns: columns(&meta.mode_names),
            flag_bits: FLAG_DOCS.to_vec(),
        }
    }

    /// Marks the trace complete with `sample_count` samples, writes the sidecar next to `trace_path`, and returns
    /// the summary every writer's `finish` reports.
    pub(crate) fn complete(
        &mut self,
        trace_path: &Path,
        sample_count: u64,
    ) -> Result<TraceSummary, TraceError> {
        self.complete = true;
        self.sample_count = sample_count;
        let sidecar_path = sidecar_path(trace_path);
        self.write(&sidecar_path)?;
        Ok(TraceSummary {
            trace_path: trace_path.to_path_buf(),
            sidecar_path,
            sample_count,
        })
    }

    /// Marks the trace as stopped early by `error` after `sample_count` samples and rewrites the sidecar.
    pub(crate) fn fail(
        &mut self,
        trace_path: &Path,
        sample_count: u64,
        error: &str,
    ) -> Result<(), TraceError> {
        self.complete = false;
        self.sample_count = sample_count;
        let mut error = error.to_owned();
        if error.len() > MAX_ERROR_TEXT {
            let mut end = MAX_ERROR_TEXT;
            while !error.is_char_boundary(end) {
                end -= 1;
            }
            error.truncate(end);
        }
        self.error = Some(error);
        self.write(&sidecar_path(trace_path))
    }

    /// The sidecar of a trace about to be written at `trace_path`, its first (provisional) version written
    /// into a new file beside it ([`Self::write_new`]).
    pub(crate) fn create(
        meta: &TraceMeta,
        format: TraceFormat,
        trace_path: &Path,
    ) -> Result<Self, TraceError> {
        let sidecar = Sidecar::new(meta, format, trace_path);
        sidecar.write_new(&sidecar_path(trace_path))?;
        Ok(sidecar)
    }

    /// Writes the first (provisional) sidecar into a new file at `path` (never over an existing file, never
    /// through a symlink).
    pub(crate) fn write_new(&self, path: &Path) -> Result<(), TraceError> {
        let file = crate::output::create_new_file(path)?;
        self.write_into(file, path)
    }

    /// Writes the sidecar as pretty JSON with a final newline, in place: the file is overwritten from the
    /// start and only then cut to length, so rewriting a sidecar no longer than the padded first version
    /// needs no new disk space. The first version is padded with [`SIDECAR_RESERVE`] spaces for that. The
    /// file must exist ([`Sidecar::write_new`] made it) and is not opened through a symlink.
    pub(crate) fn write(&self, path: &Path) -> Result<(), TraceError> {
        let file = crate::output::open_existing_output(path)?;
        self.write_into(file, path)
    }

    fn write_into(&self, mut file: std::fs::File, path: &Path) -> Result<(), TraceError> {
        use std::io::{Seek, Write};
        let mut text = serde_json::to_string_pretty(self)
            .map_err(|e| TraceError::Meta(format!("cannot encode the sidecar: {e}")))?;
        text.push('\n');
        let io_error = |source| TraceError::Io {
            path: path.to_path_buf(),
            source,
        };
        let old_len = file.metadata().map_err(io_error)?.len();
        if !self.complete && self.error.is_none() && self.sample_count == 0 {
            // The provisional sidecar: reserve room for the final one.
            text.extend(std::iter::repeat_n(' ', SIDECAR_RESERVE));
            text.push('\n');
        }
        file.seek(std::io::SeekFrom::Start(0)).map_err(io_error)?;
        file.write_all(text.as_bytes()).map_err(io_error)?;
        if old_len > text.len() as u64 {
            file.set_len(text.len() as u64).map_err(io_error)?;
        }
        file.sync_data().map_err(io_error)
    }
}

/// Spaces after the provisional sidecar's JSON (valid JSON whitespace), so the final sidecar (with an
/// error message of up to [`MAX_ERROR_TEXT`] bytes) fits in the space already allocated.
const SIDECAR_RESERVE: usize = 1024;
/// The longest error text a sidecar keeps.
const MAX_ERROR_TEXT: usize = 600;

/// The current time as RFC 3339 UTC with whole seconds, e.g. `2026-01-31T12:00:00Z`.
pub(crate) fn utc_now_rfc3339() -> String {
    let seconds = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    format_utc(seconds)
}

/// The current time as ns since 1970 (UTC), 0 if the clock is before 1970.
pub fn utc_now_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

/// Formats seconds since 1970 as RFC 3339 UTC (Howard Hinnant's days-to-civil algorithm).
fn format_utc(seconds: u64) -> String {
    let days = (seconds / 86_400) as i64;
    let second_of_day = seconds % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let day_of_era = z.rem_euclid(146_097);
    let year_of_era =
        (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let month_index = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * month_index + 2) / 5 + 1;
    let month = if month_index < 10 {
        month_index + 3
    } else {
        month_index - 9
    };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        second_of_day / 3600,
        second_of_day / 60 % 60,
        second_of_day % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_formatting_matches_known_dates() {
        assert_eq!(format_utc(0), "1970-01-01T00:00:00Z");
        assert_eq!(format_utc(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(format_utc(1_700_000_000), "2023-11-14T22:13:20Z");
        assert_eq!(format_utc(4_102_444_799), "2099-12-31T23:59:59Z");
    }

    #[test]
    fn sidecar_path_appends_json() {
        assert_eq!(
            sidecar_path(Path::new("out/run.csv")),
            PathBuf::from("out/run.csv.json")
        );
    }

    #[test]
    fn bad_metadata_is_rejected_with_a_reason() {
        let mut meta = TraceMeta::new(
            vec!["surface".into()],
            1000.0,
            serde_json::Value::Null,
            "",
            "",
        );
        assert!(meta.validate().is_ok());
        meta.mode_names.push("bad name".into());
        assert!(meta
            .validate()
            .unwrap_err()
            .to_string()
            .contains("bad name"));
        meta.mode_names = vec!["a".into(), "a".into()];
        assert!(meta.validate().unwrap_err().to_string().contains("twice"));
        meta.mode_names = (0..=MAX_MODES).map(|i| format!("m{i}")).collect();
        assert!(meta.validate().is_err());
        meta.mode_names.clear();
        meta.rate_hz = f64::NAN;
        assert!(meta.validate().unwrap_err().to_string().contains("rate_hz"));
    }
}
