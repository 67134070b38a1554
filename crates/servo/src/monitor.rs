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
//!   own watchdog, and the stall is still reported.
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
                let mut last_ticks = stats.ticks.load(Ordering::Acquire);
                let mut last_change = Instant::now();
                let mut stopped_this_stall = false;
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
                        break;
                    }
                    let ticks = stats.ticks.load(Ordering::Acquire);
                    if ticks != last_ticks {
                        last_ticks = ticks;
                        last_change = Instant::now();
                        stopped_this_stall = false;
                    } else if ticks > 0
                        && !stopped_this_stall
                        && running.load(Ordering::Acquire)
                        && last_change.elapsed() > config.stall_after()
                    {
                        stopped_this_stall = true;
                        stats.monitor_stops.fetch_add(1, Ordering::Relaxed);
                        let stalled_ms = last_change.elapsed().as_secs_f64() * 1e3;
                        let what = if thread_stopping.load(Ordering::Acquire) {
                            "the session is stopping and the servo thread has not finished for"
                        } else {
                            "the servo thread has not ticked for"
                        };
                        match slot.fire() {
                            Ok(true) => eprintln!(
                                "monitor: {what} {stalled_ms:.1} ms: zero force and Disable sent to the device"
                            ),
                            Ok(false) => eprintln!(
                                "monitor: {what} {stalled_ms:.1} ms; this device has no stop channel, so its \
                                 own watchdog must stop it"
                            ),
                            Err(error) => eprintln!(
                                "monitor: {what} {stalled_ms:.1} ms; stopping the device failed: {error}"
                            ),
                        }
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
