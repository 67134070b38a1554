//! The recorder thread: drains the servo's sample ring into a trace file while recording, and discards
//! samples otherwise.
//!
//! Where it sits (DESIGN.md section 5): the servo thread pushes a [`TraceSample`] per tick into an SPSC
//! ring and never waits; this thread pops them every couple of milliseconds. Recording starts and stops on
//! requests from the control side (`--record`, or `start_recording`/`stop_recording` commands): a start
//! brings a ready writer and the first tick to record (samples already in the ring from before the request
//! are not part of the recording); a stop finishes the trace (MCAP summary, sidecar) and answers with the
//! summary. When the servo thread ends, the ring is abandoned: the recorder drains what is left, finishes
//! the trace and exits.
//!
//! Honest failure: a bad sample never stops a recording (the writer records it flagged, see
//! [`TraceWriter`]). A write or flush error (disk full, I/O error) does: at once, the recorder prints it
//! with the OS reason to stderr (`voxhap: recording to x.csv stopped: ... No space left on device (os
//! error 28)`), counts it in the statistics (`recorder_errors`), keeps the message for the control side,
//! and marks the sidecar (`complete: false`, `error`). The trace is flushed every [`FLUSH_INTERVAL`]
//! (whole CSV lines, closed MCAP chunks), so an error or a crash is noticed, and loses, at most that much.

use super::stats::ServoStats;
use crate::record::{error_chain, TraceError, TraceSample, TraceSummary, TraceWriter};
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A request to the recorder thread.
pub enum RecorderRequest {
    /// Record every sample with `tick >= first_tick` into `writer`.
    Start {
        writer: Box<dyn TraceWriter>,
        first_tick: u64,
    },
    /// Finish the current trace and send its summary back.
    Stop {
        reply: mpsc::Sender<Result<Option<TraceSummary>, TraceError>>,
    },
}

/// The last write error, for the control side.
pub type RecorderError = Arc<Mutex<Option<String>>>;

/// How often the recorder wakes to drain the ring.
pub const DRAIN_INTERVAL: Duration = Duration::from_millis(2);
/// How often an active trace is flushed to disk.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(250);

struct Active {
    writer: Box<dyn TraceWriter>,
    first_tick: u64,
}

/// Where a recorder reports a failure: stderr, the statistics and the control side's slot.
struct Reporter {
    slot: RecorderError,
    stats: Arc<ServoStats>,
}

impl Reporter {
    /// Reports `error` and marks the trace failed; the recording ends.
    fn fail(&self, mut active: Active, error: &TraceError) {
        let text = error_chain(error);
        eprintln!("voxhap: recording stopped: {text}");
        self.stats.recorder_errors.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut slot) = self.slot.lock() {
            *slot = Some(text.clone());
        }
        if let Err(sidecar_error) = active.writer.fail(&text) {
            eprintln!(
                "voxhap: could not mark the trace's sidecar as failed either: {}",
                error_chain(&sidecar_error)
            );
        }
    }

    fn finish(&self, active: Option<Active>) -> Result<Option<TraceSummary>, TraceError> {
        match active {
            Some(mut current) => match current.writer.finish() {
                Ok(summary) => Ok(Some(summary)),
                Err(error) => {
                    self.fail(current, &error);
                    Err(error)
                }
            },
            None => Ok(None),
        }
    }
}

/// The recorder thread's body. Returns the summary of the trace that was open when the servo ended.
pub fn run_recorder(
    mut samples: rtrb::Consumer<TraceSample>,
    requests: mpsc::Receiver<RecorderRequest>,
    error_slot: RecorderError,
    stats: Arc<ServoStats>,
) -> Result<Option<TraceSummary>, TraceError> {
    let reporter = Reporter {
        slot: error_slot,
        stats,
    };
    let mut active: Option<Active> = None;
    let mut last_flush = Instant::now();
    loop {
        while let Ok(request) = requests.try_recv() {
            match request {
                RecorderRequest::Start { writer, first_tick } => {
                    // A start while recording replaces the trace; the control side refuses that, so finish
                    // the old one properly just in case.
                    let _ = reporter.finish(active.take());
                    active = Some(Active { writer, first_tick });
                    last_flush = Instant::now();
                }
                RecorderRequest::Stop { reply } => {
                    drain(&mut samples, &mut active, &reporter);
                    let _ = reply.send(reporter.finish(active.take()));
                }
            }
        }
        let abandoned = samples.is_abandoned();
        drain(&mut samples, &mut active, &reporter);
        if abandoned {
            return reporter.finish(active.take());
        }
        if last_flush.elapsed() >= FLUSH_INTERVAL {
            if let Some(mut current) = active.take() {
                match current.writer.flush() {
                    Ok(()) => active = Some(current),
                    Err(error) => reporter.fail(current, &error),
                }
            }
            last_flush = Instant::now();
        }
        std::thread::sleep(DRAIN_INTERVAL);
    }
}

fn drain(
    samples: &mut rtrb::Consumer<TraceSample>,
    active: &mut Option<Active>,
    reporter: &Reporter,
) {
    while let Ok(sample) = samples.pop() {
        let Some(current) = active.as_mut() else {
            continue;
        };
        if sample.tick < current.first_tick {
            continue;
        }
        if let Err(error) = current.writer.write_sample(&sample) {
            if let Some(failed) = active.take() {
                reporter.fail(failed, &error);
            }
        }
    }
}
