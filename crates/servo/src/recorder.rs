//! The recorder thread: drains the servo's sample ring into a trace file while recording, and discards
//! samples otherwise.
//!
//! Where it sits (docs/design.md, "Threads"): the servo thread pushes a [`TraceSample`] per tick into an SPSC
//! ring and never waits; this thread pops them every couple of milliseconds. Recording starts and stops on
//! requests from the control side (`--record`, or `start_recording`/`stop_recording` commands): a start
//! brings a ready writer and the first tick to record (samples already in the ring from before the request
//! are not part of the recording); a stop finishes the trace (MCAP summary, sidecar) and answers with the
//! summary. When the servo thread ends, the ring is abandoned: the recorder drains what is left, finishes
//! the trace and exits.
//!
//! Honest failure: a bad sample never stops a recording (the writer records it flagged, see
//! [`TraceWriter`]). A write or flush error (disk full, file too large, I/O error) does, and the session
//! goes on unrecorded (the device keeps its force rendering; stopping the recording is not a reason to
//! change what the user's hand feels): at once, the recorder prints it with the OS reason to stderr
//! (`voxhap: RECORDING STOPPED, the session goes on unrecorded: cannot write the trace file x.csv: No
//! space left on device (os error 28)`), counts it in the statistics (`recorder_errors`), keeps the
//! message for the control side (`recording_error` in `/api/scene`; `voxhap serve` exits non-zero at the
//! end with it), and marks the sidecar (`complete: false`, `error`, and the count of samples that reached
//! the file: exactly what a reader gets back). Nothing more is written to the trace after the error, and the
//! recording is over: the control side counts the failures (`recorder_errors`), so a new start is accepted at
//! once, without a stop. The
//! trace is flushed every [`FLUSH_INTERVAL`] (whole CSV lines, closed MCAP chunks and Parquet row groups
//! at most a second old), so an error or a crash is noticed, and loses, at most that much.

use super::stats::ServoStats;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use voxhap_api::Snapshot;
use voxhap_record::foxglove_scene::SceneChange;
use voxhap_record::{error_chain, TraceError, TraceSample, TraceSummary, TraceWriter};

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
    /// The scene changed (sent by the control side while recording, with the new volume already
    /// meshed): the trace draws the new volume ([`TraceWriter::scene_changed`]).
    SceneChanged(Box<SceneChange>),
}

/// The last write error, for the control side.
pub type RecorderError = Arc<Mutex<Option<String>>>;

/// How often the recorder wakes to drain the ring.
pub const DRAIN_INTERVAL: Duration = Duration::from_millis(2);
/// How often an active trace is flushed to disk.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(250);
/// Capacity of the ring of snapshots the servo hands over for the scene topics (about a second of them at
/// `RECORDED_SCENE_HZ`; the recorder drains it every [`DRAIN_INTERVAL`]).
pub const SCENE_FRAME_RING: usize = 64;

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
        eprintln!("voxhap: RECORDING STOPPED, the session goes on unrecorded: {text}");
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
    mut frames: rtrb::Consumer<Snapshot>,
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
                RecorderRequest::SceneChanged(change) => {
                    if let Some(current) = active.as_mut() {
                        current.writer.scene_changed(&change);
                    }
                }
                RecorderRequest::Stop { reply } => {
                    drain(&mut samples, &mut frames, &mut active, &reporter);
                    let _ = reply.send(reporter.finish(active.take()));
                }
            }
        }
        let abandoned = samples.is_abandoned();
        drain(&mut samples, &mut frames, &mut active, &reporter);
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

/// Writes the samples in the ring, each after the servo's snapshot of its tick when there is one (the
/// servo pushes a tick's snapshot before its sample); snapshots of ticks without a sample are dropped.
fn drain(
    samples: &mut rtrb::Consumer<TraceSample>,
    frames: &mut rtrb::Consumer<Snapshot>,
    active: &mut Option<Active>,
    reporter: &Reporter,
) {
    while let Ok(sample) = samples.pop() {
        let mut frame = None;
        while frames.peek().is_ok_and(|f| f.tick <= sample.tick) {
            frame = frames.pop().ok();
        }
        let Some(current) = active.as_mut() else {
            continue;
        };
        if sample.tick < current.first_tick {
            continue;
        }
        if let Some(frame) = frame.filter(|f| f.tick == sample.tick) {
            current.writer.scene_frame(&frame);
        }
        if let Err(error) = current.writer.write_sample(&sample) {
            if let Some(failed) = active.take() {
                reporter.fail(failed, &error);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use voxhap_record::{read_trace, CsvTraceWriter, TraceMeta, FLAG_INVALID_VALUES};

    /// A sample ring and a request channel on which `writer` is already asked to start at tick 0.
    fn started(
        writer: Box<dyn TraceWriter>,
    ) -> (
        rtrb::Producer<TraceSample>,
        rtrb::Consumer<TraceSample>,
        mpsc::Sender<RecorderRequest>,
        mpsc::Receiver<RecorderRequest>,
    ) {
        let (producer, consumer) = rtrb::RingBuffer::new(4096);
        let (requests_tx, requests_rx) = mpsc::channel();
        requests_tx
            .send(RecorderRequest::Start {
                writer,
                first_tick: 0,
            })
            .unwrap();
        (producer, consumer, requests_tx, requests_rx)
    }

    fn meta() -> TraceMeta {
        TraceMeta::new(
            vec!["surface".into()],
            1000.0,
            serde_json::Value::Null,
            "",
            "",
        )
    }

    fn sample(tick: u64) -> TraceSample {
        let mut sample = TraceSample::zeroed(1);
        sample.tick = tick;
        sample.t_s = tick as f64 * 1e-3;
        sample
    }

    /// Regression: one tick with a non-finite proxy and certificate (a replayed probe of 1e300) ended the
    /// recording for the rest of the session while the sidecar said complete.
    #[test]
    fn a_bad_tick_is_recorded_flagged_and_the_trace_goes_on() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.csv");
        let writer = CsvTraceWriter::create(&path, &meta()).unwrap();
        let (mut producer, consumer, _requests_tx, requests_rx) = started(Box::new(writer));
        for tick in 0..3000 {
            let mut s = sample(tick);
            if tick == 1000 {
                s.probe_m = DVec3::splat(1e300);
                s.proxy_m = DVec3::new(f64::NAN, 0.0, 0.0);
                s.error_bound_m = f64::NAN;
            }
            producer.push(s).unwrap();
        }
        drop(producer);
        let stats = Arc::new(ServoStats::new(1000.0));
        let (_, frames) = rtrb::RingBuffer::new(1);
        let summary = run_recorder(consumer, frames, requests_rx, Arc::default(), stats.clone())
            .unwrap()
            .unwrap();
        assert_eq!(summary.sample_count, 3000);
        let trace = read_trace(&path).unwrap();
        assert_eq!(trace.samples.len(), 3000);
        assert_ne!(trace.samples[1000].flags & FLAG_INVALID_VALUES, 0);
        assert_eq!(trace.samples[999].flags & FLAG_INVALID_VALUES, 0);
        assert!(trace.sidecar.unwrap().complete);
        assert_eq!(stats.recorder_errors.load(Ordering::Relaxed), 0);
    }

    /// A trace writer whose disk fills after `capacity` samples: later writes and flushes fail with the
    /// OS's ENOSPC error, as a file on a full disk does. (The real writers' own ENOSPC path is tested
    /// against /dev/full in `record::csv`.) It keeps what `fail` was told.
    struct FillingDisk {
        capacity: u64,
        written: u64,
        failed_with: Arc<Mutex<Option<String>>>,
    }

    impl TraceWriter for FillingDisk {
        fn write_sample(&mut self, _: &TraceSample) -> Result<(), TraceError> {
            if self.written >= self.capacity {
                return Err(TraceError::Io {
                    path: "disk.csv".into(),
                    source: std::io::Error::from_raw_os_error(28),
                });
            }
            self.written += 1;
            Ok(())
        }
        fn flush(&mut self) -> Result<(), TraceError> {
            Ok(())
        }
        fn finish(&mut self) -> Result<TraceSummary, TraceError> {
            Err(TraceError::Finished)
        }
        fn fail(&mut self, error: &str) -> Result<(), TraceError> {
            *self.failed_with.lock().unwrap() = Some(error.to_owned());
            Ok(())
        }
        fn sample_count(&self) -> u64 {
            self.written
        }
    }

    /// A full disk reaches the error slot and the statistics within a second, with the OS reason, and
    /// the writer is told (so its sidecar says what happened), while the session goes on.
    #[test]
    fn a_full_disk_is_reported_within_a_second_with_the_os_reason() {
        let failed_with = Arc::default();
        let writer = FillingDisk {
            capacity: 500,
            written: 0,
            failed_with: Arc::clone(&failed_with),
        };
        let (mut producer, consumer, _requests_tx, requests_rx) = started(Box::new(writer));
        let slot: RecorderError = Arc::default();
        let stats = Arc::new(ServoStats::new(1000.0));
        let thread = {
            let (slot, stats) = (slot.clone(), stats.clone());
            std::thread::spawn(move || {
                let (_, frames) = rtrb::RingBuffer::new(1);
                run_recorder(consumer, frames, requests_rx, slot, stats)
            })
        };
        // A 1 kHz session: 10 samples every 10 ms; the disk fills after half a second.
        let started = Instant::now();
        let mut tick = 0;
        let mut full_at = None;
        while slot.lock().unwrap().is_none() && started.elapsed() < Duration::from_secs(5) {
            for _ in 0..10 {
                let _ = producer.push(sample(tick));
                tick += 1;
                if tick == 501 {
                    full_at = Some(Instant::now());
                }
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let message = slot.lock().unwrap().clone().expect("error reported");
        let delay = full_at.expect("disk filled").elapsed();
        assert!(delay < Duration::from_secs(1), "reported {delay:?} after");
        assert!(message.contains("No space left on device"), "{message}");
        assert_eq!(stats.recorder_errors.load(Ordering::Relaxed), 1);
        assert_eq!(
            failed_with.lock().unwrap().as_deref(),
            Some(message.as_str())
        );
        drop(producer);
        assert!(thread.join().unwrap().unwrap().is_none());
    }
}
