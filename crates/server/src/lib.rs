//! The visualiser servers that run on tokio inside `voxhap serve`: the axum HTTP/WebSocket server with the
//! built-in page and the control API, the Foxglove live view, and the OpenIGTLink server for 3D Slicer
//! ([`igtl`]). All read the servo only through
//! [`voxhap_api::SessionApi`] (triple-buffer snapshots and atomic statistics), so the servo thread never waits
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
//! handlers), `ws` (the client task), `shared` (what handlers and client tasks share), `response` (the JSON
//! error response), [`assets`] (the embedded page).

pub mod addr;
pub mod assets;
pub mod auth;
pub mod config;
pub mod foxglove;
pub mod foxglove_relay;
pub mod guard;
mod http;
pub mod igtl;
pub mod messages;
pub mod origin;
pub use voxhap_view::palette;
mod response;
mod shared;
mod ws;

pub use config::{ConfigError, HttpArgs, HttpSettings, ServerConfig, DEFAULT_HTTP_ADDR};
pub use shared::{CLIENT_QUEUE_FRAMES, EXTRA_CONNECTIONS};

use shared::{Shared, BLOCKING_PERMITS, SLICE_PERMITS};

use std::future::{Future, IntoFuture};
use std::sync::atomic::AtomicU64;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use voxhap_api::SessionApi;

/// How long [`run`] waits after the shutdown signal for clients to take their close frame and for HTTP
/// requests in flight to finish.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);
/// Kernel send buffer of every accepted connection: with the 4-frame queue, this bounds what a client that
/// never reads can make the server hold.
pub const SEND_BUFFER_BYTES: usize = 64 * 1024;

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
