//! Real-time setup of the servo thread: `SCHED_FIFO`, locked memory and a pinned core.
//!
//! Called once by the servo thread on itself, before its first tick. Each feature needs a privilege
//! (`CAP_SYS_NICE` or an `rtprio` limit for `SCHED_FIFO`, `CAP_IPC_LOCK` or a `memlock` limit for `mlockall`;
//! pinning is always allowed but is skipped on a single-CPU machine). [`RtMode`] says what to do when one is
//! refused: `strict` refuses to start, `best-effort` (the default) warns and goes on without it, `off` does
//! not ask. The README's "Real-time setup" section shows the limits to grant.

use voxhap_api::RealtimeReport;

/// What the servo thread asks of the OS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RtMode {
    /// SCHED_FIFO, locked memory and a pinned core, or refuse to start.
    Strict,
    /// Ask for all three; warn and continue without the ones refused.
    #[default]
    BestEffort,
    /// Plain thread, no requests.
    Off,
}

/// `SCHED_FIFO` priority used (1..=99; 80 sits above most kernel threads' defaults of 50 and below the
/// watchdog/migration threads at 99).
pub const FIFO_PRIORITY: i32 = 80;

/// What was asked and refused, for the warning or the `strict` error.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("real-time setup refused: {}", refused.join("; "))]
pub struct RtRefused {
    pub refused: Vec<String>,
}

/// Applies `mode` to the calling thread, pinning it to `cpu` (default: the last CPU). Returns what was
/// granted and, in best-effort mode, the refusals as warnings. Allocates (messages); call it before the loop.
pub fn apply(mode: RtMode, cpu: Option<usize>) -> Result<(RealtimeReport, Vec<String>), RtRefused> {
    let mut report = RealtimeReport::default();
    let mut refused = Vec::new();
    if mode == RtMode::Off {
        return Ok((report, refused));
    }
    // SCHED_FIFO for this thread.
    let param = libc::sched_param {
        sched_priority: FIFO_PRIORITY,
    };
    // SAFETY: valid pointer to a sched_param; pid 0 means the calling thread.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } == 0 {
        report.sched_fifo = true;
    } else {
        refused.push(format!(
            "SCHED_FIFO priority {FIFO_PRIORITY}: {} (grant rtprio or CAP_SYS_NICE)",
            std::io::Error::last_os_error()
        ));
    }
    // Lock current and future pages so no tick waits on a page fault.
    // SAFETY: plain syscall with flag arguments.
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
        report.memory_locked = true;
    } else {
        refused.push(format!(
            "mlockall: {} (grant a memlock limit or CAP_IPC_LOCK)",
            std::io::Error::last_os_error()
        ));
    }
    // Pin to one core.
    let cpus = allowed_cpus().len();
    let target = servo_cpu(cpu);
    if cpus > 1 || cpu.is_some() {
        let pinned = set_thread_affinity(&[target]);
        match pinned {
            Ok(()) => report.pinned_cpu = u32::try_from(target).ok(),
            Err(error) => refused.push(format!("pinning to CPU {target}: {error}")),
        }
    } else {
        refused.push("pinning: only one CPU, not pinned".to_owned());
    }
    if mode == RtMode::Strict && !refused.is_empty() {
        return Err(RtRefused { refused });
    }
    Ok((report, refused))
}

/// The CPUs the calling thread may run on now (its affinity mask; a container's cpuset shows here).
pub fn allowed_cpus() -> Vec<usize> {
    // SAFETY: cpu_set_t is plain data; sched_getaffinity gets a valid pointer and its size; CPU_ISSET
    // indexes within CPU_SETSIZE.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Vec::new();
        }
        (0..libc::CPU_SETSIZE as usize)
            .filter(|&c| libc::CPU_ISSET(c, &set))
            .collect()
    }
}

/// Lets the calling thread run on `cpus` only (threads it starts later inherit this).
pub fn set_thread_affinity(cpus: &[usize]) -> std::io::Result<()> {
    // SAFETY: cpu_set_t is plain data; CPU_SET is only called with indices below CPU_SETSIZE; pid 0 is the
    // calling thread and sched_setaffinity gets a valid pointer and its size.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &cpu in cpus {
            if cpu >= libc::CPU_SETSIZE as usize {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    format!(
                        "CPU {cpu} is beyond the {} the kernel's CPU set holds",
                        libc::CPU_SETSIZE
                    ),
                ));
            }
            libc::CPU_SET(cpu, &mut set);
        }
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}

/// The CPUs online (`sysconf(_SC_NPROCESSORS_ONLN)`), whatever the caller's affinity.
pub fn online_cpus() -> usize {
    // SAFETY: a plain query.
    usize::try_from(unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) }).map_or(1, |n| n.max(1))
}

/// The CPU the servo thread pins itself to: `cpu` if given, else the last CPU the caller may use.
pub fn servo_cpu(cpu: Option<usize>) -> usize {
    cpu.unwrap_or_else(|| allowed_cpus().last().copied().unwrap_or(0))
}

/// Keeps the calling thread, and every thread it starts from now on (they inherit its affinity), off the
/// servo's core: its affinity becomes the CPUs it may use now minus `servo_cpu(cpu)`. Call it on the main
/// thread before starting the async runtime and the session, and pass the returned servo CPU on as
/// `SessionConfig::cpu` (the servo thread, started after, inherits the restricted mask and must be told
/// its core). The server, the recorder and the connector then never share the servo thread's core, so its
/// caches and its wake-up latency stay its own. Does nothing with `RtMode::Off`, on one CPU, or when the
/// servo CPU is not one the caller may use; returns the servo CPU and the CPUs left to the others.
pub fn reserve_servo_cpu(mode: RtMode, cpu: Option<usize>) -> Option<(usize, Vec<usize>)> {
    if mode == RtMode::Off {
        return None;
    }
    let allowed = allowed_cpus();
    let servo = servo_cpu(cpu);
    if !allowed.contains(&servo) || allowed.len() < 2 {
        return None;
    }
    let others: Vec<usize> = allowed.into_iter().filter(|&c| c != servo).collect();
    set_thread_affinity(&others).ok()?;
    Some((servo, others))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reserving_the_servo_cpu_leaves_the_others_to_the_caller() {
        // On a scratch thread, so the test harness keeps its own affinity.
        std::thread::spawn(|| {
            assert_eq!(reserve_servo_cpu(RtMode::Off, None), None);
            let before = allowed_cpus();
            let expected_servo = *before.last().unwrap();
            match reserve_servo_cpu(RtMode::BestEffort, None) {
                Some((servo, others)) => {
                    assert_eq!(servo, expected_servo);
                    assert!(!others.contains(&servo) && !others.is_empty());
                    assert_eq!(others.len() + 1, before.len());
                    // A thread started now inherits the restriction...
                    let inherited = std::thread::spawn(allowed_cpus).join().unwrap();
                    assert_eq!(inherited, others);
                    // ...and the servo thread, told its CPU, can still pin itself there.
                    let pinned = std::thread::spawn(move || {
                        apply(RtMode::BestEffort, Some(servo)).unwrap().0.pinned_cpu
                    })
                    .join()
                    .unwrap();
                    assert_eq!(pinned, u32::try_from(servo).ok());
                }
                None => assert_eq!(before.len(), 1, "{before:?} CPUs but nothing reserved"),
            }
        })
        .join()
        .unwrap();
    }

    #[test]
    fn off_asks_for_nothing() {
        let (report, warnings) = apply(RtMode::Off, None).unwrap();
        assert_eq!(report, RealtimeReport::default());
        assert!(warnings.is_empty());
    }

    #[test]
    fn strict_fails_exactly_when_something_was_refused() {
        // Run on a scratch thread: the grants (if any) must not leak into the test harness's threads.
        let result = std::thread::spawn(|| {
            let best = apply(RtMode::BestEffort, None);
            let strict = apply(RtMode::Strict, None);
            (best, strict)
        })
        .join()
        .unwrap();
        let (best, strict) = result;
        let (_, warnings) = best.expect("best effort never fails");
        match strict {
            Ok(_) => assert!(
                warnings.is_empty(),
                "strict passed but best-effort warned: {warnings:?}"
            ),
            Err(err) => {
                assert!(!err.refused.is_empty());
                assert!(err.to_string().starts_with("real-time setup refused"));
            }
        }
    }
}
