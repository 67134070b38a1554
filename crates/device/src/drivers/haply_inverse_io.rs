//! The Inverse3 link's I/O thread: a thin shell that moves forces from the servo thread's ring to the service
//! and the service's messages into the protocol core ([`super::link::LinkCore`], which decides what to send,
//! how each message counts and how the state is labelled), through the shared runner
//! ([`crate::drivers::exchange::messages_within`]); it publishes each state the core hands out to the servo
//! thread's triple buffer and mirrors the core's counters into the shared atomics. Decoding (`inverse_wire`)
//! and the socket (`transport/inverse_io.rs`) allocate as they need: this is not the servo thread.
//!
//! Per round: read what is waiting, take the newest queued force (or a keepalive the core asks for), send it,
//! then read until its reply has come or `reply_timeout` has passed (the reply may still come and is then
//! labelled with its own, older sequence); with nothing to send, sleep until the servo thread queues a force
//! or `idle_wait` has passed. Both waits derive from the servo period
//! ([`super::HaplyInverseConfig::for_period`]: at most one period each), so the link never holds a force
//! back longer than a tick. A flood, a send that cannot leave within the write timeout or a socket error
//! ends the thread and raises `link_down`. On stop: a zero force, then a WebSocket close.
//!
//! The shell runs on any [`ServiceChannel`] (the service's socket, [`ServicePort`]; a recording double in
//! the tests).

use super::link::{Incoming, LinkCore, LinkFault, Took};
use crate::drivers::exchange::{messages_within, MessageCore, MessageTransport};
use crate::transport::inverse_service::events::{default_events_url, EventChannel};
use crate::transport::inverse_service::io::ServicePort;
use crate::transport::inverse_service::{
    force_message, parse_frame_text, ForceCommand, ServiceConfig, ServiceLink, ServiceShared,
    ServiceSnapshot, Session, WireError, FORCE_RING_CAPACITY,
};
use crate::DeviceError;
use glam::DVec3;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tungstenite::Message;

/// What the I/O shell needs of the simulation channel: whole messages in (the shared runner's
/// [`MessageTransport`]), text out, a close, and the idle wait between rounds.
pub trait ServiceChannel: MessageTransport<Message = Message> + Send + 'static {
    /// Sends one text message (within the socket's bounded write wait).
    fn send_text(&mut self, text: String) -> Result<(), DeviceError>;

    /// Starts the WebSocket close and flushes it (errors ignored: the link ends).
    fn close(&mut self);

    /// Nothing to send: sleeps until the servo thread queues a force (it unparks this thread) or `wait`
    /// has passed.
    fn idle(&mut self, wait: Duration) {
        std::thread::park_timeout(wait);
    }
}

impl ServiceChannel for ServicePort {
    fn send_text(&mut self, text: String) -> Result<(), DeviceError> {
        ServicePort::send_text(self, text)
    }

    fn close(&mut self) {
        ServicePort::close(self);
    }
}

impl MessageTransport for ServicePort {
    type Message = Message;

    fn try_read_message(&mut self) -> Result<Option<Message>, DeviceError> {
        self.try_read()
    }

    fn wait_readable(&mut self, wait: Duration) -> Result<(), DeviceError> {
        ServicePort::wait_readable(self, wait);
        Ok(())
    }
}

/// The core with what the shell does with its output: the state buffer, the counters, the stop flag.
struct Feed {
    core: LinkCore,
    device_id: String,
    states: triple_buffer::Input<ServiceSnapshot>,
    shared: Arc<ServiceShared>,
}

impl Feed {
    fn take(&mut self, incoming: Incoming<'_>) -> Result<(), DeviceError> {
        match self.core.message(incoming, &self.device_id) {
            Ok(Took::State(snapshot)) => self.states.write(snapshot),
            Ok(Took::Unused { .. }) => {}
            Err(LinkFault::Flooded) => {
                self.shared.flooded.store(true, Ordering::Release);
                return Err(DeviceError::Protocol {
                    what: "the Inverse Service sends more messages than voxhap can read",
                });
            }
        }
        Ok(())
    }

    /// The core's counters into the shared atomics (this thread is their only writer).
    fn publish_counters(&self) {
        let c = self.core.counters();
        let s = &self.shared;
        for (atomic, value) in [
            (&s.sent, c.sent),
            (&s.states, c.states),
            (&s.malformed, c.malformed),
            (&s.coalesced, c.coalesced),
            (&s.extra, c.extra),
            (&s.drifted, c.drifted),
        ] {
            atomic.store(value, Ordering::Relaxed);
        }
    }
}

impl MessageCore<Message> for Feed {
    fn message(&mut self, message: Message) -> Result<(), DeviceError> {
        let result = match &message {
            Message::Text(text) => match parse_frame_text(text.as_str()) {
                Ok(frame) => self.take(Incoming::Frame(&frame)),
                Err(error) => {
                    if let WireError::TypeDrift { .. } = error {
                        let mut first = self
                            .shared
                            .first_drift
                            .lock()
                            .unwrap_or_else(|e| e.into_inner());
                        first.get_or_insert_with(|| error.to_string());
                    }
                    self.take(Incoming::Undecodable(&error))
                }
            },
            _ => self.take(Incoming::Binary),
        };
        self.publish_counters();
        result
    }

    fn emptied(&mut self) {
        self.core.socket_empty();
    }

    fn awaiting(&self) -> bool {
        self.core.awaiting() && !self.shared.stop.load(Ordering::Acquire)
    }
}

/// Starts the I/O thread and the events channel on a set-up session: the servo thread's end of the link.
pub fn start(session: Session, config: &ServiceConfig) -> Result<ServiceLink, DeviceError> {
    let Session {
        port,
        device,
        snapshot,
    } = session;
    start_on(port, device, snapshot, config)
}

/// [`start`] on any channel: the I/O thread runs the shell on `port` for `device`, from `snapshot`.
pub(crate) fn start_on<P: ServiceChannel>(
    port: P,
    device: crate::transport::inverse_service::ServiceDevice,
    snapshot: ServiceSnapshot,
    config: &ServiceConfig,
) -> Result<ServiceLink, DeviceError> {
    let (forces, force_rx) = rtrb::RingBuffer::new(FORCE_RING_CAPACITY);
    let core = LinkCore::new(snapshot, Instant::now());
    let (mut state_tx, states) = triple_buffer::triple_buffer(&core.snapshot());
    state_tx.write(core.snapshot());
    let shared = Arc::new(ServiceShared::default());
    let feed = Feed {
        core,
        device_id: device.device_id.clone(),
        states: state_tx,
        shared: shared.clone(),
    };
    let waits = Waits {
        reply: config.reply_timeout,
        idle: config.idle_wait,
    };
    let thread = std::thread::Builder::new()
        .name("voxhap-inverse-io".to_owned())
        .spawn(move || run(port, feed, force_rx, waits))
        .map_err(|e| DeviceError::Open {
            path: config.url.clone(),
            message: format!("cannot start the Inverse Service I/O thread: {e}"),
        })?;
    let events_url = config
        .events_url
        .clone()
        .unwrap_or_else(|| default_events_url(&config.url));
    let events = EventChannel::start(events_url, device.device_id.clone());
    Ok(ServiceLink {
        forces,
        states,
        shared,
        thread: Some(thread),
        device,
        events,
    })
}

/// The I/O thread's two waits (module docs).
#[derive(Debug, Clone, Copy)]
struct Waits {
    /// For the reply to the message just sent.
    reply: Duration,
    /// With nothing to send, for the servo thread's next force.
    idle: Duration,
}

fn run<P: ServiceChannel>(
    mut port: P,
    mut feed: Feed,
    mut forces: rtrb::Consumer<ForceCommand>,
    waits: Waits,
) {
    let result = exchange(&mut port, &mut feed, &mut forces, waits).and_then(|()| {
        // Stop: zero force, then close.
        port.send_text(force_message(&feed.device_id, DVec3::ZERO))?;
        port.close();
        Ok(())
    });
    if result.is_err() {
        feed.shared.link_down.store(true, Ordering::Release);
    }
}

fn exchange<P: ServiceChannel>(
    port: &mut P,
    feed: &mut Feed,
    forces: &mut rtrb::Consumer<ForceCommand>,
    waits: Waits,
) -> Result<(), DeviceError> {
    while !feed.shared.stop.load(Ordering::Acquire) {
        // Whatever came since the last look is read now, so nothing queues up unread.
        messages_within(port, feed, Duration::ZERO)?;
        let (mut newest, mut dropped) = (None, 0u64);
        while let Ok(command) = forces.pop() {
            dropped += u64::from(newest.is_some());
            newest = Some(command);
        }
        let Some(out) = feed.core.next_command(newest, dropped, Instant::now()) else {
            port.idle(waits.idle);
            continue;
        };
        port.send_text(force_message(&feed.device_id, out.force_n))?;
        feed.core.command_sent(out.sequence, Instant::now());
        feed.publish_counters();
        // One reply per message, in order: read until this message's reply has come or the timeout passed.
        messages_within(port, feed, waits.reply)?;
    }
    Ok(())
}

#[cfg(test)]
#[path = "haply_inverse_io_tests.rs"]
mod tests;
