//! Haply Inverse3 (and Inverse3x, Minverse) through the Haply Inverse Service (`--device
//! haply-inverse[:ws://HOST:PORT]`, default ws://127.0.0.1:10001).
//!
//! Where it sits: a [`HapticDevice`] whose `write_force` and `read_state` run on the servo thread and only push
//! to and pop from lock-free buffers; the WebSocket exchange runs on the I/O thread of
//! [`crate::transport::inverse_service`] (protocol, coordinate basis and sources are described there).
//!
//! Per tick: `write_force` queues one force command (sequence n) and wakes the I/O thread, which sends one
//! `set_cursor_force` message and reads the state update the service sends back, and every other message
//! already received (so a service that sends more than one per command builds no backlog: the newest state
//! is always the one published, and the extra messages are counted and reported once at 1, 2, 4, 8, ...
//! extra as [`DeviceEvent::Surplus`]). `read_state` waits at most
//! `reply_wait` (default 0.4 ms, under half a 1 kHz period) for the state answering command n; without it, it
//! returns the newest state if that answers one of the last `max_stale_ticks` commands, with its age in ticks
//! ([`HapticDevice::state_age_ticks`], which the supervisor counts towards its staleness bound), and otherwise a
//! timeout (the supervisor counts those and drops the link after too many).
//!
//! The wait spins only for its first [`REPLY_SPIN`] and then yields the CPU on every check
//! (`sched_yield`): the answer needs two other threads to run (this I/O thread and the service), and on a
//! loaded two-core machine a servo thread spinning for the whole wait kept them off the CPU it held, so the
//! answer came only after the wait had ended (under two busy loops, 8-12 % of ticks found no state newer than
//! 3 ticks, and the output took a second or never got enabled; with the yield, 0-0.1 %). Under `--rt`
//! (SCHED_FIFO, pinned) the yield gives way to nobody: the I/O thread runs on another CPU.
//! A connection that ends (the service stopped
//! or restarted) is reported as a disconnect: the supervisor closes this driver and opens a new one, which
//! connects again. Every stop sends a zero force (the lifecycle wrapper's explicit zero, then the I/O thread's
//! own zero before it closes the socket); when commands stop, the service returns the device to idle on its own.
//!
//! Capabilities: Haply's documentation does not publish a force limit or workspace box for the service, so the
//! capability record is conservative and stated as voxhap's, not Haply's: [`DEFAULT_MAX_FORCE_N`] and a box of
//! ±[`WORKSPACE_HALF_EXTENT_M`] around the origin of the service's frame (Haply's tutorial 06 clamps Inverse3
//! targets to a 0.10 m sphere). The device profile (the lead's workspace mapping) overrides both.

use crate::transport::inverse_service::{self, ForceCommand, ServiceConfig, ServiceLink};
use crate::{DeviceError, DeviceEvent, DeviceInfo, DeviceState, HapticDevice, SurplusCount};
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// voxhap's default force cap for the Inverse3 (N); a profile may lower it.
pub const DEFAULT_MAX_FORCE_N: f64 = 3.0;
/// Half the edge of the capability record's workspace box (m).
pub const WORKSPACE_HALF_EXTENT_M: f64 = 0.10;
/// How long `read_state` spins before it starts yielding the CPU while it waits for the answer.
pub const REPLY_SPIN: Duration = Duration::from_micros(20);

/// Settings of the driver.
#[derive(Debug, Clone, PartialEq)]
pub struct HaplyInverseConfig {
    /// The connection.
    pub service: ServiceConfig,
    /// Longest wait in `read_state` for the state answering this tick's force.
    pub reply_wait: Duration,
    /// A state answering one of this many most recent commands may be used when the newest is late.
    pub max_stale_ticks: u64,
    /// Force cap for the capability record (N).
    pub max_force_n: f64,
}

impl Default for HaplyInverseConfig {
    fn default() -> Self {
        HaplyInverseConfig {
            service: ServiceConfig::default(),
            reply_wait: Duration::from_micros(400),
            max_stale_ticks: 3,
            max_force_n: DEFAULT_MAX_FORCE_N,
        }
    }
}

/// An Inverse3 behind the Inverse Service.
#[derive(Debug)]
pub struct HaplyInverse {
    config: HaplyInverseConfig,
    link: Option<ServiceLink>,
    info: DeviceInfo,
    sequence: u64,
    /// Age (ticks) of the state the last `read_state` returned.
    state_age_ticks: u32,
    /// Extra messages reported so far on this link ([`DeviceEvent::Surplus`] at 1, 10, 100, 1 000, then every
    /// 1 000 more).
    surplus: SurplusCount,
    /// A report waiting for [`HapticDevice::take_event`].
    pending_event: Option<DeviceEvent>,
}

impl HaplyInverse {
    /// A driver; nothing is connected until `open`.
    pub fn new(config: HaplyInverseConfig) -> HaplyInverse {
        let info = DeviceInfo {
            model: "Haply Inverse3 (Inverse Service)".to_owned(),
            serial_number: String::new(),
            position_dof: 3,
            force_dof: 3,
            button_count: 0,
            workspace_min_m: DVec3::splat(-WORKSPACE_HALF_EXTENT_M),
            workspace_max_m: DVec3::splat(WORKSPACE_HALF_EXTENT_M),
            max_force_n: config.max_force_n,
            // Not published by Haply; the host's default cap.
            max_stiffness_n_per_m: 1000.0,
            max_speed_m_per_s: crate::info::DEFAULT_MAX_SPEED_M_PER_S,
            reports_velocity: true,
            state_rates_hz: Vec::new(),
        };
        HaplyInverse {
            config,
            link: None,
            info,
            sequence: 0,
            state_age_ticks: 0,
            surplus: SurplusCount::default(),
            pending_event: None,
        }
    }

    /// The connection, while open (counters, device identity).
    pub fn link(&self) -> Option<&ServiceLink> {
        self.link.as_ref()
    }

    fn link_mut(&mut self) -> Result<&mut ServiceLink, DeviceError> {
        self.link.as_mut().ok_or_else(not_open)
    }
}

fn not_open() -> DeviceError {
    DeviceError::Disconnected {
        during: "using the Inverse Service link before open",
        kind: std::io::ErrorKind::NotConnected,
    }
}

impl HapticDevice for HaplyInverse {
    type Error = DeviceError;

    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn open(&mut self) -> Result<(), DeviceError> {
        let link = inverse_service::connect(&self.config.service)?;
        let device = &link.device;
        self.info.model = format!("Haply {} (Inverse Service)", device.device_type);
        self.info.serial_number = device.device_id.clone();
        self.sequence = 0;
        self.surplus = SurplusCount::default();
        self.pending_event = None;
        self.link = Some(link);
        Ok(())
    }

    fn close(&mut self) -> Result<(), DeviceError> {
        if let Some(mut link) = self.link.take() {
            link.shut_down();
        }
        Ok(())
    }

    fn write_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        DeviceError::check_finite_force(force_n.to_array())?;
        let sequence = self.sequence + 1;
        let link = self.link_mut()?;
        if link.shared.link_down.load(Ordering::Acquire) {
            return Err(DeviceError::Disconnected {
                during: "sending a force to the Inverse Service",
                kind: std::io::ErrorKind::ConnectionReset,
            });
        }
        link.forces
            .push(ForceCommand { sequence, force_n })
            .map_err(|_| DeviceError::Timeout {
                waited_us: inverse_service::FORCE_RING_CAPACITY as u64 * 1000,
                waiting_for: "the Inverse Service I/O thread to take queued forces",
            })?;
        link.wake();
        self.sequence = sequence;
        Ok(())
    }

    fn read_state(&mut self) -> Result<DeviceState, DeviceError> {
        let (wanted, wait, max_stale) = (
            self.sequence,
            self.config.reply_wait,
            self.config.max_stale_ticks,
        );
        // The link through the field, not `link_mut`, so `state_age_ticks` can be set while it is borrowed.
        let link = self.link.as_mut().ok_or_else(not_open)?;
        // A service that sends more than one message per command is reported at its 1st, 10th, 100th and
        // 1 000th extra message, then every 1 000 more: a handful of reports however long it goes on.
        let extra = link.shared.extra.load(Ordering::Relaxed);
        if let Some(event) = self.surplus.add(extra.saturating_sub(self.surplus.total())) {
            self.pending_event = Some(event);
        }
        let started = Instant::now();
        let (spin_until, deadline) = (started + REPLY_SPIN.min(wait), started + wait);
        loop {
            if link.shared.link_down.load(Ordering::Acquire) {
                return Err(DeviceError::Disconnected {
                    during: "reading the Inverse Service's state",
                    kind: std::io::ErrorKind::ConnectionReset,
                });
            }
            let snapshot = *link.states.read();
            let answered = snapshot.answers_sequence >= wanted;
            let now = Instant::now();
            if answered
                || (now >= deadline
                    && snapshot.answers_sequence > 0
                    && wanted - snapshot.answers_sequence <= max_stale)
            {
                let age = wanted.saturating_sub(snapshot.answers_sequence);
                self.state_age_ticks = u32::try_from(age).unwrap_or(u32::MAX);
                return Ok(DeviceState {
                    position_m: snapshot.position_m,
                    velocity_m_per_s: snapshot.velocity_m_per_s,
                    buttons: 0,
                    device_time_us: None,
                    sequence: None,
                    status: None,
                });
            }
            if now >= deadline {
                return Err(DeviceError::Timeout {
                    waited_us: u64::try_from(wait.as_micros()).unwrap_or(u64::MAX),
                    waiting_for: "the Inverse Service's state update",
                });
            }
            if now < spin_until {
                std::hint::spin_loop();
            } else {
                // Let the I/O thread and the service have this CPU (module docs).
                std::thread::yield_now();
            }
        }
    }

    fn state_age_ticks(&self) -> u32 {
        self.state_age_ticks
    }

    fn take_event(&mut self) -> Option<DeviceEvent> {
        self.pending_event.take()
    }
}

impl Drop for HaplyInverse {
    fn drop(&mut self) {
        let _ = self.close();
    }
}
