//! Connection guards under the HTTP server: a cap on open TCP connections and a silence timeout on each.
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

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
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

/// A listener that holds at most `max_connections` connections open at once.
pub struct GuardedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    idle_timeout: Duration,
    counters: Arc<GuardCounters>,
    tune: fn(&mut TcpStream),
}

impl GuardedListener {
    /// Guards `inner`; `tune` is applied to every accepted socket.
    pub fn new(
        inner: TcpListener,
        max_connections: usize,
        idle_timeout: Duration,
        counters: Arc<GuardCounters>,
        tune: fn(&mut TcpStream),
    ) -> Self {
        GuardedListener {
            inner,
            permits: Arc::new(Semaphore::new(max_connections.max(1))),
            idle_timeout,
            counters,
            tune,
        }
    }
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
            match self.permits.clone().try_acquire_owned() {
                Ok(permit) => {
                    (self.tune)(&mut stream);
                    let io =
                        GuardedIo::new(stream, permit, self.idle_timeout, self.counters.clone());
                    return (io, addr);
                }
                Err(_) => {
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

/// An accepted connection: holds its slot until dropped, and fails with `TimedOut` once nothing has been
/// written to it for the idle timeout.
pub struct GuardedIo {
    stream: TcpStream,
    _permit: OwnedSemaphorePermit,
    idle_timeout: Duration,
    deadline: Pin<Box<Sleep>>,
    counters: Arc<GuardCounters>,
    timed_out: bool,
}

impl GuardedIo {
    fn new(
        stream: TcpStream,
        permit: OwnedSemaphorePermit,
        idle_timeout: Duration,
        counters: Arc<GuardCounters>,
    ) -> Self {
        GuardedIo {
            stream,
            _permit: permit,
            idle_timeout,
            deadline: Box::pin(tokio::time::sleep(idle_timeout)),
            counters,
            timed_out: false,
        }
    }

    fn progressed(&mut self) {
        let next = Instant::now() + self.idle_timeout;
        self.deadline.as_mut().reset(next);
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

    /// `Pending` from the socket: still pending, or `TimedOut` if nothing was written for too long.
    fn pending_or_timeout<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
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
        // Bytes read are not progress: a request trickled in a byte at a time must not hold the
        // connection (only the answer written to it does).
        let answer = Pin::new(&mut this.stream).poll_read(cx, buf);
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
        this.settle(cx, answer, |written| *written > 0)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}
