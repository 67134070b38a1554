//! The device itself: the SPEC section 6 state machine, its watchdog and streaming on a 1 kHz control loop, and
//! the misbehaviours, run in a thread on the master side of the pty.

use super::config::{HandleTime, SpecDeviceConfig, Trigger};
use super::log::{ForceRecord, HostMessage, Log, MessageRecord, SentRecord, TriggerRecord};
use super::wire::{
    cobs_encode, crc16, decode_frame, encode_frame, fault, label, put_vec3, reject, status, types,
    u16_at, u32_at, used_components, vec3_at,
};
use std::collections::VecDeque;
use std::os::fd::{AsRawFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------------------------
// The device.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Drive {
    Idle,
    Enabled,
    Faulted,
}

pub(super) struct Outgoing {
    pub(super) due: Instant,
    pub(super) message_type: u8,
    pub(super) detail: u16,
    pub(super) bytes: Vec<u8>,
    pub(super) intact: bool,
}

pub(super) struct Device {
    pub(super) config: SpecDeviceConfig,
    pub(super) master: OwnedFd,
    pub(super) log: Arc<Mutex<Log>>,
    pub(super) spawned: Instant,
    // SPEC section 6 state.
    pub(super) session_open: bool,
    pub(super) drive: Drive,
    pub(super) watchdog_timeout_us: u64,
    pub(super) last_feed: Instant,
    pub(super) applied_force_n: [f32; 3],
    pub(super) force_clamped: bool,
    pub(super) watchdog_tripped: bool,
    pub(super) faults: u16,
    pub(super) last_force_sequence: u32,
    pub(super) state_sequence: u32,
    pub(super) state_rate_hz: u16,
    pub(super) next_state_at: Instant,
    // Bookkeeping.
    pub(super) first_enable: Option<Instant>,
    /// |force| of the last SetForce applied since the latest Enable (`None` until one is).
    pub(super) last_applied_n: Option<f32>,
    /// Triggers that have fired, and when.
    pub(super) fired: Vec<(Trigger, Instant)>,
    pub(super) fault_done: bool,
    pub(super) reset_done: bool,
    pub(super) silence_from: Option<Instant>,
    pub(super) device_infos_sent: u32,
    pub(super) frames_written: u32,
    pub(super) rng: u64,
    pub(super) rx: Vec<u8>,
    pub(super) rx_overflow: bool,
    pub(super) outbox: VecDeque<Outgoing>,
    pub(super) last_position: [f32; 3],
    pub(super) last_sample_at: Instant,
    pub(super) host_attached: bool,
    /// Our own fd on the slave side, held until the host has sent its first byte (so nothing written before the
    /// host opens the pty is lost), then closed so that the host closing the port shows as a hang-up.
    pub(super) slave: Option<OwnedFd>,
}

impl Device {
    fn now_us(&self, at: Instant) -> u64 {
        at.duration_since(self.spawned).as_micros() as u64
    }

    /// Whether `trigger` has fired (latched at a control cycle, [`Device::latch_triggers`]).
    fn triggered(&self, trigger: Trigger) -> bool {
        self.fired_at(trigger).is_some()
    }

    fn fired_at(&self, trigger: Trigger) -> Option<Instant> {
        self.fired
            .iter()
            .find(|(t, _)| *t == trigger)
            .map(|&(_, at)| at)
    }

    /// Whether the condition of `trigger` holds now.
    fn holds(&self, trigger: Trigger, now: Instant) -> bool {
        match trigger {
            Trigger::AfterFirstEnable(d) => self.first_enable.is_some_and(|t| now >= t + d),
            Trigger::ForceAbove(newtons) => {
                self.drive == Drive::Enabled && self.last_applied_n.is_some_and(|f| f > newtons)
            }
        }
    }

    /// Latches every configured trigger whose condition holds now, logs it, and runs a `call_at` action whose
    /// trigger just fired.
    fn latch_triggers(&mut self, now: Instant) {
        let c = &self.config;
        let triggers = [
            c.fault.map(|(t, _)| t),
            c.silence.map(|(t, _)| t),
            c.position_glitch.map(|(t, _)| t),
            c.velocity_override.map(|(t, _)| t),
            c.noise_from,
            c.reset,
            c.handle_hold,
            c.call_at.as_ref().map(|(t, _)| *t),
        ];
        for trigger in triggers.into_iter().flatten() {
            if self.triggered(trigger) || !self.holds(trigger, now) {
                continue;
            }
            self.fired.push((trigger, now));
            if let Some((_, action)) = self.config.call_at.as_ref().filter(|(t, _)| *t == trigger) {
                action();
            }
            let mut log = self.log.lock().unwrap();
            let index = log.index();
            log.triggers.push(TriggerRecord {
                index,
                at: now,
                trigger,
            });
        }
    }

    fn status(&self) -> u16 {
        let mut s = 0;
        if self.session_open {
            s |= status::SESSION_OPEN;
        }
        match self.drive {
            Drive::Enabled => s |= status::ENABLED,
            Drive::Faulted => s |= status::FAULTED,
            Drive::Idle => {}
        }
        if self.watchdog_tripped {
            s |= status::WATCHDOG_TRIPPED;
        }
        if self.force_clamped && self.drive == Drive::Enabled {
            s |= status::FORCE_CLAMPED;
        }
        if self.state_rate_hz == 0 {
            s |= status::LOCKSTEP;
        }
        s
    }

    fn queue(&mut self, message_type: u8, payload: &[u8], detail: u16, now: Instant) {
        let mut bytes = encode_frame(message_type, payload);
        let mut intact = true;
        if message_type == types::DEVICE_INFO {
            self.device_infos_sent += 1;
            if self.device_infos_sent <= self.config.corrupt_device_infos {
                // Flip the CRC (then stuff again so the COBS framing itself stays valid).
                let mut raw = vec![message_type];
                raw.extend_from_slice(payload);
                let crc = crc16(&raw) ^ 0x5A5A;
                raw.extend_from_slice(&crc.to_le_bytes());
                bytes = cobs_encode(&raw);
                bytes.push(0);
                intact = false;
            }
        }
        self.outbox.push_back(Outgoing {
            due: now + self.config.reply_delay,
            message_type,
            detail,
            bytes,
            intact,
        });
    }

    fn reject(&mut self, message_type: u8, reason: u8, now: Instant) {
        self.queue(
            types::REJECTED,
            &[message_type, reason],
            u16::from(reason),
            now,
        );
    }

    fn raise_fault(&mut self, code: u8, now: Instant) {
        if code == fault::WATCHDOG_EXPIRED {
            self.watchdog_tripped = true;
            if self.drive == Drive::Enabled {
                self.drive = Drive::Idle;
            }
        } else {
            self.faults |= 1 << code;
            self.drive = Drive::Faulted;
        }
        self.applied_force_n = [0.0; 3];
        let mut payload = vec![code];
        payload.extend_from_slice(&self.faults.to_le_bytes());
        payload.extend_from_slice(&self.now_us(now).to_le_bytes());
        self.queue(types::FAULT, &payload, u16::from(code), now);
    }

    fn send_device_info(&mut self, now: Instant) {
        let c = &self.config;
        let mut p = vec![c.version.0, c.version.1];
        p.extend_from_slice(&label(&c.model));
        p.extend_from_slice(&label(&c.serial_number));
        p.extend_from_slice(&[c.position_dof, c.force_dof, 0, c.supported_rates]);
        let (min, max) = (c.workspace_min_m, c.workspace_max_m);
        put_vec3(&mut p, min);
        put_vec3(&mut p, max);
        p.extend_from_slice(&c.max_force_n.to_le_bytes());
        p.extend_from_slice(&c.max_stiffness_n_per_m.to_le_bytes());
        // A slow answer: the DeviceInfo is due later; the outbox is written in order, so whatever the device
        // queues after it waits too.
        let slow = self
            .config
            .device_info_delay_from
            .is_none_or(|t| self.triggered(t));
        let now = if slow {
            now + self.config.device_info_delay
        } else {
            now
        };
        // SPEC section 4.3: a lone 0x00 before each DeviceInfo.
        self.outbox.push_back(Outgoing {
            due: now + self.config.reply_delay,
            message_type: 0,
            detail: 0,
            bytes: vec![0],
            intact: true,
        });
        self.queue(types::DEVICE_INFO, &p, 0, now);
    }

    /// The handle as sensed now: scripted position plus any glitch, and the velocity (finite difference or the
    /// injected override).
    fn sample(&mut self, now: Instant) -> ([f32; 3], [f32; 3]) {
        // A held handle is where the script had it when the hold began.
        let script_at = self
            .config
            .handle_hold
            .and_then(|t| self.fired_at(t))
            .unwrap_or(now);
        let time = HandleTime {
            since_spawn_s: script_at.duration_since(self.spawned).as_secs_f64(),
            since_first_enable_s: self
                .first_enable
                .map(|t| script_at.saturating_duration_since(t).as_secs_f64()),
        };
        let mut position = (self.config.handle)(time);
        if let Some((trigger, jump)) = self.config.position_glitch {
            if self.triggered(trigger) {
                for (p, j) in position.iter_mut().zip(jump) {
                    *p += j;
                }
            }
        }
        let dt = now.duration_since(self.last_sample_at).as_secs_f32();
        let mut velocity = if dt > 1e-4 {
            let v = [0, 1, 2].map(|i| (position[i] - self.last_position[i]) / dt);
            self.last_position = position;
            self.last_sample_at = now;
            v
        } else {
            [0.0; 3]
        };
        if let Some((trigger, v)) = self.config.velocity_override {
            if self.triggered(trigger) {
                velocity = v;
            }
        }
        // SPEC 6.8: a 1- or 2-DOF device reports its unused components as 0 (or, misbehaving, as garbage).
        let dof = self.config.position_dof;
        position = used_components(position, dof);
        velocity = used_components(velocity, dof);
        if let Some((garbage_position, garbage_velocity)) = self.config.unused_components {
            let unused = match dof {
                1 | 2 => usize::from(dof)..3,
                _ => 3..3,
            };
            position[unused.clone()].copy_from_slice(&garbage_position[unused.clone()]);
            velocity[unused.clone()].copy_from_slice(&garbage_velocity[unused]);
        }
        (position, velocity)
    }

    fn send_state(&mut self, now: Instant) {
        let (position, velocity) = self.sample(now);
        self.state_sequence = self.state_sequence.wrapping_add(1);
        let mut p = Vec::with_capacity(46);
        p.extend_from_slice(&self.state_sequence.to_le_bytes());
        p.extend_from_slice(&self.now_us(now).to_le_bytes());
        put_vec3(&mut p, position);
        put_vec3(&mut p, velocity);
        p.extend_from_slice(&self.last_force_sequence.to_le_bytes());
        p.extend_from_slice(&0u16.to_le_bytes());
        let status = self.status();
        p.extend_from_slice(&status.to_le_bytes());
        p.extend_from_slice(&self.faults.to_le_bytes());
        self.queue(types::STATE, &p, status, now);
    }

    fn on_frame(&mut self, message_type: u8, p: &[u8], now: Instant) {
        let record = |device: &mut Device, message: HostMessage| {
            let mut log = device.log.lock().unwrap();
            let index = log.index();
            log.messages.push(MessageRecord {
                index,
                at: now,
                message,
            });
        };
        match message_type {
            types::SET_FORCE => {
                let sequence = u32_at(p, 0);
                let force_n = vec3_at(p, 4);
                let flags = u16_at(p, 16);
                {
                    let enabled = self.drive == Drive::Enabled && self.session_open;
                    let mut log = self.log.lock().unwrap();
                    let index = log.index();
                    log.forces.push(ForceRecord {
                        index,
                        at: now,
                        sequence,
                        force_n,
                        enabled,
                    });
                }
                if force_n.iter().any(|f| !f.is_finite()) {
                    // SPEC section 1: dropped as invalid_value; not answered.
                    self.log.lock().unwrap().dropped_frames += 1;
                    return;
                }
                if !self.session_open {
                    return; // SPEC section 6: ignored, not answered.
                }
                self.last_force_sequence = sequence;
                if self.drive == Drive::Enabled {
                    // SPEC 6.8: a 1- or 2-DOF device ignores the components it does not render (the log above
                    // keeps what arrived, so a test still sees them).
                    let force_n = used_components(force_n, self.config.force_dof);
                    let norm = force_n
                        .iter()
                        .map(|f| f64::from(*f).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    self.last_applied_n = Some(norm as f32);
                    let max = f64::from(self.config.max_force_n);
                    if norm > max {
                        self.applied_force_n = force_n.map(|f| (f64::from(f) * max / norm) as f32);
                        self.force_clamped = true;
                    } else {
                        self.applied_force_n = force_n;
                        self.force_clamped = false;
                    }
                    self.last_feed = now;
                }
                // Lockstep: one State per SetForce, sampled now (SPEC section 6.6); REQUEST_STATE when streaming.
                if self.state_rate_hz == 0 || flags & 1 != 0 {
                    self.send_state(now);
                }
            }
            types::HELLO => {
                record(
                    self,
                    HostMessage::Hello {
                        major: p[0],
                        minor: p[1],
                    },
                );
                self.send_device_info(now);
                if self.drive == Drive::Enabled {
                    self.drive = Drive::Idle;
                }
                self.applied_force_n = [0.0; 3];
                self.state_rate_hz = 0;
                self.watchdog_timeout_us = 50_000;
                self.session_open = p[0] == self.config.version.0;
                if !self.session_open {
                    self.reject(types::HELLO, reject::VERSION_MISMATCH, now);
                }
            }
            types::HEARTBEAT => {
                let counter = u32_at(p, 0);
                record(self, HostMessage::Heartbeat { counter });
                let mut reply = counter.to_le_bytes().to_vec();
                reply.extend_from_slice(&self.now_us(now).to_le_bytes());
                let status = self.status();
                reply.extend_from_slice(&status.to_le_bytes());
                self.queue(types::HEARTBEAT_REPLY, &reply, status, now);
            }
            other => {
                let message = match other {
                    types::ENABLE => HostMessage::Enable {
                        watchdog_timeout_us: u32_at(p, 0),
                    },
                    types::DISABLE => HostMessage::Disable,
                    types::CLEAR_FAULT => HostMessage::ClearFault,
                    types::SET_STATE_RATE => HostMessage::SetStateRate { hz: u16_at(p, 0) },
                    _ => return, // a device-to-host type: dropped as unknown_type
                };
                record(self, message);
                if !self.session_open {
                    return self.reject(other, reject::NO_SESSION, now);
                }
                match message {
                    HostMessage::Enable {
                        watchdog_timeout_us,
                    } => self.enable(watchdog_timeout_us, now),
                    HostMessage::Disable => {
                        if self.drive == Drive::Enabled {
                            self.drive = Drive::Idle;
                        }
                        self.applied_force_n = [0.0; 3];
                    }
                    HostMessage::ClearFault if self.drive == Drive::Faulted => {
                        self.faults = 0;
                        self.drive = Drive::Idle;
                    }
                    HostMessage::SetStateRate { hz } => {
                        let table = [100, 200, 250, 500, 1000, 2000, 4000, 8000];
                        let supported = table.iter().enumerate().any(|(bit, &r)| {
                            r == hz && self.config.supported_rates & (1 << bit) != 0
                        });
                        if hz == 0 || supported {
                            self.state_rate_hz = hz;
                            self.next_state_at = now;
                        } else {
                            self.reject(other, reject::INVALID_ARGUMENT, now);
                        }
                    }
                    _ => {}
                }
            }
        }
    }

    fn enable(&mut self, requested_us: u32, now: Instant) {
        if let Some(reason) = self.config.refuse_enable {
            return self.reject(types::ENABLE, reason, now);
        }
        if self.drive == Drive::Faulted {
            return self.reject(types::ENABLE, reject::FAULTED, now);
        }
        let timeout_us = match requested_us {
            0 => 50_000,
            t @ 1_000..=1_000_000 => t,
            _ => return self.reject(types::ENABLE, reject::INVALID_ARGUMENT, now),
        };
        self.drive = Drive::Enabled;
        self.last_applied_n = None;
        self.watchdog_timeout_us = u64::from(timeout_us);
        self.last_feed = now;
        self.applied_force_n = [0.0; 3];
        self.force_clamped = false;
        self.watchdog_tripped = false;
        self.first_enable.get_or_insert(now);
    }

    /// One periodic 1 kHz control cycle: watchdog, injected faults, streamed States.
    fn control_cycle(&mut self, now: Instant) {
        self.latch_triggers(now);
        if self.drive == Drive::Enabled
            && now.duration_since(self.last_feed) > Duration::from_micros(self.watchdog_timeout_us)
        {
            self.raise_fault(fault::WATCHDOG_EXPIRED, now);
        }
        if let Some((trigger, code)) = self.config.fault {
            if !self.fault_done && self.triggered(trigger) {
                self.fault_done = true;
                self.raise_fault(code, now);
            }
        }
        if let Some(trigger) = self.config.reset {
            if !self.reset_done && self.triggered(trigger) {
                self.reset_done = true;
                self.power_up(now);
            }
        }
        if self.silence_from.is_none() {
            if let Some((trigger, _)) = self.config.silence {
                if self.triggered(trigger) {
                    self.silence_from = Some(now);
                }
            }
        }
        if self.session_open && self.state_rate_hz != 0 && now >= self.next_state_at {
            let period = Duration::from_secs_f64(1.0 / f64::from(self.state_rate_hz));
            self.next_state_at = if now.duration_since(self.next_state_at) >= period {
                now + period
            } else {
                self.next_state_at + period
            };
            self.send_state(now);
        }
    }

    /// Back to the power-up state (SPEC section 6: session closed, drive Idle, zero force), as after a reset.
    fn power_up(&mut self, now: Instant) {
        self.session_open = false;
        self.drive = Drive::Idle;
        self.watchdog_timeout_us = 50_000;
        self.applied_force_n = [0.0; 3];
        self.force_clamped = false;
        self.watchdog_tripped = false;
        self.faults = 0;
        self.last_force_sequence = 0;
        self.state_sequence = 0;
        self.state_rate_hz = 0;
        self.rx.clear();
        self.outbox.clear();
        self.outbox.push_back(Outgoing {
            due: now,
            message_type: 0,
            detail: 0,
            bytes: vec![0],
            intact: true,
        });
    }

    fn silent(&self, now: Instant) -> bool {
        match (self.silence_from, self.config.silence) {
            (Some(from), Some((_, duration))) => now < from + duration,
            _ => false,
        }
    }

    fn next_random(&mut self) -> u64 {
        // xorshift64*
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn transmit(&mut self, now: Instant) {
        while self.outbox.front().is_some_and(|o| o.due <= now) {
            let Some(mut out) = self.outbox.pop_front() else {
                break;
            };
            if self.silent(now) {
                continue; // silence: the frame is lost, not postponed
            }
            let noisy = self.config.noise_from.is_none_or(|t| self.triggered(t));
            if out.message_type != 0 && noisy {
                self.frames_written += 1;
                if let Some(every) = self.config.partial_frame_every {
                    if every > 0 && self.frames_written.is_multiple_of(every) {
                        out.bytes.truncate(out.bytes.len() / 2);
                        out.intact = false;
                    }
                }
            }
            if noisy && self.config.corrupt_fraction > 0.0 {
                for i in 0..out.bytes.len() {
                    let r = self.next_random();
                    let unit = (r >> 11) as f64 / (1u64 << 53) as f64;
                    if unit < self.config.corrupt_fraction {
                        out.bytes[i] = (self.next_random() >> 56) as u8;
                        out.intact = false;
                    }
                }
            }
            write_all(self.master.as_raw_fd(), &out.bytes);
            if out.message_type != 0 {
                let mut log = self.log.lock().unwrap();
                let index = log.index();
                log.sent.push(SentRecord {
                    index,
                    at: Instant::now(),
                    message_type: out.message_type,
                    detail: out.detail,
                    intact: out.intact,
                });
            }
        }
    }

    /// Feeds received bytes through the frame collector (SPEC section 4.4).
    fn receive(&mut self, bytes: &[u8], now: Instant) {
        for &b in bytes {
            if b != 0 {
                if self.rx.len() < 66 {
                    self.rx.push(b);
                } else {
                    self.rx_overflow = true;
                }
                continue;
            }
            let frame = std::mem::take(&mut self.rx);
            let overflow = std::mem::replace(&mut self.rx_overflow, false);
            if frame.is_empty() && !overflow {
                continue; // idle filler
            }
            match (overflow, decode_frame(&frame)) {
                (false, Ok((message_type, payload))) => self.on_frame(message_type, &payload, now),
                _ => self.log.lock().unwrap().dropped_frames += 1,
            }
        }
    }

    pub(super) fn run(mut self, stop: Arc<AtomicBool>) {
        // SPEC section 4.3: a lone 0x00 at start-up.
        write_all(self.master.as_raw_fd(), &[0]);
        let period = Duration::from_millis(1);
        let mut next_cycle = Instant::now();
        let mut buffer = [0u8; 512];
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            let wait = next_cycle.saturating_duration_since(now);
            let wait = match self.outbox.front() {
                Some(o) => wait.min(o.due.saturating_duration_since(now)),
                None => wait,
            };
            let mut pfd = libc::pollfd {
                fd: self.master.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            let wait = wait.min(period);
            let timeout = libc::timespec {
                tv_sec: 0,
                tv_nsec: wait.subsec_nanos() as libc::c_long,
            };
            // SAFETY: one valid pollfd and a valid timespec for the duration of the call; no signal mask.
            let ready = unsafe { libc::ppoll(&mut pfd, 1, &timeout, std::ptr::null()) };
            let now = Instant::now();
            if ready > 0 && pfd.revents & libc::POLLIN != 0 {
                // SAFETY: reading into a buffer we own, at most its length.
                let n = unsafe {
                    libc::read(
                        self.master.as_raw_fd(),
                        buffer.as_mut_ptr().cast(),
                        buffer.len(),
                    )
                };
                if n > 0 {
                    self.host_attached = true;
                    self.slave = None;
                    let received = buffer[..n as usize].to_vec();
                    self.receive(&received, now);
                } else {
                    self.hang_up(now);
                }
            } else if ready > 0 && pfd.revents & (libc::POLLHUP | libc::POLLERR) != 0 {
                self.hang_up(now);
            }
            let now = Instant::now();
            if now >= next_cycle {
                self.control_cycle(now);
                next_cycle += period;
                if next_cycle < now {
                    next_cycle = now + period; // fell behind: skip, never burst
                }
            }
            self.transmit(Instant::now());
        }
    }

    fn hang_up(&mut self, now: Instant) {
        if self.host_attached {
            self.host_attached = false;
            self.rx.clear();
            let mut log = self.log.lock().unwrap();
            let index = log.index();
            log.messages.push(MessageRecord {
                index,
                at: now,
                message: HostMessage::PortClosed,
            });
        }
        // No slave is open: poll reports a hang-up at once, so pace the loop here.
        std::thread::sleep(Duration::from_micros(500));
    }
}

pub(super) fn write_all(fd: libc::c_int, mut bytes: &[u8]) {
    let deadline = Instant::now() + Duration::from_millis(50);
    while !bytes.is_empty() && Instant::now() < deadline {
        // SAFETY: writing from a slice we own, at most its length.
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        if n > 0 {
            bytes = &bytes[n as usize..];
        } else if std::io::Error::last_os_error().kind() == std::io::ErrorKind::WouldBlock {
            std::thread::sleep(Duration::from_micros(200));
        } else {
            return; // no reader (the host closed the port): the bytes are lost, as on a real line
        }
    }
}
