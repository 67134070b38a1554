//! The [`TraceWriter`] trait every trace format implements (CSV, MCAP, Parquet).

use crate::error::TraceError;
#[cfg(doc)]
use crate::flags::FLAG_INVALID_VALUES;
use crate::foxglove_scene;
use crate::meta::TraceSummary;
use crate::sample::TraceSample;

/// A trace sink. Runs on the recorder thread (it allocates and does I/O; never call it on the servo
/// thread). Call [`TraceWriter::finish`] to close the files cleanly; writing after that is an error.
///
/// A sample that breaks a trace rule (a non-finite value, a wrong mode count) is recorded as it came with
/// [`FLAG_INVALID_VALUES`] set, so one bad tick never ends a trace; a sample whose tick does not increase
/// is left out and counted (`Sidecar::samples_rejected`). Only I/O errors end a trace: the caller then
/// calls [`TraceWriter::fail`] so the sidecar says why.
pub trait TraceWriter: Send {
    /// Appends one sample (see the trait docs for bad samples). Errors are I/O errors, or `Finished`.
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError>;
    /// Pushes buffered data to the file so a reader (or a crash) sees everything written so far: whole
    /// CSV lines, a closed MCAP chunk.
    fn flush(&mut self) -> Result<(), TraceError>;
    /// Writes the trailer (MCAP summary), flushes, and rewrites the sidecar with the final sample count.
    fn finish(&mut self) -> Result<TraceSummary, TraceError>;
    /// Gives up after an error: nothing more reaches the trace file (not even buffered bytes), and the
    /// sidecar records `error` (complete: false) and the samples that reached the file, exactly the ones
    /// a reader recovers. Best effort: the sidecar may be unwritable too.
    fn fail(&mut self, error: &str) -> Result<(), TraceError>;
    /// Samples that reached the file so far (whole CSV lines handed to the OS, closed Parquet row groups,
    /// closed MCAP chunks): the count the sidecar gives, never samples still in a buffer.
    fn sample_count(&self) -> u64;
    /// The servo's snapshot of a tick whose sample comes next (the recorder hands one over at most
    /// `foxglove_scene::RECORDED_SCENE_HZ` times a second of tick time, before that tick's sample): the
    /// MCAP writer draws the tick's primitives and operating state from it. Writers without scene topics
    /// ignore it.
    fn scene_frame(&mut self, _frame: &voxhap_api::Snapshot) {}
    /// The scene changed while recording (a volume loaded, a transfer function replaced): the MCAP writer
    /// draws the new volume picture with the first snapshot that shows `change.generation`. Writers
    /// without scene topics ignore it.
    fn scene_changed(&mut self, _change: &foxglove_scene::SceneChange) {}
}
