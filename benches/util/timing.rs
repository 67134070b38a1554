//! Median timing of repeated calls, for benchmarks that print their own tables (benches/solver.rs) and for
//! quick side-by-side comparisons (examples/solver_instructions.rs).

use std::time::Instant;

/// Median nanoseconds per call of `f`: 31 samples of `batch` calls each (5 samples when one call takes over
/// 20 ms, 1 when it takes over a second, to keep the run short).
pub fn median_ns(batch: usize, mut f: impl FnMut()) -> f64 {
    let start = Instant::now();
    f();
    let once_ns = start.elapsed().as_nanos() as f64;
    let count = if once_ns > 1e9 {
        1
    } else if once_ns > 2e7 {
        5
    } else {
        31
    };
    let mut samples: Vec<f64> = (0..count)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..batch {
                f();
            }
            start.elapsed().as_nanos() as f64 / batch as f64
        })
        .collect();
    samples.sort_by(f64::total_cmp);
    samples[samples.len() / 2]
}

/// Calls per sample so that a sample lasts about 2 ms (at least one call).
pub fn batch_for(mut f: impl FnMut()) -> usize {
    let start = Instant::now();
    f();
    let once = start.elapsed().as_nanos().max(1) as f64;
    ((2e6 / once) as usize).clamp(1, 100_000)
}
