//! The monitor thread: the servo thread's watchdog that acts, and the reporter of device events.
//!
//! Where it sits: beside the servo thread in `voxhap serve` (docs/design.md, "Threads"). It never touches
//! the device handle the servo thread owns. Twice per servo period (at least every millisecond) it:
//!
//! - **watches the tick counter.** When the servo thread has not ticked for `stall_periods` periods (default 20,
//!   so 20 ms at 1 kHz) while the session runs, it brings the device to zero force itself through the
//!   device's stop channel ([`StopSlot`]): a second handle of the serial port on which a driver pre-encoded a
//!   delimiter, a zero force and a Disable ([`voxhap_device::EmergencyStop`]). Then it raises the slot's flag;
//!   the servo thread's next tick sees it, keeps the output at zero and takes the device through
//!   `Recovering` (enable again once the link is healthy, ramp in). One stop per stall; counted and reported.
//!   Devices whose driver has no stop channel (HID devices, the in-process simulated arm, replay) rely on their
//!   own watchdog, and the stall is still reported: at the stop, as "has not ticked for X ms so far" (X just
//!   past the threshold: the stall is not over), and, once the servo thread ticks again, with how long it went
//!   without a tick in all ([`StallWatch`]; as the monitor's polls saw it, to within a poll).
//! - **reports device events.** The servo thread pushes every supervisor event (fault, refusal, enable,
//!   disconnect, stall stop) into an SPSC ring; the monitor prints each once on stderr with its tick and time
//!   and what the operator should do, so nothing on the servo thread formats or writes text.
//!
//! The stop channel is installed under a mutex by whichever thread opens a device (the connector thread or the
//! session at start); only the monitor takes it to stop. The servo thread never locks it.

use super::stats::ServoStats;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use voxhap_device::info::{fault_name, reject_reason_name, MESSAGE_TYPE_ENABLE};
use voxhap_device::supervisor::SupervisorEvent;
use voxhap_device::{DeviceEvent, EmergencyStop};

/// Where the monitor finds the current device's stop channel, and the flag it raises after using it.
pub struct StopSlot {
    handle: Mutex<Option<Box<dyn EmergencyStop>>>,
    tripped: Arc<AtomicBool>,
}

impl std::fmt::Debug for StopSlot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StopSlot")
            .field("tripped", &self.tripped.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

impl StopSlot {
    /// An empty slot.
    pub fn new() -> Arc<StopSlot> {
        Arc::new(StopSlot {
            handle: Mutex::new(None),
            tripped: Arc::new(AtomicBool::new(false)),
        })
    }

    /// Installs the stop channel of a newly opened device (`None`: it has none). Off the servo thread.
    pub fn install(&self, handle: Option<Box<dyn EmergencyStop>>) {
        if let Ok(mut slot) = self.handle.lock() {
            *slot = handle;
        }
    }

    /// The flag raised after a stop, for the supervisor.
    pub fn tripped_flag(&self) -> Arc<AtomicBool> {
        self.tripped.clone()
    }

    /// Stops the device through its channel and raises the flag. `Ok(false)` when there is no channel.
    pub fn fire(&self) -> Result<bool, voxhap_device::DeviceError> {
        let mut slot = match self.handle.lock() {
            Ok(slot) => slot,
            Err(poisoned) => poisoned.into_inner(),
        };
        self.tripped.store(true, Ordering::Release);
        match slot.as_mut() {
            Some(handle) => handle.stop().map(|()| true),
            None => Ok(false),
        }
    }
}

/// One supervisor event as the servo thread saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceReport {
    /// The tick it happened on.
    pub tick: u64,
    /// Session time (s).
    pub t_s: f64,
    /// What happened.
    pub event: SupervisorEvent,
}

/// Capacity of the event ring (events beyond it are counted as dropped by the servo thread).
pub const EVENT_RING: usize = 256;

/// Settings of the monitor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MonitorConfig {
    /// Servo period.
    pub period: Duration,
    /// Periods without a tick that count as a stall.
    pub stall_periods: u32,
}

impl MonitorConfig {
    /// The stall threshold as a duration.
    pub fn stall_after(&self) -> Duration {
        self.period.saturating_mul(self.stall_periods.max(1))
    }
}

/// The monitor's view of the tick counter (module docs): when it last saw the counter move, and whether it
/// stopped the device in the stall since. No thread and no clock of its own, so tests can feed it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StallWatch {
    last_ticks: u64,
    last_change: Instant,
    stopped: bool,
}

/// What a look at the tick counter found ([`StallWatch::look`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StallNews {
    /// No tick for longer than the threshold, first seen now: stop the device. The stall so far.
    Stalled(Duration),
    /// The servo thread ticked again after a stall the monitor stopped the device for. The time without a tick
    /// in all, from the last tick seen before the stall to this look.
    Ended(Duration),
}

impl StallWatch {
    /// Watching a counter at `ticks`, seen at `now`.
    pub fn new(ticks: u64, now: Instant) -> StallWatch {
        StallWatch {
            last_ticks: ticks,
            last_change: now,
            stopped: false,
        }
    }

    /// The counter reads `ticks` at `now`. A stall is news once, when it passes `stall_after` while `watching`
    /// (the session runs, and has ticked), and once more when it ends; `None` otherwise.
    pub fn look(
        &mut self,
        ticks: u64,
        now: Instant,
        watching: bool,
        stall_after: Duration,
    ) -> Option<StallNews> {
        let without = now.saturating_duration_since(self.last_change);
        if ticks != self.last_ticks {
            let ended = self.stopped.then_some(StallNews::Ended(without));
            *self = StallWatch::new(ticks, now);
            return ended;
        }
        if ticks > 0 && !self.stopped && watching && without > stall_after {
            self.stopped = true;
            return Some(StallNews::Stalled(without));
        }
        None
    }

    /// How long the stall the monitor stopped the device for has lasted at `now`; `None` when there is none.
    pub fn open_stall(&self, now: Instant) -> Option<Duration> {
        self.stopped
            .then(|| now.saturating_duration_since(self.last_change))
    }
}

/// The line the monitor prints when a stall it stopped the device for ends after `without` without a tick.
pub fn stall_ended(without: Duration) -> String {
    format!(
        "monitor: the servo thread ticked again after {:.1} ms without a tick",
        without.as_secs_f64() * 1e3
    )
}

/// What the operator reads for an event.
pub fn describe(event: SupervisorEvent) -> String {
    match event {
        SupervisorEvent::Connected => {
            "device connected; enabling once the servo loop runs steadily".to_owned()
        }
        SupervisorEvent::Enabled => {
            "device enabled; forces ramp in once the rendered force is small".to_owned()
        }
        SupervisorEvent::Disconnected { kind, reason } => format!(
            "device link dropped ({}, last error {kind:?}): zero force sent; reconnecting",
            reason.describe()
        ),
        SupervisorEvent::ReconnectFailed(kind) => format!("reconnect failed ({kind:?}); retrying"),
        SupervisorEvent::DeviceError(kind) => format!("device error ({kind:?})"),
        SupervisorEvent::Device(event) => describe_device(event),
        SupervisorEvent::DroppedOut => {
            "device says it is not enabled although the host enabled it: force off; enabling again"
                .to_owned()
        }
        SupervisorEvent::StallStop => {
            "servo thread was stalled; the monitor had stopped the device: enabling again"
                .to_owned()
        }
        SupervisorEvent::FaultCleared => {
            "faults cleared on the operator's request; enabling again once the link is healthy"
                .to_owned()
        }
    }
}

/// What the operator reads for something the device told the host.
fn describe_device(event: DeviceEvent) -> String {
    match event {
        DeviceEvent::Fault { code: 0, .. } => {
            "device watchdog expired: the device dropped the force; enabling again once the link is healthy"
                .to_owned()
        }
        DeviceEvent::Fault {
            code,
            active_faults,
        } => format!(
            "device FAULT {} (code {code}, latched faults 0x{active_faults:04x}): force off; this needs a \
             person: check the arm, then send clear_fault (voxhap clear-fault, or the page's button)",
            fault_name(code)
        ),
        DeviceEvent::Rejected {
            message_type,
            reason,
        } => {
            let what = if message_type == MESSAGE_TYPE_ENABLE {
                "Enable".to_owned()
            } else {
                format!("message 0x{message_type:02x}")
            };
            format!(
                "device refused {what} ({}): force stays off",
                reject_reason_name(reason)
            )
        }
        DeviceEvent::Surplus { total } => format!(
            "device sent {total} message(s) more than the host asked for (does it answer twice, or stream?): \
             force is rendered from the newest, the rest are dropped; check the device's firmware"
        ),
    }
}

/// The running monitor thread.
pub struct Monitor {
    stop: Arc<AtomicBool>,
    /// The session is stopping: ticks have ended on purpose, and a stop that takes a while (a device's close,
    /// the connector thread) is said to be one, not a stall. The device is still stopped through its channel.
    stopping: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Monitor {
    /// Starts the thread. `running` is true while the servo thread runs; `events` is the ring the servo thread
    /// reports into.
    pub fn spawn(
        config: MonitorConfig,
        stats: Arc<ServoStats>,
        running: Arc<AtomicBool>,
        slot: Arc<StopSlot>,
        mut events: rtrb::Consumer<DeviceReport>,
    ) -> std::io::Result<Monitor> {
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = stop.clone();
        let stopping = Arc::new(AtomicBool::new(false));
        let thread_stopping = stopping.clone();
        let poll = (config.period / 2).clamp(Duration::from_micros(100), Duration::from_millis(1));
        let thread = std::thread::Builder::new()
            .name("voxhap-monitor".to_owned())
            .spawn(move || {
                let mut watch = StallWatch::new(stats.ticks.load(Ordering::Acquire), Instant::now());
                loop {
                    while let Ok(report) = events.pop() {
                        eprintln!(
                            "device: tick {} (t = {:.3} s): {}",
                            report.tick,
                            report.t_s,
                            describe(report.event)
                        );
                    }
                    if thread_stop.load(Ordering::Acquire) {
                        if let Some(without) = watch.open_stall(Instant::now()) {
                            eprintln!(
                                "monitor: stopped {:.1} ms after the servo thread's last tick",
                                without.as_secs_f64() * 1e3
                            );
                        }
                        break;
                    }
                    let ticks = stats.ticks.load(Ordering::Acquire);
                    let watching = running.load(Ordering::Acquire);
                    match watch.look(ticks, Instant::now(), watching, config.stall_after()) {
                        Some(StallNews::Stalled(so_far)) => {
                            stats.monitor_stops.fetch_add(1, Ordering::Relaxed);
                            let stalled_ms = so_far.as_secs_f64() * 1e3;
                            let what = if thread_stopping.load(Ordering::Acquire) {
                                "the session is stopping and the servo thread has not finished for"
                            } else {
                                "the servo thread has not ticked for"
                            };
                            match slot.fire() {
                                Ok(true) => eprintln!(
                                    "monitor: {what} {stalled_ms:.1} ms so far: zero force and Disable sent to \
                                     the device"
                                ),
                                Ok(false) => eprintln!(
                                    "monitor: {what} {stalled_ms:.1} ms so far; this device has no stop \
                                     channel, so its own watchdog must stop it"
                                ),
                                Err(error) => eprintln!(
                                    "monitor: {what} {stalled_ms:.1} ms so far; stopping the device failed: \
                                     {error}"
                                ),
                            }
                        }
                        Some(StallNews::Ended(without)) => eprintln!("{}", stall_ended(without)),
                        None => {}
                    }
                    std::thread::sleep(poll);
                }
            })?;
        Ok(Monitor {
            stop,
            stopping,
            thread: Some(thread),
        })
    }

    /// The session is stopping (its servo thread has been told to stop): a pause in ticks from here on is
    /// reported as the stop taking a while, not as a stall.
    pub fn note_stopping(&self) {
        self.stopping.store(true, Ordering::Release);
    }

    /// Stops the thread (after printing what is left in the ring).
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for Monitor {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use voxhap_device::DeviceError;

    struct CountingStop(Arc<std::sync::atomic::AtomicU32>);

    impl EmergencyStop for CountingStop {
        fn stop(&mut self) -> Result<(), DeviceError> {
            self.0.fetch_add(1, Ordering::Relaxed);
            Ok(())
        }
    }

    /// A stall of 0.9 s, polled every 0.5 ms as at 1 kHz, with the threshold of 20 ms: the last tick is seen
    /// at t = 10 ms; the first look past 30 ms (t = 30.5 ms, 20.5 ms without a tick) says stalled so far; the
    /// looks up to t = 910 ms say nothing more; the tick seen at t = 910.5 ms ends it after 900.5 ms in all,
    /// and the line says so (not the threshold). Ticking again, nothing; a short pause (10 ms) is no stall;
    /// a stall while the session is not running is not stopped, and its end is no news.
    #[test]
    fn a_stall_is_reported_when_it_passes_the_threshold_and_again_with_its_length_when_it_ends() {
        let t0 = Instant::now();
        let at = |us: u64| t0 + Duration::from_micros(us);
        let after = Duration::from_millis(20);
        let mut watch = StallWatch::new(0, t0);
        let mut news = Vec::new();
        let mut ticks = 0;
        for step in 0..=2_000u64 {
            let now_us = step * 500;
            if now_us <= 10_000 || now_us >= 910_500 {
                ticks += 1;
            }
            if let Some(n) = watch.look(ticks, at(now_us), true, after) {
                news.push((now_us, n));
            }
        }
        assert_eq!(
            news,
            [
                (30_500, StallNews::Stalled(Duration::from_micros(20_500))),
                (910_500, StallNews::Ended(Duration::from_micros(900_500))),
            ]
        );
        assert_eq!(
            stall_ended(Duration::from_micros(900_500)),
            "monitor: the servo thread ticked again after 900.5 ms without a tick"
        );
        assert_eq!(watch.open_stall(at(1_000_000)), None);
        let mut paused = StallWatch::new(5, t0);
        assert_eq!(paused.look(5, at(10_000), true, after), None);
        assert_eq!(paused.look(6, at(10_500), true, after), None);
        let mut idle = StallWatch::new(5, t0);
        assert_eq!(idle.look(5, at(50_000), false, after), None);
        assert_eq!(idle.open_stall(at(50_000)), None);
        assert_eq!(idle.look(6, at(60_000), true, after), None);
        let mut open = StallWatch::new(5, t0);
        assert_eq!(
            open.look(5, at(25_000), true, after),
            Some(StallNews::Stalled(Duration::from_millis(25)))
        );
        assert_eq!(open.open_stall(at(40_000)), Some(Duration::from_millis(40)));
    }

    #[test]
    fn a_stalled_servo_thread_is_stopped_once_per_stall() {
        let stats = Arc::new(ServoStats::new(1000.0));
        let running = Arc::new(AtomicBool::new(true));
        let slot = StopSlot::new();
        let stops = Arc::new(std::sync::atomic::AtomicU32::new(0));
        slot.install(Some(Box::new(CountingStop(stops.clone()))));
        let (_producer, consumer) = rtrb::RingBuffer::new(4);
        // Generous: this machine is shared, and a sleeping test thread may wake late.
        let config = MonitorConfig {
            period: Duration::from_millis(1),
            stall_periods: 100,
        };
        let mut monitor =
            Monitor::spawn(config, stats.clone(), running, slot.clone(), consumer).unwrap();
        // Ticking: no stop.
        for _ in 0..30 {
            stats.ticks.fetch_add(1, Ordering::Release);
            std::thread::sleep(Duration::from_millis(1));
        }
        // Stalled for 400 ms: exactly one stop, and the flag is up.
        std::thread::sleep(Duration::from_millis(400));
        monitor.stop();
        assert_eq!(stops.load(Ordering::Relaxed), 1);
        assert!(slot.tripped_flag().load(Ordering::Acquire));
        assert_eq!(stats.monitor_stops.load(Ordering::Relaxed), 1);
    }
}
