//! The visualiser servers that run on tokio inside `voxhap serve`: the axum HTTP/WebSocket server with the
//! built-in page and the control API, the Foxglove live view, and the OpenIGTLink server for 3D Slicer
//! ([`igtl`]). All read the servo only through
//! [`crate::servo::SessionApi`] (triple-buffer snapshots and atomic statistics), so the servo thread never waits
//! on them.
//!
//! The HTTP/WebSocket server is shaped like mini-redis: [`run`] takes a bound listener, the session and a
//! shutdown future; one task per WebSocket client (plus a sampler task that feeds it); a cap on clients; a
//! broadcast (watch channel) that tells every client to close with 1001 when the shutdown future resolves.
//! Its wire contract, `voxhap.visualiser.v1`, is documented in protocol/VISUALISER.md.
//!
//! ```text
//!  servo thread ─triple buffer─▶ SessionApi::snapshot ◀─ sampler task (one per client, at the client's rate)
//!                                                          │ try_reserve on a 4-frame queue; full: drop, count
//!                                                          ▼
//!  SessionApi::control/scene/slice ◀─ spawn_blocking ◀── client task ──▶ socket (SO_SNDBUF 64 KiB)
//!                                                         ▲ one request in flight; shutdown → close 1001
//! ```
//!
//! Files: [`config`] (flags), [`auth`] (bearer token), [`origin`] (Host and Origin checks), [`guard`]
//! (connection cap, header deadline, silence timeout), [`messages`] (the JSON), `http` (router and REST
//! handlers), `ws` (the client task), [`assets`] (the embedded page).

pub mod assets;
pub mod auth;
pub mod config;
pub mod foxglove;
pub mod guard;
mod http;
pub mod igtl;
pub mod messages;
pub mod origin;
pub mod palette;
mod response;
mod ws;

pub use config::{ConfigError, HttpArgs, HttpSettings, ServerConfig, DEFAULT_HTTP_ADDR};

use crate::servo::api::{ControlError, SessionApi};
use messages::ServerStats;
use std::future::{Future, IntoFuture};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};

/// How long [`run`] waits after the shutdown signal for clients to take their close frame and for HTTP
/// requests in flight to finish.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);
/// Kernel send buffer of every accepted connection: with the 4-frame queue, this bounds what a client that
/// never reads can make the server hold.
pub const SEND_BUFFER_BYTES: usize = 64 * 1024;
/// State frames queued per client before new ones are dropped.
pub const CLIENT_QUEUE_FRAMES: usize = 4;
/// TCP connections allowed beyond `max_clients` (the page, its scripts, REST requests, keep-alive).
pub const EXTRA_CONNECTIONS: usize = 64;
/// Slices computed at once (each is up to 512 x 512 samples of CPU work).
const SLICE_PERMITS: usize = 2;
/// Blocking session calls (control, scene) in flight at once across all clients.
const BLOCKING_PERMITS: usize = 8;

/// What every handler and client task shares.
pub(crate) struct Shared {
    pub(crate) api: Arc<dyn SessionApi>,
    pub(crate) config: ServerConfig,
    /// Host and Origin rules for this listening address.
    pub(crate) origin: origin::OriginPolicy,
    /// WebSocket clients connected now; `run` waits on it reaching 0 at shutdown.
    clients: watch::Sender<usize>,
    pub(crate) frames_sent: AtomicU64,
    pub(crate) frames_dropped: AtomicU64,
    pub(crate) clients_refused: AtomicU64,
    guards: Arc<guard::GuardCounters>,
    /// Becomes `true` once: every client closes with 1001.
    pub(crate) shutdown: watch::Receiver<bool>,
    slices: Semaphore,
    blocking: Semaphore,
}

impl Shared {
    pub(crate) fn stats(&self) -> ServerStats {
        ServerStats {
            clients: *self.clients.borrow(),
            max_clients: self.config.max_clients,
            frames_sent: self.frames_sent.load(Ordering::Relaxed),
            frames_dropped: self.frames_dropped.load(Ordering::Relaxed),
            clients_refused: self.clients_refused.load(Ordering::Relaxed),
            max_connections: self.max_connections(),
            connections_refused: self.guards.connections_refused.load(Ordering::Relaxed),
            idle_closed: self.guards.idle_closed.load(Ordering::Relaxed),
        }
    }

    fn max_connections(&self) -> usize {
        self.config.max_clients.saturating_add(EXTRA_CONNECTIONS)
    }

    /// A client slot, or `None` when `max_clients` are connected (counted as refused).
    pub(crate) fn try_add_client(self: &Arc<Self>) -> Option<ClientSlot> {
        let max = self.config.max_clients;
        let added = self.clients.send_if_modified(|n| {
            if *n < max {
                *n += 1;
                true
            } else {
                false
            }
        });
        if added {
            Some(ClientSlot(self.clone()))
        } else {
            self.clients_refused.fetch_add(1, Ordering::Relaxed);
            None
        }
    }

    /// Runs a session call that may block (it takes the control lock, which a command holds while the servo
    /// applies it) on tokio's blocking pool, at most `BLOCKING_PERMITS` (or, for slices, `SLICE_PERMITS`)
    /// at once.
    pub(crate) async fn blocking<T: Send + 'static>(
        self: &Arc<Self>,
        slice: bool,
        call: impl FnOnce(&dyn SessionApi) -> T + Send + 'static,
    ) -> Result<T, ControlError> {
        let semaphore = if slice { &self.slices } else { &self.blocking };
        let _permit = semaphore
            .acquire()
            .await
            .map_err(|_| ControlError::Unavailable("the server is shutting down".to_owned()))?;
        let api = self.api.clone();
        tokio::task::spawn_blocking(move || call(api.as_ref()))
            .await
            .map_err(|_| {
                ControlError::Unavailable("the request failed inside the server".to_owned())
            })
    }
}

/// One connected WebSocket client; dropping it frees the slot.
pub(crate) struct ClientSlot(Arc<Shared>);

impl Drop for ClientSlot {
    fn drop(&mut self) {
        self.0.clients.send_modify(|n| *n = n.saturating_sub(1));
    }
}

/// Caps the kernel send buffer and turns off Nagle on an accepted connection.
fn tune_socket(stream: &mut TcpStream) {
    let _ = stream.set_nodelay(true);
    let _ = socket2::SockRef::from(&*stream).set_send_buffer_size(SEND_BUFFER_BYTES);
}

/// Serves the page, the REST API and the WebSocket stream on `listener` until `shutdown` resolves; then
/// stops accepting, closes every WebSocket client with 1001 "server shutting down", waits up to
/// [`SHUTDOWN_GRACE`] for them and for HTTP requests in flight, and returns.
pub async fn run(
    listener: TcpListener,
    api: Arc<dyn SessionApi>,
    config: ServerConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> std::io::Result<()> {
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let (clients_tx, mut clients_rx) = watch::channel(0usize);
    let origin = origin::OriginPolicy::new(
        listener.local_addr()?,
        &config.allowed_hosts,
        &config.allowed_origins,
    );
    let shared = Arc::new(Shared {
        api,
        origin,
        config,
        clients: clients_tx,
        frames_sent: AtomicU64::new(0),
        frames_dropped: AtomicU64::new(0),
        clients_refused: AtomicU64::new(0),
        guards: Arc::default(),
        shutdown: shutdown_rx.clone(),
        slices: Semaphore::new(SLICE_PERMITS),
        blocking: Semaphore::new(BLOCKING_PERMITS),
    });
    let app = http::router(shared.clone());
    let listener = guard::GuardedListener::new(
        listener,
        shared.max_connections(),
        guard::GuardTimeouts {
            idle: shared.config.idle_timeout,
            header: shared.config.header_timeout,
        },
        shared.guards.clone(),
        tune_socket,
    );
    let mut http_done = shutdown_rx.clone();
    let server = axum::serve(listener, app).with_graceful_shutdown(async move {
        let _ = http_done.wait_for(|stop| *stop).await;
    });
    let mut server = std::pin::pin!(server.into_future());
    let finished = tokio::select! {
        result = &mut server => Some(result),
        () = shutdown => None,
    };
    let _ = shutdown_tx.send(true);
    let _ = tokio::time::timeout(SHUTDOWN_GRACE, async {
        if finished.is_none() {
            let _ = (&mut server).await;
        }
        let _ = clients_rx.wait_for(|n| *n == 0).await;
    })
    .await;
    drop(shared);
    finished.unwrap_or(Ok(()))
}
