//! The recorder thread: drains the servo's sample ring into a trace file while recording, and discards
//! samples otherwise.
//!
//! Where it sits (DESIGN.md section 5): the servo thread pushes a [`TraceSample`] per tick into an SPSC
//! ring and never waits; this thread pops them every couple of milliseconds. Recording starts and stops on
//! requests from the control side (`--record`, or `start_recording`/`stop_recording` commands): a start
//! brings a ready writer and the first tick to record (samples already in the ring from before the request
//! are not part of the recording); a stop finishes the trace (MCAP summary, sidecar) and answers with the
//! summary. When the servo thread ends, the ring is abandoned: the recorder drains what is left, finishes
//! the trace and exits. A write error stops the recording and is kept for the control side to report.

use crate::record::{TraceError, TraceSample, TraceSummary, TraceWriter};
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

fn finish(active: Option<Active>) -> Result<Option<TraceSummary>, TraceError> {
    match active {
        Some(mut active) => active.writer.finish().map(Some),
        None => Ok(None),
    }
}

/// The recorder thread's body. Returns the summary of the trace that was open when the servo ended.
pub fn run_recorder(
    mut samples: rtrb::Consumer<TraceSample>,
    requests: mpsc::Receiver<RecorderRequest>,
    error_slot: RecorderError,
) -> Result<Option<TraceSummary>, TraceError> {
    let mut active: Option<Active> = None;
    let mut last_flush = Instant::now();
    loop {
        while let Ok(request) = requests.try_recv() {
            match request {
                RecorderRequest::Start { writer, first_tick } => {
                    // A start while recording replaces the trace; the control side refuses that, so finish
                    // the old one properly just in case.
                    if let Err(error) = finish(active.take()) {
                        store(&error_slot, &error);
                    }
                    active = Some(Active { writer, first_tick });
                }
                RecorderRequest::Stop { reply } => {
                    drain(&mut samples, &mut active, &error_slot);
                    let _ = reply.send(finish(active.take()));
                }
            }
        }
        let abandoned = samples.is_abandoned();
        drain(&mut samples, &mut active, &error_slot);
        if abandoned {
            return finish(active.take());
        }
        if last_flush.elapsed() >= FLUSH_INTERVAL {
            if let Some(current) = active.as_mut() {
                if let Err(error) = current.writer.flush() {
                    store(&error_slot, &error);
                    active = None;
                }
            }
            last_flush = Instant::now();
        }
        std::thread::sleep(DRAIN_INTERVAL);
    }
}

fn store(slot: &RecorderError, error: &TraceError) {
    if let Ok(mut slot) = slot.lock() {
        *slot = Some(error.to_string());
    }
}

fn drain(
    samples: &mut rtrb::Consumer<TraceSample>,
    active: &mut Option<Active>,
    error_slot: &RecorderError,
) {
    while let Ok(sample) = samples.pop() {
        let Some(current) = active.as_mut() else {
            continue;
        };
        if sample.tick < current.first_tick {
            continue;
        }
        if let Err(error) = current.writer.write_sample(&sample) {
            store(error_slot, &error);
            // Keep what was written: finish the file, then stop recording.
            let _ = current.writer.finish();
            *active = None;
        }
    }
}
