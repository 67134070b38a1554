//! What every HTTP handler and WebSocket client task shares ([`Shared`]): the session, the configuration,
//! the counters, the client slots and the permits for blocking session calls.

use super::config::ServerConfig;
use super::messages::ServerStats;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use tokio::sync::{watch, Semaphore};
use voxhap_api::{ControlError, SessionApi};

/// State frames queued per client before new ones are dropped.
pub const CLIENT_QUEUE_FRAMES: usize = 4;
/// TCP connections allowed beyond `max_clients` (the page, its scripts, REST requests, keep-alive).
pub const EXTRA_CONNECTIONS: usize = 64;
/// Slices computed at once (each is up to 512 x 512 samples of CPU work).
pub(super) const SLICE_PERMITS: usize = 2;
/// Blocking session calls (control, scene) in flight at once across all clients.
pub(super) const BLOCKING_PERMITS: usize = 8;

/// What every handler and client task shares.
pub(crate) struct Shared {
    pub(crate) api: Arc<dyn SessionApi>,
    pub(crate) config: ServerConfig,
    /// Host and Origin rules for this listening address.
    pub(crate) origin: super::origin::OriginPolicy,
    /// WebSocket clients connected now; `run` waits on it reaching 0 at shutdown.
    pub(super) clients: watch::Sender<usize>,
    pub(crate) frames_sent: AtomicU64,
    pub(crate) frames_dropped: AtomicU64,
    pub(crate) clients_refused: AtomicU64,
    pub(super) guards: Arc<super::guard::GuardCounters>,
    /// Becomes `true` once: every client closes with 1001.
    pub(crate) shutdown: watch::Receiver<bool>,
    pub(super) slices: Semaphore,
    pub(super) blocking: Semaphore,
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

    pub(super) fn max_connections(&self) -> usize {
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
