//! Reading an MCAP trace back: the mode names from the metadata record, the samples from the state and
//! solver channels joined by tick, after [`crate::mcap_check`] has checked the file's structure.

use crate::csv::read_sidecar;
use crate::error::{TraceError, TraceReadError};
use crate::mcap_check::check_record_lengths;
#[cfg(doc)]
use crate::mcap_trace::McapTraceWriter;
use crate::mcap_trace::{METADATA_NAME, SOLVER_TOPIC, STATE_TOPIC};
use crate::meta::TRACE_FORMAT_VERSION;
use crate::output::sidecar_path;
use crate::sample::{SolverStatus, TraceSample};
use crate::trace::Trace;
use glam::DVec3;
use serde::Deserialize;
use std::collections::VecDeque;
use std::path::Path;
use voxhap_api::TraceFormat;
use voxhap_core::haptics::modes::MAX_MODES;

/// What is wrong with the content of an MCAP trace whose structure passed the checks.
#[derive(Debug, thiserror::Error)]
pub enum McapContentError {
    /// The mcap library refused a record.
    #[error("{0}")]
    Library(#[from] mcap::McapError),
    #[error("metadata record has no format_version")]
    NoFormatVersion,
    #[error("metadata record has no mode_names")]
    NoModeNames,
    #[error("metadata mode_names: {0}")]
    BadModeNames(serde_json::Error),
    #[error("{count} modes, at most {MAX_MODES}")]
    TooManyModes { count: usize },
    #[error("no {METADATA_NAME:?} metadata record: not a voxhap trace")]
    NotVoxhap,
    #[error("{topic} message {sequence}: {source}")]
    BadMessage {
        topic: &'static str,
        sequence: u32,
        source: serde_json::Error,
    },
    #[error("{states} state messages but {solvers} solver messages")]
    Unpaired { states: usize, solvers: usize },
    #[error("state tick {state_tick} (t_s {state_t_s}) paired with solver tick {solver_tick} (t_s {solver_t_s:?})")]
    Mismatched {
        state_tick: u64,
        state_t_s: f64,
        solver_tick: u64,
        solver_t_s: Option<f64>,
    },
    /// A mode's entry in a per-mode map of the solver message (`what`: "primitive count", "mode force") is
    /// missing or not valid.
    #[error("tick {tick}: no valid {what} for {mode}")]
    NoModeValue {
        tick: u64,
        what: &'static str,
        mode: String,
    },
    /// A name field of the solver message (`field`: `solver_status`, `force_off_cause`) names nothing known.
    #[error("tick {tick}: unknown {field} {name:?}")]
    UnknownName {
        tick: u64,
        field: &'static str,
        name: String,
    },
    /// A sample that breaks a trace rule.
    #[error("{0}")]
    Sample(#[from] TraceError),
}

/// A vector as read back: `null` (a non-finite value written by JSON) becomes NaN.
type ReadVector = [Option<f64>; 3];

fn read_vector(v: ReadVector) -> DVec3 {
    DVec3::from_array(v.map(|x| x.unwrap_or(f64::NAN)))
}

#[derive(Deserialize)]
struct StateMessageOwned {
    tick: u64,
    t_s: Option<f64>,
    probe_m: ReadVector,
    probe_velocity_m_per_s: ReadVector,
    proxy_m: ReadVector,
    rendered_force_n: ReadVector,
    force_n: ReadVector,
}

#[derive(Deserialize)]
struct SolverMessageOwned {
    tick: u64,
    t_s: Option<f64>,
    primitives: serde_json::Map<String, serde_json::Value>,
    mode_force_n: serde_json::Map<String, serde_json::Value>,
    solver_status: String,
    sweeps: u32,
    error_bound_m: Option<f64>,
    device_sequence: Option<u64>,
    device_time_us: Option<u64>,
    flag_bits: u32,
    truth: crate::truth_columns::TruthMessageOwned,
}

/// Reads an MCAP trace written by [`McapTraceWriter`] (mode names from the metadata record, samples
/// from the two channels joined by tick), and its sidecar when `path.json` exists, handing each sample to
/// `sink` in file order. A file the writer never finished (no end magic: a crash) is read up to its last
/// complete chunk, with a warning. The file's bytes are held (MCAP's checks and the mcap crate read it from
/// memory), its decoded samples and messages are not (`voxhap plot` reads the file one record at a time
/// instead, [`crate::mcap_stream`]). Returns the trace without its samples, and how many were read.
pub(crate) fn for_each_mcap_sample(
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<(Trace, u64), TraceReadError> {
    let bytes = crate::trace::read_trace_file(path)?;
    let (mode_names, count, warnings) = parse_mcap_bytes(&bytes, path, sink)?;
    drop(bytes);
    trace_without_samples(path, mode_names, count, warnings)
}

/// The trace read from `path` without its samples: its mode names and warnings, its sidecar, and the warnings
/// the sidecar gives for `count` samples read; with `count`.
pub(crate) fn trace_without_samples(
    path: &Path,
    mode_names: Vec<String>,
    count: u64,
    warnings: Vec<String>,
) -> Result<(Trace, u64), TraceReadError> {
    let sidecar = read_sidecar(&sidecar_path(path))?;
    let mut trace = Trace {
        mode_names,
        samples: Vec::new(),
        sidecar,
        warnings,
    };
    trace.warnings.extend(crate::trace::sidecar_warnings(
        trace.sidecar.as_ref(),
        path,
        TraceFormat::Mcap,
        &trace.mode_names,
        count,
    ));
    Ok((trace, count))
}

/// Parses an MCAP trace held in memory; returns the mode names and the samples (as
/// [`crate::csv::parse_csv_trace`] does for CSV).
pub fn parse_mcap_trace(bytes: &[u8]) -> Result<(Vec<String>, Vec<TraceSample>), TraceReadError> {
    let mut samples = Vec::new();
    let (modes, _, _) = parse_mcap_bytes(bytes, Path::new("<input>"), &mut |sample| {
        samples.push(*sample)
    })?;
    Ok((modes, samples))
}

/// The mode names, the count of samples handed to the sink, and the warnings.
type Parsed = (Vec<String>, u64, Vec<String>);

fn parse_mcap_bytes(
    bytes: &[u8],
    path: &Path,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<Parsed, TraceReadError> {
    let problem = |problem: String| TraceReadError::Mcap {
        path: path.to_path_buf(),
        problem,
    };
    let finished = bytes.len() >= 2 * mcap::MAGIC.len() && bytes.ends_with(mcap::MAGIC);
    // Every length in the file is checked against the file's size before the mcap crate sees it: its
    // reader sizes a buffer from a record's length field, so 8 damaged bytes could ask for gigabytes. An
    // unfinished file is read up to its last complete record.
    let readable = check_record_lengths(bytes, finished).map_err(|e| problem(e.to_string()))?;
    // An unfinished file is closed in memory (its complete records, then DataEnd, a Footer and the end magic)
    // and checked again as a finished one, so the mcap crate only ever reads files of the shape the checks
    // were written for (the fuzzer found an allocation its lenient mode made on a damaged unfinished file).
    let closed;
    let bytes: &[u8] = if finished {
        bytes
    } else {
        let mut owned = Vec::with_capacity(readable + 9 + 4 + 9 + 20 + mcap::MAGIC.len());
        owned.extend_from_slice(&bytes[..readable]);
        owned.push(0x0F); // DataEnd: a CRC of 0 means "not computed"
        owned.extend_from_slice(&4u64.to_le_bytes());
        owned.extend_from_slice(&0u32.to_le_bytes());
        owned.push(0x02); // Footer: no summary section
        owned.extend_from_slice(&20u64.to_le_bytes());
        owned.extend_from_slice(&[0u8; 20]);
        owned.extend_from_slice(mcap::MAGIC);
        check_record_lengths(&owned, true).map_err(|e| problem(e.to_string()))?;
        closed = owned;
        &closed
    };
    // The mcap crate (0.26) can panic on damaged files (an integer overflow on a record longer than its
    // chunk, found by the proptest below); a damaged file must be an error, not a crash.
    let parsed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let (mode_names, version) = read_mode_names(bytes)?;
        if version != TRACE_FORMAT_VERSION {
            return Ok(Err(version));
        }
        let samples = read_samples(bytes, &mode_names, !finished, sink)?;
        let cut = (!finished).then(|| "the file ends without its summary".to_owned());
        Ok::<_, McapContentError>(Ok((mode_names, samples, cut)))
    }));
    let (mode_names, samples, cut) = match parsed {
        Ok(Ok(Ok(result))) => result,
        Ok(Ok(Err(found))) => {
            return Err(TraceReadError::OldFormat {
                path: path.to_path_buf(),
                found,
                expected: TRACE_FORMAT_VERSION,
                hint: "its metadata record says so",
            })
        }
        Ok(Err(error)) => return Err(problem(error.to_string())),
        Err(_) => {
            return Err(problem(
                "damaged file: the MCAP library failed while parsing it".to_string(),
            ))
        }
    };
    let mut warnings = Vec::new();
    if let Some(reason) = cut {
        warnings.push(cut_warning(path, samples, &reason));
    }
    Ok((mode_names, samples, warnings))
}

/// The warning for a file the writer never finished, read up to its last complete chunk.
pub(crate) fn cut_warning(path: &Path, samples: u64, reason: &str) -> String {
    format!(
        "{}: the file was not finished (the recording was cut off); read {samples} samples up to the last complete chunk ({reason}); `voxhap trace repair` rewrites it as a finished file",
        path.display(),
    )
}

/// The mode names and the trace format version from the metadata record.
fn read_mode_names(bytes: &[u8]) -> Result<(Vec<String>, u32), McapContentError> {
    for record in mcap::read::LinearReader::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    )? {
        let Ok(record) = record else {
            break;
        };
        if let mcap::records::Record::Metadata(metadata) = record {
            if metadata.name == METADATA_NAME {
                return mode_names_from(|key| metadata.metadata.get(key).map(String::as_str));
            }
        }
    }
    Err(McapContentError::NotVoxhap)
}

/// The mode names and the trace format version from the voxhap metadata record's entries (`get` looks one up);
/// no names when the version is not this reader's.
pub(crate) fn mode_names_from<'a>(
    get: impl Fn(&str) -> Option<&'a str>,
) -> Result<(Vec<String>, u32), McapContentError> {
    let version: u32 = get("format_version")
        .and_then(|v| v.parse().ok())
        .ok_or(McapContentError::NoFormatVersion)?;
    if version != TRACE_FORMAT_VERSION {
        return Ok((Vec::new(), version));
    }
    let text = get("mode_names").ok_or(McapContentError::NoModeNames)?;
    let names: Vec<String> = serde_json::from_str(text).map_err(McapContentError::BadModeNames)?;
    if names.len() > MAX_MODES {
        return Err(McapContentError::TooManyModes { count: names.len() });
    }
    Ok((names, version))
}

/// The samples of a finished file's bytes (an unfinished file is closed in memory first, [`parse_mcap_bytes`]),
/// handed to `sink` in order; returns how many. The writer writes each tick's state message and then its
/// solver message, so the n-th state pairs with the n-th solver: messages wait in two queues only until their
/// partner arrives. `cut_off`: the file on disk was unfinished, so its last tick may have lost its second
/// message (the writer also closes a chunk when it passes its size limit, which may fall inside a tick): the
/// samples end at the last tick with both.
fn read_samples(
    bytes: &[u8],
    mode_names: &[String],
    cut_off: bool,
    sink: &mut dyn FnMut(&TraceSample),
) -> Result<u64, McapContentError> {
    let mut pairing = Pairing::new(mode_names);
    for message in mcap::MessageStream::new(bytes)? {
        let message = message?;
        pairing.message(
            message.channel.topic.as_str(),
            message.sequence,
            &message.data,
            sink,
        )?;
    }
    pairing.finish(cut_off)
}

/// Pairs each tick's state and solver messages, in file order, into samples (see [`read_samples`]): messages
/// wait in two queues only until their partner arrives.
pub(crate) struct Pairing<'a> {
    mode_names: &'a [String],
    states: VecDeque<StateMessageOwned>,
    solvers: VecDeque<SolverMessageOwned>,
    state_count: usize,
    solver_count: usize,
    last_tick: Option<u64>,
    count: u64,
}

impl<'a> Pairing<'a> {
    pub(crate) fn new(mode_names: &'a [String]) -> Self {
        Pairing {
            mode_names,
            states: VecDeque::new(),
            solvers: VecDeque::new(),
            state_count: 0,
            solver_count: 0,
            last_tick: None,
            count: 0,
        }
    }

    /// One message on `topic` (messages on other topics are ignored); hands every completed sample to `sink`.
    pub(crate) fn message(
        &mut self,
        topic: &str,
        sequence: u32,
        data: &[u8],
        sink: &mut dyn FnMut(&TraceSample),
    ) -> Result<(), McapContentError> {
        let bad_message = |topic, source| McapContentError::BadMessage {
            topic,
            sequence,
            source,
        };
        if topic == STATE_TOPIC {
            self.states
                .push_back(serde_json::from_slice(data).map_err(|e| bad_message(STATE_TOPIC, e))?);
            self.state_count += 1;
        } else if topic == SOLVER_TOPIC {
            self.solvers
                .push_back(serde_json::from_slice(data).map_err(|e| bad_message(SOLVER_TOPIC, e))?);
            self.solver_count += 1;
        }
        while !self.states.is_empty() && !self.solvers.is_empty() {
            let (Some(state), Some(solver)) = (self.states.pop_front(), self.solvers.pop_front())
            else {
                break;
            };
            let sample = join(state, solver, self.mode_names)?;
            crate::sample::check_sample(&sample, self.mode_names.len(), self.last_tick)?;
            self.last_tick = Some(sample.tick);
            self.count += 1;
            sink(&sample);
        }
        Ok(())
    }

    /// How many samples were handed on. `cut_off`: the file was unfinished, so its last tick may have lost its
    /// second message; otherwise every state message must have had its solver message.
    pub(crate) fn finish(self, cut_off: bool) -> Result<u64, McapContentError> {
        // Left unpaired: the pairing above already checked, tick by tick, that the kept messages belong together.
        if self.state_count != self.solver_count && !cut_off {
            return Err(McapContentError::Unpaired {
                states: self.state_count,
                solvers: self.solver_count,
            });
        }
        Ok(self.count)
    }
}

/// One tick's sample from its state and solver messages (which must be the same tick's).
fn join(
    state: StateMessageOwned,
    solver: SolverMessageOwned,
    mode_names: &[String],
) -> Result<TraceSample, McapContentError> {
    let t_s = state.t_s.unwrap_or(f64::NAN);
    if state.tick != solver.tick || t_s.to_bits() != solver.t_s.unwrap_or(f64::NAN).to_bits() {
        return Err(McapContentError::Mismatched {
            state_tick: state.tick,
            state_t_s: t_s,
            solver_tick: solver.tick,
            solver_t_s: solver.t_s,
        });
    }
    let mut sample = TraceSample::zeroed(mode_names.len() as u8);
    for (name, (primitives, force_n)) in mode_names.iter().zip(sample.modes.slots_mut()) {
        *primitives = solver
            .primitives
            .get(name)
            .and_then(|v| v.as_u64())
            .and_then(|v| u16::try_from(v).ok())
            .ok_or_else(|| McapContentError::NoModeValue {
                tick: state.tick,
                what: "primitive count",
                mode: name.clone(),
            })?;
        let force: ReadVector = solver
            .mode_force_n
            .get(name)
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .ok_or_else(|| McapContentError::NoModeValue {
                tick: state.tick,
                what: "mode force",
                mode: name.clone(),
            })?;
        *force_n = read_vector(force);
    }
    sample.tick = state.tick;
    sample.t_s = t_s;
    sample.probe_m = read_vector(state.probe_m);
    sample.probe_velocity_m_per_s = read_vector(state.probe_velocity_m_per_s);
    sample.proxy_m = read_vector(state.proxy_m);
    sample.rendered_force_n = read_vector(state.rendered_force_n);
    sample.sent_force_n = read_vector(state.force_n);
    sample.solver_status = SolverStatus::from_name(&solver.solver_status).ok_or_else(|| {
        McapContentError::UnknownName {
            tick: state.tick,
            field: "solver_status",
            name: solver.solver_status.clone(),
        }
    })?;
    sample.sweeps = solver.sweeps;
    sample.error_bound_m = solver.error_bound_m.unwrap_or(f64::INFINITY);
    sample.device_sequence = solver.device_sequence;
    sample.device_time_us = solver.device_time_us;
    sample.flags = solver.flag_bits;
    sample.truth = solver
        .truth
        .truth()
        .map_err(|cause| McapContentError::UnknownName {
            tick: state.tick,
            field: "force_off_cause",
            name: cause,
        })?;
    Ok(sample)
}
