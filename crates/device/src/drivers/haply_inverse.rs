//! Haply Inverse3 (and Inverse3x, Minverse) through the Haply Inverse Service (`--device
//! haply-inverse[:ws://HOST:PORT[,events=ws://HOST:PORT]]`, default ws://127.0.0.1:10001).
//!
//! Where it sits: a [`HapticDevice`] whose `write_force` and `read_state` run on the servo thread and only push
//! to and pop from lock-free buffers. The connection and session set-up are
//! [`crate::transport::inverse_service`]'s (protocol, coordinate basis and sources are described there); the
//! exchange runs on this driver's I/O thread ([`io`]), a thin shell around the link's sans-IO protocol core
//! ([`link`]: what is sent, how replies are counted and labelled, floods, and the servo thread's verdict on
//! how old a state is), fed by the shared runner (`exchange::messages_within`).
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
//! Capabilities ([`limits::LIMITS`], every number with its vendor source): the workspace box is the Inverse3's
//! measured reachable box in Haply's default frame, so the host's input checks accept a handle anywhere the
//! arm can go; the force cap is voxhap's (Haply publishes none). The device profile may lower both.
//!
//! Safety events: the link's events channel ([`crate::transport::inverse_service::events`]) hands e-brake,
//! stall and stability-ceiling events to `take_event` as [`DeviceEvent::Fault`] (codes
//! [`FAULT_EMERGENCY_STOP`], [`FAULT_MOTOR_STALL`], [`FAULT_STABILITY_CEILING`]): the supervisor zeroes the force
//! on the tick it reads them and stays faulted until the operator clears it, through a dropped link and its
//! reconnect too (the supervisor keeps faults reported by event across a reconnect).

#[path = "haply_inverse_io.rs"]
pub mod io;
#[path = "haply_inverse_limits.rs"]
pub mod limits;
#[path = "haply_inverse_link.rs"]
pub mod link;

pub use link::{FAULT_EMERGENCY_STOP, FAULT_MOTOR_STALL, FAULT_STABILITY_CEILING};

use crate::transport::inverse_service::{self, ForceCommand, ServiceConfig, ServiceLink};
use crate::{DeviceError, DeviceEvent, DeviceInfo, DeviceState, HapticDevice, SurplusCount};
use glam::DVec3;
use link::Verdict;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// voxhap's default force cap for the Inverse3 (N); a profile may lower it.
pub const DEFAULT_MAX_FORCE_N: f64 = limits::DEFAULT_MAX_FORCE_N;
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

impl HaplyInverseConfig {
    /// These settings for a servo loop of `period`: no wait is longer than the period, so a late or lost state
    /// never holds a tick. The servo thread's wait for its answer is at most 0.4 of it
    /// ([`link::reply_wait_for`]); the I/O thread's wait for a reply and its sleep with nothing to send are at
    /// most one period each (a reply later than that is read on the next round, labelled with its own older
    /// sequence). At 1 kHz the servo thread's wait stays 0.4 ms.
    pub fn for_period(mut self, period: Duration) -> Self {
        self.reply_wait = link::reply_wait_for(self.reply_wait, period);
        self.service.reply_timeout = self.service.reply_timeout.min(period);
        self.service.idle_wait = self.service.idle_wait.min(period);
        self
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
    /// Fault bits latched by the service's safety events on this link.
    active_faults: u16,
    /// The force that reached the arm (the service's `current_cursor_force`) in the last state read.
    arm_force_n: Option<DVec3>,
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
            workspace_min_m: DVec3::from_array(limits::REACHABLE_MIN_M),
            workspace_max_m: DVec3::from_array(limits::REACHABLE_MAX_M),
            max_force_n: config.max_force_n,
            max_stiffness_n_per_m: limits::MAX_STIFFNESS_N_PER_M,
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
            active_faults: 0,
            arm_force_n: None,
        }
    }

    /// A driver already running on `link` (the tests' doubles of the service's socket).
    #[cfg(test)]
    pub(crate) fn on_link(config: HaplyInverseConfig, link: ServiceLink) -> HaplyInverse {
        let mut driver = HaplyInverse::new(config);
        driver.link = Some(link);
        driver
    }

    /// The settings in use.
    pub fn config(&self) -> &HaplyInverseConfig {
        &self.config
    }

    /// The force that reached the arm after the service's filters, as the service reported it with the last
    /// state read (`current_cursor_force`, N, Haply's frame); `None` until it reports one.
    pub fn arm_force_n(&self) -> Option<DVec3> {
        self.arm_force_n
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
        let session = inverse_service::handshake(&self.config.service)?;
        let link = io::start(session, &self.config.service)?;
        let device = &link.device;
        self.info.model = format!("Haply {} (Inverse Service)", device.device_type);
        self.info.serial_number = device.device_id.clone();
        self.sequence = 0;
        self.surplus = SurplusCount::default();
        self.pending_event = None;
        self.active_faults = 0;
        self.arm_force_n = None;
        if let inverse_service::Configuration::Unconfirmed(why) = &device.configuration {
            eprintln!(
                "voxhap: Haply Inverse Service: the session's frame (preset {:?}, basis {:?}, no mount) is set but \
                 not confirmed: {why}",
                inverse_service::SESSION_PRESET,
                inverse_service::SESSION_BASIS
            );
        }
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
            let now = Instant::now();
            let verdict = link::judge(
                snapshot.answers_sequence,
                wanted,
                now >= deadline,
                max_stale,
            );
            if let Verdict::Use { age_ticks } = verdict {
                self.state_age_ticks = age_ticks;
                self.arm_force_n = snapshot.arm_force_n;
                return Ok(DeviceState {
                    position_m: snapshot.position_m,
                    velocity_m_per_s: snapshot.velocity_m_per_s,
                    buttons: 0,
                    device_time_us: None,
                    sequence: None,
                    status: None,
                });
            }
            if verdict == Verdict::Late {
                if link.shared.drifted.load(Ordering::Relaxed) > 0 {
                    // Not a slow service: its messages have a field in another type than Haply documents
                    // (the reconnect's open names the field).
                    return Err(DeviceError::Protocol {
                        what: "the Inverse Service's state updates carry a field voxhap uses in another JSON \
                               type than Haply documents",
                    });
                }
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

    /// The operator's clear: the safety events are forgotten (Haply's own e-brake lock is released on the arm
    /// or in Haply Hub, not here).
    fn clear_fault(&mut self) -> Result<(), DeviceError> {
        self.active_faults = 0;
        Ok(())
    }

    fn reported_force_n(&self) -> Option<DVec3> {
        self.arm_force_n
    }

    fn link_latency(&self) -> Option<crate::latency::LinkLatency> {
        Some(crate::latency::HAPLY_INVERSE)
    }

    fn take_event(&mut self) -> Option<DeviceEvent> {
        if let Some(event) = self.pending_event.take() {
            return Some(event);
        }
        let event = self.link.as_mut()?.events.pop()?;
        let code = link::fault_code(event);
        self.active_faults |= 1 << code;
        Some(DeviceEvent::Fault {
            code,
            active_faults: self.active_faults,
        })
    }
}

impl Drop for HaplyInverse {
    fn drop(&mut self) {
        let _ = self.close();
    }
}
