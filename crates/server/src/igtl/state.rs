//! What the server's tasks share: the session, the token, the counters, the stream queue and the connection
//! table, and the choice of which connection to close when the table is full.

use super::volume_file::ImageFolder;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::{broadcast, Notify, Semaphore};
use voxhap_api::SessionApi;

/// Counters of a running server.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct IgtlStats {
    /// Connections open now (one being closed to make room counts until it is closed).
    pub clients: usize,
    /// Stream frames written to clients (one frame = the four transforms of one tick).
    pub frames_sent: u64,
    /// Stream frames a slow client lost.
    pub frames_dropped: u64,
    /// Connections closed to make room for a new client when [`MAX_CLIENTS`] were connected.
    pub clients_evicted: u64,
    /// Connections closed by the idle timeout (a message could not be written to them).
    pub idle_closed: u64,
    /// Messages refused from their header because the body was larger than a client without the token
    /// may send ([`UNAUTHENTICATED_BODY_BYTES`]).
    pub large_bodies_refused: u64,
    /// Volumes loaded from IMAGE messages.
    pub images_loaded: u64,
}

#[derive(Default)]
pub(super) struct Counters {
    pub(super) clients: AtomicUsize,
    pub(super) frames_sent: AtomicU64,
    pub(super) frames_dropped: AtomicU64,
    pub(super) clients_evicted: AtomicU64,
    pub(super) idle_closed: AtomicU64,
    pub(super) large_bodies_refused: AtomicU64,
    pub(super) images_loaded: AtomicU64,
}

/// One tick's stream, encoded for both header versions.
pub(super) struct Frame {
    pub(super) v1: Vec<u8>,
    pub(super) v2: Vec<u8>,
}

/// What every task shares.
pub(super) struct Shared {
    pub(super) api: Arc<dyn SessionApi>,
    pub(super) token: String,
    pub(super) counters: Counters,
    pub(super) frames: broadcast::Sender<Arc<Frame>>,
    /// The newest STATUS, encoded for both header versions (sent to new clients first).
    pub(super) status: Mutex<Option<Arc<Frame>>>,
    pub(super) folder: Mutex<Option<ImageFolder>>,
    /// One IMAGE decoded and loaded at a time.
    pub(super) images: Semaphore,
    /// [`LARGE_BODY_BUDGET_BYTES`] in KiB: a body over [`UNAUTHENTICATED_BODY_BYTES`] holds its size's
    /// share while it is read and handled.
    pub(super) large_bodies: Arc<Semaphore>,
    /// The connections that count towards [`MAX_CLIENTS`], oldest first.
    pub(super) table: Mutex<Vec<Arc<Connection>>>,
    pub(super) idle_timeout: Duration,
    /// The zero of the millisecond times in [`Connection`].
    pub(super) epoch: tokio::time::Instant,
    pub(super) clock: WallClock,
}

impl Shared {
    /// Milliseconds since the server started.
    pub(super) fn now_ms(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX)
    }
}

/// What the accept loop knows of a connection, to choose whom to close when the table is full.
pub(super) struct Connection {
    /// When the client's last byte arrived (ms since the server started; the accept at first).
    pub(super) heard_ms: AtomicU64,
    /// When the write in progress started ([`NOT_WRITING`] when none is).
    pub(super) writing_since_ms: AtomicU64,
    pub(super) authorised: AtomicBool,
    /// Told to close, to make room.
    pub(super) evicted: Notify,
}

/// [`Connection::writing_since_ms`] when no write is in progress.
pub(super) const NOT_WRITING: u64 = u64::MAX;
/// A write in progress for longer than this counts as stalled (the client is not reading) when choosing
/// whom to close.
pub(super) const STALLED_AFTER_MS: u64 = 1000;

impl Connection {
    pub(super) fn new(now_ms: u64) -> Self {
        Connection {
            heard_ms: AtomicU64::new(now_ms),
            writing_since_ms: AtomicU64::new(NOT_WRITING),
            authorised: AtomicBool::new(false),
            evicted: Notify::new(),
        }
    }

    pub(super) fn candidate(&self, now_ms: u64) -> Candidate {
        let writing_since = self.writing_since_ms.load(Ordering::Relaxed);
        Candidate {
            authorised: self.authorised.load(Ordering::Relaxed),
            stalled: writing_since != NOT_WRITING
                && now_ms.saturating_sub(writing_since) > STALLED_AFTER_MS,
            silent_ms: now_ms.saturating_sub(self.heard_ms.load(Ordering::Relaxed)),
        }
    }
}

/// A connection as [`choose_victim`] sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Candidate {
    /// It sent the control token.
    pub authorised: bool,
    /// A write to it has been waiting for more than a second: it does not read its stream.
    pub stalled: bool,
    /// Milliseconds since its last byte arrived (since it connected, if it never sent one).
    pub silent_ms: u64,
}

/// Which connection (index into `candidates`, oldest first) to close so that a new client gets in: one
/// without the token before one with it; then one that does not read (stalled) before one that does; then
/// the one silent longest; then the oldest. `None` for an empty list.
pub fn choose_victim(candidates: &[Candidate]) -> Option<usize> {
    let key = |c: &Candidate| (!c.authorised, c.stalled, c.silent_ms);
    let mut best: Option<(usize, (bool, bool, u64))> = None;
    for (index, candidate) in candidates.iter().enumerate() {
        let this = key(candidate);
        // Strictly greater: of equals, the first (oldest) stays the choice.
        if best.is_none_or(|(_, b)| this > b) {
            best = Some((index, this));
        }
    }
    best.map(|(index, _)| index)
}

/// Maps the session's tick time to wall-clock time (ns since the Unix epoch), fixed at the first snapshot.
#[derive(Default)]
pub(super) struct WallClock {
    pub(super) epoch_ns: Mutex<Option<u64>>,
}

pub(super) fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl WallClock {
    pub(super) fn at(&self, t_s: f64) -> u64 {
        let tick_ns = (t_s.max(0.0) * 1e9) as u64;
        let mut epoch = match self.epoch_ns.lock() {
            Ok(epoch) => epoch,
            Err(poisoned) => poisoned.into_inner(),
        };
        epoch
            .get_or_insert_with(|| unix_now_ns().saturating_sub(tick_ns))
            .saturating_add(tick_ns)
    }
}
