//! The running server: binds, starts the streamer and the accept loop, reports counters and stops.

use super::client::accept;
use super::config::{
    IgtlConfig, IgtlError, CLIENT_QUEUE_FRAMES, LARGE_BODY_BUDGET_BYTES, MAX_CLIENTS, STOP_TIMEOUT,
};
use super::read::kib;
use super::state::{Counters, IgtlStats, Shared, WallClock};
use super::stream::stream;
use super::volume_file::ImageFolder;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, watch, Semaphore};
use tokio::task::JoinHandle;
use voxhap_api::SessionApi;

/// A running OpenIGTLink server. Stop it with [`IgtlServer::stop`].
pub struct IgtlServer {
    addr: SocketAddr,
    shared: Arc<Shared>,
    stop: watch::Sender<bool>,
    tasks: Vec<JoinHandle<()>>,
}

impl IgtlServer {
    /// Binds `config.addr` and starts serving `api` with control token `token`. Call it inside a tokio
    /// runtime. Does not check the address policy (see [`IgtlConfig::check`]).
    pub async fn start(
        api: Arc<dyn SessionApi>,
        config: &IgtlConfig,
        token: String,
    ) -> Result<IgtlServer, IgtlError> {
        config.check_values()?;
        let listener = TcpListener::bind(config.addr)
            .await
            .map_err(|source| IgtlError::Bind {
                addr: config.addr,
                source,
            })?;
        let addr = listener.local_addr().map_err(|source| IgtlError::Bind {
            addr: config.addr,
            source,
        })?;
        let folder = ImageFolder::create()?;
        let (frames, _) = broadcast::channel(CLIENT_QUEUE_FRAMES);
        let shared = Arc::new(Shared {
            api,
            token,
            counters: Counters::default(),
            frames,
            status: Mutex::new(None),
            folder: Mutex::new(Some(folder)),
            images: Semaphore::new(1),
            large_bodies: Arc::new(Semaphore::new(kib(LARGE_BODY_BUDGET_BYTES) as usize)),
            table: Mutex::new(Vec::with_capacity(MAX_CLIENTS)),
            idle_timeout: config.idle_timeout,
            epoch: tokio::time::Instant::now(),
            clock: WallClock::default(),
        });
        let (stop, stopped) = watch::channel(false);
        let period = Duration::from_secs_f64(1.0 / f64::from(config.rate_hz));
        let tasks = vec![
            tokio::spawn(stream(shared.clone(), period, stopped.clone())),
            tokio::spawn(accept(listener, shared.clone(), stopped)),
        ];
        Ok(IgtlServer {
            addr,
            shared,
            stop,
            tasks,
        })
    }

    /// The address it listens on (the real port when started on port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The counters so far.
    pub fn stats(&self) -> IgtlStats {
        let c = &self.shared.counters;
        IgtlStats {
            clients: c.clients.load(Ordering::Relaxed),
            frames_sent: c.frames_sent.load(Ordering::Relaxed),
            frames_dropped: c.frames_dropped.load(Ordering::Relaxed),
            clients_evicted: c.clients_evicted.load(Ordering::Relaxed),
            idle_closed: c.idle_closed.load(Ordering::Relaxed),
            large_bodies_refused: c.large_bodies_refused.load(Ordering::Relaxed),
            images_loaded: c.images_loaded.load(Ordering::Relaxed),
        }
    }

    /// Stops accepting, closes every client and waits (at most [`STOP_TIMEOUT`]) for the tasks; removes the
    /// image folder.
    pub async fn stop(self) {
        let _ = self.stop.send(true);
        for task in self.tasks {
            let _ = tokio::time::timeout(STOP_TIMEOUT, task).await;
        }
        let deadline = tokio::time::Instant::now() + STOP_TIMEOUT;
        while self.shared.counters.clients.load(Ordering::Relaxed) > 0
            && tokio::time::Instant::now() < deadline
        {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let folder = self.shared.folder.lock().ok().and_then(|mut f| f.take());
        if let Some(folder) = folder {
            folder.remove();
        }
    }
}
