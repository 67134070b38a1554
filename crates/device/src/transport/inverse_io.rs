//! The Inverse Service link's I/O thread: sends each force as soon as it is queued, reads every message the
//! service has sent (draining to the newest), and publishes the newest state to the servo thread. The
//! protocol, the invariants on reply labels and the flood and write bounds are described in
//! [`super::inverse_service`]. Allocates as it needs (it is not the servo thread).

use super::{
    ForceCommand, ServiceShared, ServiceSnapshot, Socket, FORCE_RING_CAPACITY, KEEPALIVE_INTERVAL,
    MAX_DRAIN_MESSAGES, WRITE_TIMEOUT,
};
use crate::transport::inverse_wire::{force_message, parse_frame_text, WireError, WireState};
use glam::DVec3;
use std::os::fd::AsRawFd;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tungstenite::Message;

/// Applies a state object (absent fields keep their value); false when there is none or it holds a
/// non-finite position.
pub(super) fn apply_state(snapshot: &mut ServiceSnapshot, state: Option<&WireState>) -> bool {
    let Some(state) = state else {
        return false;
    };
    if let Some(p) = state.cursor_position {
        if !p.is_finite() {
            return false;
        }
        snapshot.position_m = p;
    }
    if let Some(v) = state.cursor_velocity.filter(|v| v.is_finite()) {
        snapshot.velocity_m_per_s = v;
    }
    if let Some(f) = state.current_cursor_force.filter(|f| f.is_finite()) {
        snapshot.arm_force_n = Some(f);
    }
    true
}

pub(super) fn is_would_block(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e) if e.kind() == std::io::ErrorKind::WouldBlock)
}

/// Waits until the socket has `events` (`POLLIN`, `POLLOUT`) or `timeout` passes (rounded up to 1 ms).
pub(super) fn poll_socket(socket: &Socket, events: libc::c_short, timeout: Duration) {
    let mut fd = libc::pollfd {
        fd: socket.get_ref().stream.as_raw_fd(),
        events,
        revents: 0,
    };
    let ms = i32::try_from(timeout.as_micros().div_ceil(1000)).unwrap_or(i32::MAX);
    // SAFETY: one valid pollfd for the duration of the call; the descriptor stays open (we own the socket).
    unsafe {
        libc::poll(&mut fd, 1, ms);
    }
}

/// The I/O thread's state.
pub(super) struct IoLoop {
    pub(super) socket: Socket,
    pub(super) device_id: String,
    pub(super) states: triple_buffer::Input<ServiceSnapshot>,
    pub(super) snapshot: ServiceSnapshot,
    pub(super) shared: Arc<ServiceShared>,
    /// Sequences of the messages sent whose replies have not come yet, oldest first.
    pub(super) unanswered: std::collections::VecDeque<u64>,
    /// The newest force sequence sent.
    pub(super) last_sent: u64,
    /// The newest force sequence sent before the socket was last found empty: every message read after
    /// that was written by the service after that force was sent (a TCP stream keeps the order).
    pub(super) floor: u64,
}

impl IoLoop {
    pub(super) fn run(mut self, mut forces: rtrb::Consumer<ForceCommand>, reply_timeout: Duration) {
        let result = self.exchange(&mut forces, reply_timeout);
        let result = result.and_then(|()| {
            // Stop: zero force, then close.
            let zero = force_message(&self.device_id, DVec3::ZERO);
            self.send(Message::text(zero))?;
            let _ = self.socket.close(None);
            let _ = self.flush_within(Instant::now() + WRITE_TIMEOUT);
            Ok(())
        });
        if result.is_err() {
            self.shared.link_down.store(true, Ordering::Release);
        }
    }

    fn exchange(
        &mut self,
        forces: &mut rtrb::Consumer<ForceCommand>,
        reply_timeout: Duration,
    ) -> Result<(), tungstenite::Error> {
        let mut last_send = Instant::now();
        while !self.shared.stop.load(Ordering::Acquire) {
            // Whatever came since the last look (a second reply, an unsolicited update) is read now, so the
            // servo thread always gets the newest state and nothing queues up unread.
            self.drain()?;
            let mut newest = None;
            while let Ok(command) = forces.pop() {
                if newest.is_some() {
                    self.shared.coalesced.fetch_add(1, Ordering::Relaxed);
                }
                newest = Some(command);
            }
            let (sequence, force_n) = match newest {
                Some(command) => (command.sequence, command.force_n),
                None if last_send.elapsed() >= KEEPALIVE_INTERVAL => (self.last_sent, DVec3::ZERO),
                None => {
                    std::thread::park_timeout(Duration::from_micros(500));
                    continue;
                }
            };
            // The driver refuses non-finite forces; a NaN must never reach the device all the same.
            let force_n = if force_n.is_finite() {
                force_n
            } else {
                DVec3::ZERO
            };
            let text = force_message(&self.device_id, force_n);
            self.send(Message::text(text))?;
            last_send = Instant::now();
            self.last_sent = self.last_sent.max(sequence);
            self.shared.sent.fetch_add(1, Ordering::Relaxed);
            if self.unanswered.len() >= FORCE_RING_CAPACITY {
                // The service has left this many messages unanswered: forget the oldest (the driver has long
                // reported the missing states, and the link is dropped well before this in a session).
                self.unanswered.pop_front();
            }
            self.unanswered.push_back(sequence);
            // One reply per message, in the order sent: read until this message's reply has come (or
            // `reply_timeout`: it may still come, and is then labelled with its own, older sequence).
            let deadline = Instant::now() + reply_timeout;
            loop {
                self.drain()?;
                let now = Instant::now();
                if self.unanswered.is_empty()
                    || now >= deadline
                    || self.shared.stop.load(Ordering::Acquire)
                {
                    break;
                }
                poll_socket(
                    &self.socket,
                    libc::POLLIN,
                    (deadline - now).min(Duration::from_millis(1)),
                );
            }
        }
        Ok(())
    }

    /// Reads every complete message already received, until the socket has nothing more; then raises
    /// `floor`. A service that keeps more than [`MAX_DRAIN_MESSAGES`] coming is flooding the link: error.
    fn drain(&mut self) -> Result<(), tungstenite::Error> {
        for _ in 0..MAX_DRAIN_MESSAGES {
            match self.socket.read() {
                Ok(message @ (Message::Text(_) | Message::Binary(_))) => self.take(&message),
                Ok(Message::Close(_)) => return Err(tungstenite::Error::ConnectionClosed),
                Ok(_) => {}
                Err(error) if is_would_block(&error) => {
                    self.floor = self.last_sent;
                    return Ok(());
                }
                Err(error) => return Err(error),
            }
        }
        self.shared.flooded.store(true, Ordering::Release);
        Err(tungstenite::Error::Io(std::io::Error::other(
            "the Inverse Service sends more messages than voxhap can read",
        )))
    }

    /// One message from the service: the reply to the oldest unanswered message, or an extra one.
    fn take(&mut self, message: &Message) {
        let answers = self.unanswered.pop_front();
        if answers.is_none() {
            self.shared.extra.fetch_add(1, Ordering::Relaxed);
        }
        let text = match message {
            Message::Text(text) => Some(text.as_str()),
            _ => None,
        };
        let used = match text.map(parse_frame_text) {
            Some(Ok(frame)) => frame
                .inverse3
                .into_iter()
                .find(|d| d.device_id == self.device_id)
                .is_some_and(|entry| apply_state(&mut self.snapshot, entry.state.as_ref())),
            Some(Err(error)) => {
                if let WireError::TypeDrift { .. } = error {
                    self.shared.drifted.fetch_add(1, Ordering::Relaxed);
                    let mut first = self
                        .shared
                        .first_drift
                        .lock()
                        .unwrap_or_else(|e| e.into_inner());
                    first.get_or_insert_with(|| error.to_string());
                }
                false
            }
            None => false,
        };
        if used {
            // The label says which force the state answers at the latest: the reply's own message, but never
            // one sent after the socket was last found empty (a reply counted against the wrong message
            // because the service sent extra ones is then at most as new as that). An extra message updates
            // the position and keeps the label.
            if let Some(answers) = answers {
                let label = answers.min(self.floor);
                self.snapshot.answers_sequence = self.snapshot.answers_sequence.max(label);
            }
            self.states.write(self.snapshot);
            self.shared.states.fetch_add(1, Ordering::Relaxed);
        } else {
            self.shared.malformed.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Sends one message, waiting at most [`WRITE_TIMEOUT`] for room in the socket's send buffer.
    fn send(&mut self, message: Message) -> Result<(), tungstenite::Error> {
        match self.socket.send(message) {
            Ok(()) => Ok(()),
            Err(error) if is_would_block(&error) => {
                self.flush_within(Instant::now() + WRITE_TIMEOUT)
            }
            Err(error) => Err(error),
        }
    }

    fn flush_within(&mut self, deadline: Instant) -> Result<(), tungstenite::Error> {
        loop {
            match self.socket.flush() {
                Ok(()) => return Ok(()),
                Err(error) if is_would_block(&error) => {
                    let now = Instant::now();
                    if now >= deadline {
                        return Err(tungstenite::Error::Io(std::io::Error::new(
                            std::io::ErrorKind::TimedOut,
                            "the Inverse Service reads nothing",
                        )));
                    }
                    poll_socket(&self.socket, libc::POLLOUT, deadline - now);
                }
                Err(error) => return Err(error),
            }
        }
    }
}
