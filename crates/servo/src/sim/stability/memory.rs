//! A trace kept in memory: the stability runs are many and short, and nothing of them needs to reach a file.

use voxhap_record::{TraceError, TraceSample, TraceSummary, TraceWriter};

/// A [`TraceWriter`] that keeps every sample in a vector.
#[derive(Default)]
pub struct MemoryTrace(pub Vec<TraceSample>);

impl TraceWriter for MemoryTrace {
    fn write_sample(&mut self, sample: &TraceSample) -> Result<(), TraceError> {
        self.0.push(*sample);
        Ok(())
    }
    fn flush(&mut self) -> Result<(), TraceError> {
        Ok(())
    }
    fn finish(&mut self) -> Result<TraceSummary, TraceError> {
        Ok(TraceSummary {
            trace_path: "memory".into(),
            sidecar_path: "memory".into(),
            sample_count: self.0.len() as u64,
        })
    }
    fn fail(&mut self, _error: &str) -> Result<(), TraceError> {
        Ok(())
    }
    fn sample_count(&self) -> u64 {
        self.0.len() as u64
    }
}
