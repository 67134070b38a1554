//! Spawning a device on a fresh pty, and the handle a test asserts on (the logs and the checks built on them).

use super::config::{SpecDeviceConfig, Trigger};
use super::device::{Device, Drive};
use super::log::{ForceRecord, HostMessage, Log, MessageRecord, SentRecord, TriggerRecord};
use std::collections::VecDeque;
use std::ffi::CStr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

/// Spawns devices.
pub struct SpecDevice;

impl SpecDevice {
    /// Creates a pty, starts the device thread on its master side and returns the handle. The slave side is kept
    /// open (raw mode) until the host has sent its first byte, so that nothing is lost before the host opens it.
    pub fn spawn(config: SpecDeviceConfig) -> SpecDeviceHandle {
        let (mut master, mut slave) = (0, 0);
        let mut name = [0 as libc::c_char; 128];
        // SAFETY: openpty writes two fds and a NUL-terminated name into buffers we own (128 bytes is ample).
        let rc = unsafe {
            libc::openpty(
                &mut master,
                &mut slave,
                name.as_mut_ptr(),
                std::ptr::null(),
                std::ptr::null(),
            )
        };
        assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
        // SAFETY: both fds were just returned by openpty and are owned by nobody else.
        let (master, slave) =
            unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        // SAFETY: termios is plain data; tcgetattr fills it, cfmakeraw edits it, tcsetattr applies it to our fd.
        unsafe {
            let mut t: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(slave.as_raw_fd(), &mut t), 0);
            libc::cfmakeraw(&mut t);
            assert_eq!(libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t), 0);
            let flags = libc::fcntl(master.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        // SAFETY: openpty NUL-terminated the name.
        let path = unsafe { CStr::from_ptr(name.as_ptr()) }
            .to_string_lossy()
            .into_owned();
        let log = Arc::new(Mutex::new(Log::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let now = Instant::now();
        let drive = if config.start_faulted.is_some() {
            Drive::Faulted
        } else {
            Drive::Idle
        };
        let faults = config.start_faulted.map_or(0, |code| 1u16 << code);
        let device = Device {
            rng: config.seed.max(1),
            config,
            master,
            log: Arc::clone(&log),
            spawned: now,
            session_open: false,
            drive,
            watchdog_timeout_us: 50_000,
            last_feed: now,
            applied_force_n: [0.0; 3],
            force_clamped: false,
            watchdog_tripped: false,
            faults,
            last_force_sequence: 0,
            state_sequence: 0,
            state_rate_hz: 0,
            next_state_at: now,
            first_enable: None,
            last_applied_n: None,
            fired: Vec::new(),
            fault_done: false,
            reset_done: false,
            silence_from: None,
            device_infos_sent: 0,
            frames_written: 0,
            rx: Vec::with_capacity(66),
            rx_overflow: false,
            outbox: VecDeque::new(),
            last_position: [0.0; 3],
            last_sample_at: now,
            host_attached: false,
            slave: Some(slave),
        };
        let thread_stop = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("spec-device".to_owned())
            .spawn(move || device.run(thread_stop))
            .expect("spawn the spec device thread");
        SpecDeviceHandle {
            path,
            log,
            stop,
            thread: Some(thread),
        }
    }
}

/// A running device; stopped (thread joined, pty closed) by [`SpecDeviceHandle::stop`] or on drop.
pub struct SpecDeviceHandle {
    pub(super) path: String,
    pub(super) log: Arc<Mutex<Log>>,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) thread: Option<JoinHandle<()>>,
}

impl SpecDeviceHandle {
    /// The pty slave path; the host opens it as `serial:PATH`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Every SetForce received so far, in order.
    pub fn forces(&self) -> Vec<ForceRecord> {
        self.log.lock().unwrap().forces.clone()
    }

    /// Every other message received so far (and `PortClosed` events), in order.
    pub fn messages(&self) -> Vec<MessageRecord> {
        self.log.lock().unwrap().messages.clone()
    }

    /// Every frame written so far, in order.
    pub fn sent(&self) -> Vec<SentRecord> {
        self.log.lock().unwrap().sent.clone()
    }

    /// When `trigger` fired, if it has.
    pub fn fired(&self, trigger: Trigger) -> Option<TriggerRecord> {
        self.log
            .lock()
            .unwrap()
            .triggers
            .iter()
            .find(|r| r.trigger == trigger)
            .copied()
    }

    /// The last SetForce received, if any (cheap: nothing else is copied).
    pub fn last_force(&self) -> Option<ForceRecord> {
        self.log.lock().unwrap().forces.last().copied()
    }

    /// The number of SetForce frames received so far (cheap: nothing is copied).
    pub fn force_count(&self) -> usize {
        self.log.lock().unwrap().forces.len()
    }

    /// The number of SetForce frames received after `instant` (cheap: nothing is copied).
    pub fn force_count_after(&self, instant: Instant) -> usize {
        let log = self.log.lock().unwrap();
        log.forces.len() - log.forces.partition_point(|f| f.at <= instant)
    }

    /// The number of SetForce frames received after the event with this `index` (cheap: nothing is copied).
    pub fn force_count_after_index(&self, index: u64) -> usize {
        let log = self.log.lock().unwrap();
        log.forces.len() - log.forces.partition_point(|f| f.index <= index)
    }

    /// Frames received and dropped (bad COBS, CRC, length, type, or a non-finite force).
    pub fn dropped_frames(&self) -> u64 {
        self.log.lock().unwrap().dropped_frames
    }

    /// Stops the device thread and closes the pty.
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }

    /// Messages of one kind (compared by variant).
    pub fn messages_like(&self, like: HostMessage) -> Vec<MessageRecord> {
        self.messages()
            .into_iter()
            .filter(|m| std::mem::discriminant(&m.message) == std::mem::discriminant(&like))
            .collect()
    }

    /// The largest |force| received while the device was not Enabled (0 if none).
    pub fn max_force_while_not_enabled(&self) -> f32 {
        self.forces()
            .iter()
            .filter(|f| !f.enabled)
            .map(|f| {
                if f.is_finite() {
                    f.magnitude_n()
                } else {
                    f32::INFINITY
                }
            })
            .fold(0.0, f32::max)
    }

    /// The largest |force| received (infinite if any was not finite).
    pub fn max_force_n(&self) -> f32 {
        self.forces()
            .iter()
            .map(|f| {
                if f.is_finite() {
                    f.magnitude_n()
                } else {
                    f32::INFINITY
                }
            })
            .fold(0.0, f32::max)
    }

    /// SetForce frames with a non-finite component.
    pub fn non_finite_forces(&self) -> usize {
        self.forces().iter().filter(|f| !f.is_finite()).count()
    }

    /// The steepest rise of |force| between consecutive SetForce frames, per host tick: the rise divided by the
    /// number of sequence steps between them (at least 1). At the host's 1 kHz rate one tick is 1 ms, so this is
    /// the slew in N per ms, independent of when the frames happened to arrive.
    pub fn max_slew_n_per_ms(&self) -> f32 {
        let forces = self.forces();
        forces
            .windows(2)
            .map(|w| {
                let steps = w[1].sequence.wrapping_sub(w[0].sequence).clamp(1, 1000);
                (w[1].magnitude_n() - w[0].magnitude_n()) / steps as f32
            })
            .fold(0.0, f32::max)
    }

    /// Non-zero SetForce frames received after the event with this `index`.
    pub fn nonzero_forces_after_index(&self, index: u64) -> usize {
        self.forces()
            .iter()
            .filter(|f| f.index > index && !f.is_zero())
            .count()
    }
}

impl Drop for SpecDeviceHandle {
    fn drop(&mut self) {
        self.stop();
    }
}
