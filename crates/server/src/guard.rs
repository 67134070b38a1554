//! Connection guards under the HTTP server: a cap on open TCP connections, a deadline for each request's
//! head, and a silence timeout on each connection.
//!
//! Where it sits: between the listening socket and axum. The WebSocket client cap (`--max-clients`) counts
//! upgraded clients only; these guards cover every connection, so that clients that open connections and
//! never finish a request, or keep-alive connections nobody uses, cannot pile up. [`GuardedListener`]
//! accepts a connection only while fewer than `max_connections` are open (one more is accepted and closed
//! at once, and counted, so a flood is refused quickly instead of filling the kernel's backlog);
//! [`GuardedIo`] closes a connection to which the server has written nothing for `idle_timeout` (counted
//! from the accept, then from each write). Only the server's writes count, not the client's bytes: a
//! request whose headers or body arrive a byte every few seconds (slowloris) never gets its answer
//! written, so it is closed after the timeout like a connection that sends nothing; so is a keep-alive
//! connection left unused. A WebSocket client is sent a state at least once a second, so it stays as
//! long as it reads them; one that stops reading stalls the writes and is closed after the timeout,
//! which is what a client that never reads deserves.
//!
//! Half-open connections (accepted, request head not complete yet) are cheap to make and must not lock
//! out real requests, so they get two more rules:
//! - **Header deadline.** A request's head (request line and headers, up to the blank line) must be
//!   complete `header_timeout` (5 s) after the accept, or after the previous answer was written on a
//!   keep-alive connection; otherwise the connection is closed (counted in `idle_closed`). Once the head
//!   is in, the request and its answer fall under the 30 s silence rule only; after a `101 Switching
//!   Protocols` answer (a WebSocket) the deadline never applies again.
//! - **Reserve.** Every slot held by a half-open connection is in reserve for complete requests: when all
//!   `max_connections` slots are taken, a new connection takes the slot of the oldest half-open one, which
//!   is closed (counted in `connections_refused`). Only when every slot carries a request in progress or
//!   an established stream is the newcomer refused. So a flood of half-open connections delays a real
//!   request by at most one accept, instead of locking it out.

use std::collections::VecDeque;
use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// Counters the guards keep (shown in `/api/stats` as `server.connections_refused`, `server.idle_closed`).
#[derive(Debug, Default)]
pub struct GuardCounters {
    pub connections_refused: AtomicU64,
    pub idle_closed: AtomicU64,
}

/// A connection whose request head is not complete yet: it may be told to give up its slot.
#[derive(Debug, Default)]
struct HalfOpen {
    /// Set by the listener: close now, a newcomer takes the slot.
    evicted: AtomicBool,
    /// Set by the connection once its head is complete: no longer a candidate.
    complete: AtomicBool,
    /// The connection task's waker, so an eviction takes effect at once.
    waker: Mutex<Option<std::task::Waker>>,
}

impl HalfOpen {
    fn evict(&self) {
        self.evicted.store(true, Ordering::Release);
        if let Some(waker) = self.waker.lock().ok().and_then(|mut w| w.take()) {
            waker.wake();
        }
    }
}

/// Half-open connections, oldest first.
type HalfOpenQueue = Arc<Mutex<VecDeque<Weak<HalfOpen>>>>;

/// A listener that holds at most `max_connections` connections open at once.
pub struct GuardedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    idle_timeout: Duration,
    header_timeout: Duration,
    half_open: HalfOpenQueue,
    counters: Arc<GuardCounters>,
    tune: fn(&mut TcpStream),
}

/// How long a newcomer waits for an evicted half-open connection to give up its slot.
const EVICTION_WAIT: Duration = Duration::from_secs(1);

impl GuardedListener {
    /// Guards `inner`; `tune` is applied to every accepted socket.
    pub fn new(
        inner: TcpListener,
        max_connections: usize,
        timeouts: GuardTimeouts,
        counters: Arc<GuardCounters>,
        tune: fn(&mut TcpStream),
    ) -> Self {
        GuardedListener {
            inner,
            permits: Arc::new(Semaphore::new(max_connections.max(1))),
            idle_timeout: timeouts.idle,
            header_timeout: timeouts.header,
            half_open: Arc::default(),
            counters,
            tune,
        }
    }

    /// Evicts the oldest half-open connection; false when there is none.
    fn evict_oldest_half_open(&self) -> bool {
        let Ok(mut queue) = self.half_open.lock() else {
            return false;
        };
        while let Some(entry) = queue.pop_front() {
            if let Some(entry) = entry.upgrade() {
                if !entry.complete.load(Ordering::Acquire) {
                    entry.evict();
                    return true;
                }
            }
        }
        false
    }

    /// A slot for a new connection: a free one, or one given up by an evicted half-open connection.
    async fn slot(&self) -> Option<OwnedSemaphorePermit> {
        if let Ok(permit) = self.permits.clone().try_acquire_owned() {
            return Some(permit);
        }
        if !self.evict_oldest_half_open() {
            return None;
        }
        tokio::time::timeout(EVICTION_WAIT, self.permits.clone().acquire_owned())
            .await
            .ok()
            .and_then(Result::ok)
    }
}

/// The two time limits of a guarded connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GuardTimeouts {
    /// Nothing written this long: closed.
    pub idle: Duration,
    /// Request head not complete this long after the accept or the previous answer: closed.
    pub header: Duration,
}

impl axum::serve::Listener for GuardedListener {
    type Io = GuardedIo;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        loop {
            let (mut stream, addr) = match self.inner.accept().await {
                Ok(accepted) => accepted,
                Err(error) => {
                    // Out of file descriptors and the like: wait a little instead of spinning (as axum does).
                    eprintln!("warning: http: accept failed: {error}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            match self.slot().await {
                Some(permit) => {
                    (self.tune)(&mut stream);
                    let io = GuardedIo::new(
                        stream,
                        permit,
                        GuardTimeouts {
                            idle: self.idle_timeout,
                            header: self.header_timeout,
                        },
                        self.half_open.clone(),
                        self.counters.clone(),
                    );
                    return (io, addr);
                }
                None => {
                    self.counters
                        .connections_refused
                        .fetch_add(1, Ordering::Relaxed);
                    drop(stream);
                }
            }
        }
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

/// Where a connection is in its request/answer cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Waiting for a request head; `matched` bytes of its end (`\r\n\r\n`) seen so far.
    AwaitingHead { matched: u8 },
    /// A head is in: the request and its answer run under the silence rule only.
    InRequest,
    /// Switched protocols (WebSocket): the header deadline no longer applies.
    Upgraded,
}

/// An accepted connection: holds its slot until dropped; fails with `TimedOut` once nothing has been
/// written to it for the idle timeout, or when a request head takes longer than the header timeout, and
/// with `ConnectionAborted` when a newcomer took its slot while it was half-open.
pub struct GuardedIo {
    stream: TcpStream,
    _permit: OwnedSemaphorePermit,
    idle_timeout: Duration,
    deadline: Pin<Box<Sleep>>,
    header_timeout: Duration,
    head_deadline: Pin<Box<Sleep>>,
    phase: Phase,
    half_open: Option<Arc<HalfOpen>>,
    queue: HalfOpenQueue,
    counters: Arc<GuardCounters>,
    timed_out: bool,
}

impl GuardedIo {
    fn new(
        stream: TcpStream,
        permit: OwnedSemaphorePermit,
        timeouts: GuardTimeouts,
        queue: HalfOpenQueue,
        counters: Arc<GuardCounters>,
    ) -> Self {
        let mut io = GuardedIo {
            stream,
            _permit: permit,
            idle_timeout: timeouts.idle,
            deadline: Box::pin(tokio::time::sleep(timeouts.idle)),
            header_timeout: timeouts.header,
            head_deadline: Box::pin(tokio::time::sleep(timeouts.header)),
            phase: Phase::InRequest,
            half_open: None,
            queue,
            counters,
            timed_out: false,
        };
        io.await_head();
        io
    }

    /// Starts waiting for a request head: the header deadline runs and the connection may be evicted.
    fn await_head(&mut self) {
        if self.phase != Phase::InRequest {
            if let Phase::AwaitingHead { .. } = self.phase {
                // Still waiting (more of the same answer was written): push the deadline back.
                self.head_deadline
                    .as_mut()
                    .reset(Instant::now() + self.header_timeout);
            }
            return;
        }
        self.phase = Phase::AwaitingHead { matched: 0 };
        self.head_deadline
            .as_mut()
            .reset(Instant::now() + self.header_timeout);
        let entry = Arc::new(HalfOpen::default());
        if let Ok(mut queue) = self.queue.lock() {
            // Entries of connections that finished their head or closed stay until pruned: prune at
            // every power of two from 1024 on, so the queue stays within twice the live half-open ones.
            if queue.len() >= 1024 && queue.len().is_power_of_two() {
                queue.retain(|entry| {
                    entry
                        .upgrade()
                        .is_some_and(|e| !e.complete.load(Ordering::Acquire))
                });
            }
            queue.push_back(Arc::downgrade(&entry));
        }
        self.half_open = Some(entry);
    }

    /// Scans bytes read while a head is awaited for its end (a blank line).
    fn scan_head(&mut self, bytes: &[u8]) {
        let Phase::AwaitingHead { mut matched } = self.phase else {
            return;
        };
        for &byte in bytes {
            matched = match (matched, byte) {
                (0 | 2, b'\r') => matched + 1,
                (1 | 3, b'\n') => matched + 1,
                // A bare LF line end (tolerated by the parser): "\n\n" also ends the head.
                (0, b'\n') => 2,
                (2, b'\n') => 4,
                (_, b'\r') => 1,
                _ => 0,
            };
            if matched == 4 {
                self.phase = Phase::InRequest;
                if let Some(entry) = self.half_open.take() {
                    entry.complete.store(true, Ordering::Release);
                }
                return;
            }
        }
        self.phase = Phase::AwaitingHead { matched };
    }

    /// After bytes of an answer were written: a 101 answer upgrades, any other ends the request.
    fn wrote(&mut self, first_bytes: &[u8]) {
        if self.phase == Phase::InRequest && first_bytes.starts_with(b"HTTP/1.1 101 ") {
            self.phase = Phase::Upgraded;
        } else if self.phase != Phase::Upgraded {
            self.await_head();
        }
    }

    fn progressed(&mut self) {
        let next = Instant::now() + self.idle_timeout;
        self.deadline.as_mut().reset(next);
    }

    /// A half-open connection that was evicted, or whose head is late: the error to fail with.
    fn head_verdict(&mut self, cx: &mut Context<'_>) -> Option<io::Error> {
        if !matches!(self.phase, Phase::AwaitingHead { .. }) {
            return None;
        }
        if let Some(entry) = &self.half_open {
            if entry.evicted.load(Ordering::Acquire) {
                return Some(io::Error::new(
                    io::ErrorKind::ConnectionAborted,
                    "a new connection took the slot of this half-open one (every slot was taken)",
                ));
            }
            if let Ok(mut waker) = entry.waker.lock() {
                if !waker.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
                    *waker = Some(cx.waker().clone());
                }
            }
        }
        if self.head_deadline.as_mut().poll(cx).is_ready() {
            if !self.timed_out {
                self.timed_out = true;
                self.counters.idle_closed.fetch_add(1, Ordering::Relaxed);
            }
            return Some(io::Error::new(
                io::ErrorKind::TimedOut,
                format!(
                    "no complete request head within {} s",
                    self.header_timeout.as_secs_f64()
                ),
            ));
        }
        None
    }

    /// What the socket answered, after bookkeeping: a write that moved bytes (`moved`) pushes the deadline
    /// back; `Pending` stays pending until the deadline passes, then fails with `TimedOut`.
    fn settle<T>(
        &mut self,
        cx: &mut Context<'_>,
        answer: Poll<io::Result<T>>,
        moved: impl FnOnce(&T) -> bool,
    ) -> Poll<io::Result<T>> {
        match answer {
            Poll::Ready(Ok(value)) => {
                if moved(&value) {
                    self.progressed();
                }
                Poll::Ready(Ok(value))
            }
            Poll::Ready(Err(error)) => Poll::Ready(Err(error)),
            Poll::Pending => self.pending_or_timeout(cx),
        }
    }

    /// `Pending` from the socket: still pending, or `TimedOut` if nothing was written for too long (or a
    /// request head is late, or the connection was evicted while half-open).
    fn pending_or_timeout<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        if let Some(error) = self.head_verdict(cx) {
            return Poll::Ready(Err(error));
        }
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => {
                if !self.timed_out {
                    self.timed_out = true;
                    self.counters.idle_closed.fetch_add(1, Ordering::Relaxed);
                }
                Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "nothing written to the connection for {} s (a request never finished, \
                         an unused keep-alive connection, or a client that stopped reading)",
                        self.idle_timeout.as_secs_f64()
                    ),
                )))
            }
            Poll::Pending => Poll::Pending,
        }
    }
}

impl AsyncRead for GuardedIo {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        if let Some(error) = this.head_verdict(cx) {
            return Poll::Ready(Err(error));
        }
        // Bytes read are not progress: a request trickled in a byte at a time must not hold the
        // connection (only the answer written to it does).
        let before = buf.filled().len();
        let answer = Pin::new(&mut this.stream).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = answer {
            let filled = buf.filled();
            this.scan_head(&filled[before..]);
        }
        this.settle(cx, answer, |()| false)
    }
}

impl AsyncWrite for GuardedIo {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let answer = Pin::new(&mut this.stream).poll_write(cx, data);
        if let Poll::Ready(Ok(written)) = answer {
            if written > 0 {
                this.wrote(data);
            }
        }
        this.settle(cx, answer, |written| *written > 0)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let answer = Pin::new(&mut this.stream).poll_flush(cx);
        this.settle(cx, answer, |()| false)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let answer = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        if let Poll::Ready(Ok(written)) = answer {
            if written > 0 {
                let first = bufs
                    .iter()
                    .find(|b| !b.is_empty())
                    .map_or(&[][..], |b| &b[..]);
                this.wrote(first);
            }
        }
        this.settle(cx, answer, |written| *written > 0)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}
