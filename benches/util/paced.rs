//! A paced run at 1 kHz (the servo rate) of one device round trip, printing its p50, p99 and maximum latency;
//! shared by the device benchmarks (benches/device.rs, benches/inverse3.rs).

use std::time::{Duration, Instant};

/// Runs `round_trip` `count` times, one per millisecond, and prints `label`'s latency percentiles.
pub fn paced_percentiles(label: &str, count: usize, mut round_trip: impl FnMut()) {
    let mut latencies_us = Vec::with_capacity(count);
    let start = Instant::now();
    for tick in 1..=count as u64 {
        let deadline = start + Duration::from_micros(tick * 1_000);
        let now = Instant::now();
        if deadline > now {
            std::thread::sleep(deadline - now);
        }
        let sent = Instant::now();
        round_trip();
        latencies_us.push(sent.elapsed().as_secs_f64() * 1e6);
    }
    latencies_us.sort_by(f64::total_cmp);
    let at = |q: f64| latencies_us[((latencies_us.len() - 1) as f64 * q).round() as usize];
    println!(
        "{label}: {count} exchanges: p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        at(0.5),
        at(0.99),
        latencies_us[latencies_us.len() - 1]
    );
}
