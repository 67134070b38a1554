//! `voxhap trace repair`: recovers what a crash left of a trace and writes it as a finished trace.
//!
//! Where it sits: after the recorder or `voxhap sim` died (SIGKILL, power loss), a CSV trace may end in a
//! partial line and an MCAP trace lacks its summary and end magic. The readers already read such files up
//! to the damage, with a warning; [`repair_trace`] reads the input that way and writes every recovered
//! sample through the normal writer into a new file (never over the input), with a sidecar that says what
//! was recovered (`repaired`) and the run's metadata from the old sidecar (or, without one, what the
//! trace itself says).

use crate::error::{error_chain, TraceError, TraceReadError};
use crate::formats::{create_trace_writer_with, read_trace};
use crate::meta::{Sidecar, TraceMeta};
use crate::output::{sidecar_path, OutputPolicy};
use std::path::{Path, PathBuf};
use voxhap_api::TraceFormat;

/// Why a repair failed.
#[derive(Debug, thiserror::Error)]
pub enum RepairError {
    /// The input could not be read even tolerantly.
    #[error("cannot read {path}")]
    Read {
        /// The input.
        path: PathBuf,
        /// Why.
        source: TraceReadError,
    },
    /// The output could not be written.
    #[error("cannot write the repaired trace")]
    Write(#[from] TraceError),
}

/// What a repair did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RepairReport {
    /// The repaired trace written.
    pub output: PathBuf,
    /// Samples recovered.
    pub sample_count: u64,
    /// What the reader skipped (empty if the input was intact).
    pub warnings: Vec<String>,
}

/// The default output of a repair: `NAME.repaired.EXT` next to the input.
pub fn default_repair_output(input: &Path) -> PathBuf {
    let stem = input
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "trace".to_owned());
    let name = match input.extension() {
        Some(ext) => format!("{stem}.repaired.{}", ext.to_string_lossy()),
        None => format!("{stem}.repaired"),
    };
    input.with_file_name(name)
}

/// Reads what `input` holds and writes it as a finished trace to `output` in `format` (default: the
/// input's format). `policy.inputs` gets `input` and its sidecar added, so the input is never replaced.
pub fn repair_trace(
    input: &Path,
    output: &Path,
    format: Option<TraceFormat>,
    policy: &OutputPolicy,
) -> Result<RepairReport, RepairError> {
    let trace = read_trace(input).map_err(|source| RepairError::Read {
        path: input.to_path_buf(),
        source,
    })?;
    let meta = match &trace.sidecar {
        Some(sidecar) => sidecar.meta.clone(),
        None => {
            let rate_hz = match trace.samples.as_slice() {
                [a, b, ..] if b.t_s > a.t_s => (b.tick - a.tick) as f64 / (b.t_s - a.t_s),
                _ => 1000.0,
            };
            let mut meta = TraceMeta::new(
                trace.mode_names.clone(),
                if rate_hz.is_finite() && rate_hz > 0.0 {
                    rate_hz
                } else {
                    1000.0
                },
                serde_json::Value::Null,
                "unknown (no sidecar)",
                "unknown (no sidecar)",
            );
            meta.start_utc_ns = 0;
            meta
        }
    };
    let format = format.unwrap_or_else(|| match trace.sidecar.as_ref() {
        Some(sidecar) => sidecar.trace_format,
        None => TraceFormat::from_path(input),
    });
    let mut policy = policy.clone();
    policy.inputs.push(input.to_path_buf());
    policy.inputs.push(sidecar_path(input));
    let mut writer = create_trace_writer_with(output, format, &meta, &policy)?;
    for sample in &trace.samples {
        writer.write_sample(sample)?;
    }
    let summary = writer.finish()?;
    let note = if trace.warnings.is_empty() {
        format!(
            "rewritten from {} ({} samples; nothing was damaged)",
            input.display(),
            summary.sample_count
        )
    } else {
        format!(
            "recovered {} samples from {}: {}",
            summary.sample_count,
            input.display(),
            trace.warnings.join("; ")
        )
    };
    let mut sidecar: Sidecar =
        serde_json::from_slice(&std::fs::read(&summary.sidecar_path).map_err(|source| {
            TraceError::Io {
                path: summary.sidecar_path.clone(),
                source,
            }
        })?)
        .map_err(|e| {
            TraceError::Meta(format!(
                "cannot re-read the new sidecar: {}",
                error_chain(&e)
            ))
        })?;
    sidecar.repaired = Some(note);
    if let Some(old) = &trace.sidecar {
        sidecar.error = old.error.clone();
    }
    sidecar.write(&summary.sidecar_path)?;
    Ok(RepairReport {
        output: summary.trace_path,
        sample_count: summary.sample_count,
        warnings: trace.warnings,
    })
}
