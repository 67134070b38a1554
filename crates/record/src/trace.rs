//! A trace read back ([`Trace`]), the checks of its sidecar against its data ([`sidecar_warnings`]),
//! and opening trace files safely (regular files only).

use crate::columns::columns;
use crate::error::TraceReadError;
use crate::meta::{Sidecar, TRACE_FORMAT_VERSION};
use crate::output::sidecar_path;
use crate::sample::TraceSample;
use std::path::Path;
use voxhap_api::TraceFormat;

/// A trace read back from disk.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// Mode names, in column order.
    pub mode_names: Vec<String>,
    /// The samples in file order.
    pub samples: Vec<TraceSample>,
    /// The sidecar, when `TRACE.json` exists.
    pub sidecar: Option<Sidecar>,
    /// What the reader skipped and why (a partial last CSV line, an unfinished MCAP chunk after a
    /// crash); empty for a cleanly finished trace. Callers show these to the user.
    pub warnings: Vec<String>,
}

/// What a trace's sidecar says that its data contradict, one warning each (empty when it tells the
/// truth, or when there is no sidecar): the sample count (of a finished trace, or of one whose sidecar
/// records the error that stopped it; a sidecar still provisional, `complete: false` without an error,
/// has no final count to check), the mode names, the columns, the format and the trace format version
/// (not `trace_file`: a trace and sidecar renamed together are still honest). The readers add these to `Trace::warnings`, which `voxhap plot`, `voxhap trace`, replay
/// and `voxhap compare` print on stderr: a lying sidecar is never trusted silently.
pub fn sidecar_warnings(
    sidecar: Option<&Sidecar>,
    path: &Path,
    format: TraceFormat,
    mode_names: &[String],
    sample_count: u64,
) -> Vec<String> {
    let Some(sidecar) = sidecar else {
        return Vec::new();
    };
    let mut warnings = Vec::new();
    let mut warn = |what: String| {
        warnings.push(format!(
            "{}: the sidecar {} does not match the trace: {what}; the trace's data are used",
            path.display(),
            sidecar_path(path).display()
        ))
    };
    if (sidecar.complete || sidecar.error.is_some()) && sidecar.sample_count != sample_count {
        warn(format!(
            "it says {} samples, the trace holds {sample_count}",
            sidecar.sample_count
        ));
    }
    if sidecar.meta.mode_names != mode_names {
        warn(format!(
            "it names the modes {:?}, the trace has {:?}",
            sidecar.meta.mode_names, mode_names
        ));
    } else if sidecar.columns != columns(mode_names) {
        warn("its column list differs from the trace's columns".to_owned());
    }
    if sidecar.trace_format != format {
        warn(format!(
            "it says trace_format {}, the file is {format}",
            sidecar.trace_format
        ));
    }
    if sidecar.meta.format_version != TRACE_FORMAT_VERSION {
        warn(format!(
            "it says format_version {}, this reader reads {TRACE_FORMAT_VERSION}",
            sidecar.meta.format_version
        ));
    }
    warnings
}

/// A streaming reader: hands every sample of the trace at the path to the sink, and returns the trace without
/// its samples and how many there were.
pub(crate) type ForEachSample =
    fn(&Path, &mut dyn FnMut(&TraceSample)) -> Result<(Trace, u64), TraceReadError>;

/// A whole trace from a streaming reader (`for_each(path, sink)` hands every sample to `sink` and returns the
/// trace without its samples): the samples collected.
pub(crate) fn collect_samples(
    path: &Path,
    for_each: ForEachSample,
) -> Result<Trace, TraceReadError> {
    let mut samples = Vec::new();
    let (mut trace, _) = for_each(path, &mut |sample| samples.push(*sample))?;
    trace.samples = samples;
    Ok(trace)
}

/// Opens a trace (or sidecar) for reading: a regular file only, so a FIFO or a device (`replay:/dev/zero`)
/// is refused at once instead of blocking or reading without end.
pub(crate) fn open_trace_file(path: &Path) -> Result<(std::fs::File, u64), TraceReadError> {
    voxhap_io::open_regular(path).map_err(|error| TraceReadError::Io {
        path: path.to_path_buf(),
        source: match error {
            voxhap_io::FileError::Io(source) => source,
            other => std::io::Error::new(std::io::ErrorKind::InvalidInput, other.to_string()),
        },
    })
}

/// Reads a whole trace file (a regular file; its size bounds the read).
pub(crate) fn read_trace_file(path: &Path) -> Result<Vec<u8>, TraceReadError> {
    use std::io::Read;
    let (file, size_bytes) = open_trace_file(path)?;
    let mut bytes = Vec::with_capacity(usize::try_from(size_bytes).unwrap_or(0));
    file.take(size_bytes)
        .read_to_end(&mut bytes)
        .map_err(|source| TraceReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(bytes)
}
