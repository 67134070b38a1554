//! Steal time: how long the hypervisor ran something else while a virtual machine's CPUs had work, read from
//! Linux's `/proc/stat` before and after a run (`voxhap bench-loop` prints it beside the overruns).
//!
//! On a virtual machine a servo tick can start milliseconds late with nothing in the guest to blame: the host
//! took the virtual CPU away. The guest kernel counts that time per CPU as *steal* (the eighth number of each
//! `cpuN` line, in clock ticks, proc(5)). A run whose overruns come with steal time on the servo's CPU, and
//! whose empty-tick baseline overruns alike, is losing them to the machine, not to voxhap.
//!
//! Off the real-time path: read only before and after a run. Any line that does not parse as proc(5) describes
//! gives no sample (`None`), never a guess.

use serde::Serialize;

/// Steal time per CPU at one moment, in clock ticks (`USER_HZ`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StealSample {
    /// `(cpu number, steal ticks)` for each `cpuN` line.
    per_cpu: Vec<(u32, u64)>,
}

/// Steal time over a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StealReport {
    /// Summed over all CPUs (ms).
    pub total_ms: f64,
    /// On the CPU the servo thread was pinned to, when it was pinned (ms).
    pub servo_cpu_ms: Option<f64>,
    /// The clock's resolution: one tick (ms).
    pub resolution_ms: f64,
}

impl StealReport {
    /// One line for the text tables.
    pub fn summary(&self) -> String {
        let servo = self.servo_cpu_ms.map_or(String::new(), |ms| {
            format!(", {ms:.0} ms of it on the servo's CPU")
        });
        format!(
            "steal time (the hypervisor running something else, /proc/stat): {:.0} ms over all CPUs{servo}, \
             in steps of {:.0} ms",
            self.total_ms, self.resolution_ms
        )
    }
}

/// Parses the text of `/proc/stat`: every `cpuN` line (not the `cpu` total) with at least eight numbers.
/// `None` if there is no such line or one of them is malformed (a kernel before 2.6.11 has no steal column).
pub fn parse(text: &str) -> Option<StealSample> {
    let mut per_cpu = Vec::new();
    for line in text.lines() {
        let mut fields = line.split_ascii_whitespace();
        let Some(name) = fields.next() else {
            continue;
        };
        let Some(number) = name.strip_prefix("cpu") else {
            continue;
        };
        if number.is_empty() {
            continue; // the all-CPU total
        }
        let cpu: u32 = number.parse().ok()?;
        // user nice system idle iowait irq softirq steal
        let steal: u64 = fields.nth(7)?.parse().ok()?;
        per_cpu.push((cpu, steal));
    }
    (!per_cpu.is_empty()).then_some(StealSample { per_cpu })
}

/// Reads `/proc/stat` now (`None` off Linux or when it does not parse).
pub fn sample() -> Option<StealSample> {
    parse(&std::fs::read_to_string("/proc/stat").ok()?)
}

/// The steal time from `before` (a [`sample`]) to now; `None` if either sample is missing.
pub fn since(before: Option<&StealSample>, servo_cpu: Option<u32>) -> Option<StealReport> {
    between(before?, &sample()?, servo_cpu)
}

/// The line a text output ends with: the report's [`StealReport::summary`], or why there is none.
pub fn describe(report: Option<&StealReport>) -> String {
    report.map_or_else(
        || "steal time: not available (no readable /proc/stat)".to_owned(),
        StealReport::summary,
    )
}

/// Clock ticks per second of `/proc/stat`'s counters.
fn ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions; it returns -1 for an unknown name.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if hz > 0 {
        hz as f64
    } else {
        100.0
    }
}

/// The steal time between two samples; `servo_cpu` picks one CPU out. `None` if the CPUs differ between them
/// (one went offline) or a counter went backwards.
pub fn between(
    before: &StealSample,
    after: &StealSample,
    servo_cpu: Option<u32>,
) -> Option<StealReport> {
    between_at(before, after, servo_cpu, ticks_per_s())
}

fn between_at(
    before: &StealSample,
    after: &StealSample,
    servo_cpu: Option<u32>,
    ticks_per_s: f64,
) -> Option<StealReport> {
    if before.per_cpu.len() != after.per_cpu.len() {
        return None;
    }
    let ms_per_tick = 1e3 / ticks_per_s;
    let mut total = 0u64;
    let mut servo = None;
    for (&(cpu, a), &(cpu_after, b)) in before.per_cpu.iter().zip(&after.per_cpu) {
        if cpu != cpu_after {
            return None;
        }
        let delta = b.checked_sub(a)?;
        total += delta;
        if Some(cpu) == servo_cpu {
            servo = Some(delta as f64 * ms_per_tick);
        }
    }
    Some(StealReport {
        total_ms: total as f64 * ms_per_tick,
        servo_cpu_ms: servo,
        resolution_ms: ms_per_tick,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout of proc(5): `cpu` totals, then one line per CPU: user nice system idle iowait irq softirq
    /// steal guest guest_nice.
    const BEFORE: &str = "cpu  4705 356 584 3699 23 23 0 40 0 0\n\
                          cpu0 1393 280 290 1819 11 11 0 15 0 0\n\
                          cpu1 3312 76 294 1880 12 12 0 25 0 0\n\
                          intr 114930548 113199788 3 0 5 263 0 4 [...]\n\
                          ctxt 1990473\n";
    const AFTER: &str = "cpu  4805 356 584 3699 23 23 0 77 0 0\n\
                         cpu0 1443 280 290 1819 11 11 0 17 0 0\n\
                         cpu1 3362 76 294 1880 12 12 0 60 0 0\n";

    #[test]
    fn steal_is_the_eighth_number_of_each_cpu_line() {
        let before = parse(BEFORE).unwrap();
        let after = parse(AFTER).unwrap();
        let report = between_at(&before, &after, Some(1), 100.0).unwrap();
        assert_eq!(report.total_ms, 370.0); // (2 + 35) ticks of 10 ms
        assert_eq!(report.servo_cpu_ms, Some(350.0));
        assert_eq!(report.resolution_ms, 10.0);
        let unpinned = between_at(&before, &after, None, 100.0).unwrap();
        assert_eq!(unpinned.servo_cpu_ms, None);
        assert!(describe(Some(&report))
            .contains("370 ms over all CPUs, 350 ms of it on the servo's CPU"));
        assert!(describe(None).contains("not available"));
    }

    #[test]
    fn malformed_or_mismatched_samples_give_nothing() {
        // No steal column (a kernel before 2.6.11), a non-number, no CPU lines at all.
        assert_eq!(parse("cpu0 1 2 3 4 5 6 7\n"), None);
        assert_eq!(parse("cpu0 1 2 3 4 5 6 7 x\n"), None);
        assert_eq!(parse("cpux 1 2 3 4 5 6 7 8\n"), None);
        assert_eq!(parse("intr 1 2\n"), None);
        // A CPU went offline, or a counter went backwards.
        let two = parse(BEFORE).unwrap();
        let one = parse("cpu0 1393 280 290 1819 11 11 0 15 0 0\n").unwrap();
        assert_eq!(between_at(&two, &one, None, 100.0), None);
        let backwards = parse(AFTER).unwrap();
        assert_eq!(between_at(&backwards, &two, None, 100.0), None);
    }
}
