//! The OpenIGTLink server behind `voxhap serve --igtl`: voxhap as a tracked, force-rendering tool for 3D
//! Slicer (OpenIGTLinkIF) and other OpenIGTLink clients, and a way for them to send a volume in.
//!
//! Where it sits (docs/design.md, "Threads"): tasks on `voxhap serve`'s tokio runtime that read the servo only
//! through [`SessionApi`] (the triple-buffer snapshot) and change it only through
//! [`SessionApi::control`] on the blocking pool. A streamer task samples the session at `--igtl-rate`
//! (default 60 Hz) and puts one encoded frame per new tick on a bounded broadcast queue
//! ([`CLIENT_QUEUE_FRAMES`]); a client that falls behind loses the oldest frames (counted), so no client can
//! slow another or the servo.
//!
//! What a client receives (every message with a valid CRC-64; header version 1, i.e. protocol 2, until the
//! client itself sends a version-2 header, i.e. protocol 3, and from then on version 2):
//!
//! | device name | type | content |
//! |---|---|---|
//! | `Probe` | TRANSFORM | the device (stylus) position, RAS millimetres, identity rotation (voxhap's probe is a point) |
//! | `Proxy` | TRANSFORM | the proxy position, RAS millimetres, identity rotation |
//! | `ProbeVelocity` | TRANSFORM | identity rotation, translation = probe velocity in mm/s, RAS (as PLUS's OpenHaptics device sends `StylusVelocity`) |
//! | `Force` | TRANSFORM | identity rotation, translation = the force sent to the device in newtons, RAS (the convention of PLUS's `Force` tool) |
//! | `voxhap` | STATUS | once a second and on connect: 1 OK (connected and engaged), 13 not ready (ramping in), 15 disabled (no device) |
//!
//! The velocity and force conventions are PLUS's (PlusToolkit/PlusLib,
//! src/PlusDataCollection/OpenHaptics/vtkPlusOpenHapticsDevice.cxx at commit 063daba7): its `positionCallback`
//! puts `HD_CURRENT_VELOCITY` into the translation column of an otherwise identity matrix for the
//! `StylusVelocity` tool, and reads the force for `HD_CURRENT_FORCE` (newtons) from elements (0..2, 3), the
//! translation, of the `Force` tool's matrix, both in RAS after its `rasCorrection`.
//!
//! What a client may send (replies are STATUS messages with the request's device name):
//!
//! - STRING `token <T>`: authorises this connection for control (the token `voxhap serve` prints as
//!   `igtl: control token T`, the same one the HTTP server takes). A protocol-3 message may instead carry
//!   the metadata entry `token` = T. Reply: 1 OK, or 5 access denied.
//! - IMAGE (a scalar volume, any device name; needs the token): decoded ([`codec::decode_image`], RAS or
//!   LPS, the position is the image centre), written to the server's private folder
//!   ([`volume_file`]) and loaded with `load_volume`, replacing the scene's first volume (or the one named
//!   by the metadata entry `volume`). The scene is built on the blocking pool, never on the servo thread.
//!   Reply: 1 OK with the new volume's size, or the error (5 without the token).
//! - TRANSFORM `ProbeTarget` (needs the token): pulls the simulated arm's hand to the translation (RAS mm);
//!   only the newest target is applied when they come faster than the session takes them. Replies only on
//!   failure.
//! - GET_STATUS: answered with the current STATUS. Anything else is read and ignored.
//!
//! Who may connect, and what a client can make the server hold (the bounds are the constants below):
//!
//! - **Connections:** [`MAX_CLIENTS`]. A new client always gets in: when the table is full, the connection
//!   that matters least is closed to make room (STATUS 6 "Evicted" with the reason, counted in
//!   `clients_evicted`), chosen by [`choose_victim`]: one without the token before one with it, then one
//!   whose stream the server cannot write (it does not read) before one that reads, then the one silent
//!   longest (nothing received from it), then the oldest. A client that must stay connected under pressure
//!   sends the token.
//! - **Idle timeout** (`--igtl-idle-timeout`, default [`DEFAULT_IDLE_TIMEOUT`]): a connection to which a
//!   message could not be written for that long (the client does not read, so its socket buffers are full)
//!   is closed (counted in `idle_closed`). Reading the stream is what keeps a client connected; a
//!   viewer that only reads (Slicer's connector) stays as long as it reads. Each accepted socket's kernel
//!   send buffer is [`SEND_BUFFER_BYTES`], so a client that stops reading stalls after a few seconds of
//!   stream.
//! - **Authentication before large bodies:** a client without the token may send bodies of at most
//!   [`UNAUTHENTICATED_BODY_BYTES`]; a larger one is refused from its header alone (STATUS 5, then the
//!   connection is closed after discarding at most [`LINGER_BYTES`] for at most [`LINGER_TIME`], so that
//!   the client can read the STATUS), and none of it is stored. So a large IMAGE needs the token sent first
//!   (STRING `token <T>`, or the metadata entry on an earlier small message).
//! - **Bodies with the token:** up to [`MAX_BODY_BYTES`] each; all bodies over
//!   [`UNAUTHENTICATED_BODY_BYTES`] being read or handled at once, over all clients, share a budget of
//!   [`LARGE_BODY_BUDGET_BYTES`] (a client waits for its share at most [`MESSAGE_TIMEOUT`]); IMAGEs are
//!   decoded one at a time, up to [`MAX_IMAGE_VOXELS`] (4 bytes each once decoded).
//! - **Time:** once a message's first byte arrived, its header must follow within [`MESSAGE_TIMEOUT`],
//!   and its body within [`MESSAGE_TIMEOUT`] after that.
//!
//! So a client without the token makes the server hold at most one body of
//! [`UNAUTHENTICATED_BODY_BYTES`], [`REPLY_QUEUE`] short replies, one stream frame being written and the
//! [`SEND_BUFFER_BYTES`] kernel buffer; all token holders together at most [`LARGE_BODY_BUDGET_BYTES`] of
//! bodies plus one decoded image. A bad CRC is answered with STATUS 9 and the message dropped; a header
//! that cannot be framed closes the connection.

pub mod codec;
pub mod volume_file;

use self::codec::{status_code, Body, Header, Transform, HEADER_BYTES};
use self::volume_file::ImageFolder;
use crate::auth::token_matches;
use glam::DVec3;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU16, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc, oneshot, watch, Notify, OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinHandle;
use tokio::time::MissedTickBehavior;
use voxhap_api::{ControlCommand, ControlError, SessionApi, Snapshot};

/// Where the server listens with a bare `--igtl` (loopback, Slicer OpenIGTLinkIF's default port).
pub const DEFAULT_ADDR: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 18944);
/// Default streaming rate (Hz).
pub const DEFAULT_RATE_HZ: u32 = 60;
/// Accepted streaming rates (Hz).
pub const RATE_RANGE_HZ: std::ops::RangeInclusive<u32> = 1..=1000;
/// Most clients at once; a newcomer to a full table takes the place of the one [`choose_victim`] picks.
pub const MAX_CLIENTS: usize = 16;
/// Stream frames queued per client; a client further behind loses the oldest.
pub const CLIENT_QUEUE_FRAMES: usize = 8;
/// Replies queued per client.
pub const REPLY_QUEUE: usize = 16;
/// Largest message body accepted (bytes), from a client with the token.
pub const MAX_BODY_BYTES: u64 = 256 << 20;
/// Largest message body accepted from a client without the token (bytes): larger is refused from the
/// header, before any of the body is read.
pub const UNAUTHENTICATED_BODY_BYTES: u64 = 64 << 10;
/// All bodies over [`UNAUTHENTICATED_BODY_BYTES`] read or handled at once, over all clients (bytes).
pub const LARGE_BODY_BUDGET_BYTES: u64 = MAX_BODY_BYTES;
/// After refusing a body, at most this much of what follows is read and discarded (never stored) before
/// the connection is closed, so that the client can read the refusal.
pub const LINGER_BYTES: u64 = 1 << 20;
/// ... and for at most this long.
pub const LINGER_TIME: Duration = Duration::from_secs(1);
/// Kernel send buffer of each accepted socket (bytes).
pub const SEND_BUFFER_BYTES: usize = 64 << 10;
/// Largest IMAGE accepted (voxels).
pub const MAX_IMAGE_VOXELS: usize = 64 << 20;
/// Once a message's first byte arrived, its header must follow within this, then its body within this.
pub const MESSAGE_TIMEOUT: Duration = Duration::from_secs(30);
/// Default `--igtl-idle-timeout`: a connection the server could not write to for this long is closed.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// Accepted `--igtl-idle-timeout` values (seconds).
pub const IDLE_TIMEOUT_RANGE_S: std::ops::RangeInclusive<u64> = 1..=3600;
/// How often the streamed STATUS is sent.
pub const STATUS_INTERVAL: Duration = Duration::from_secs(1);
/// How long [`IgtlServer::stop`] waits for the tasks to end.
pub const STOP_TIMEOUT: Duration = Duration::from_secs(2);
/// Device name of the probe pose.
pub const PROBE_DEVICE: &str = "Probe";
/// Device name of the proxy pose.
pub const PROXY_DEVICE: &str = "Proxy";
/// Device name of the probe velocity.
pub const PROBE_VELOCITY_DEVICE: &str = "ProbeVelocity";
/// Device name of the force.
pub const FORCE_DEVICE: &str = "Force";
/// Device name of the streamed STATUS.
pub const STATUS_DEVICE: &str = "voxhap";
/// Device name of the TRANSFORM that moves the simulated hand.
pub const PROBE_TARGET_DEVICE: &str = "ProbeTarget";
/// Metadata key (protocol 3) that carries the control token.
pub const TOKEN_METADATA_KEY: &str = "token";

/// The server's flags, flattened into `voxhap serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct IgtlArgs {
    /// OpenIGTLink server for 3D Slicer and other clients; a bare --igtl listens on 127.0.0.1:18944
    /// (OpenIGTLinkIF's default port). Off unless given.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:18944",
          value_parser = parse_addr)]
    pub igtl: Option<SocketAddr>,
    /// Allow a non-loopback --igtl address: anyone who can reach it sees the session, and with the token
    /// loads volumes and moves the simulated hand.
    #[arg(long, requires = "igtl")]
    pub igtl_allow_remote: bool,
    /// How often the OpenIGTLink server streams the poses and the force (Hz, 1 to 1000).
    #[arg(long, value_name = "HZ", default_value_t = DEFAULT_RATE_HZ,
          value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub igtl_rate: u32,
    /// Close an OpenIGTLink connection to which a message could not be written for this long (the client
    /// does not read its stream), in seconds (1 to 3600).
    #[arg(long, value_name = "SECONDS", default_value_t = DEFAULT_IDLE_TIMEOUT.as_secs(),
          value_parser = clap::value_parser!(u64).range(1..=3600))]
    pub igtl_idle_timeout: u64,
}

fn parse_addr(text: &str) -> Result<SocketAddr, String> {
    if let Some(port) = text.strip_prefix("localhost:") {
        let port = port
            .parse::<u16>()
            .map_err(|_| format!("{port:?} is not a port number"))?;
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    text.parse().map_err(|_| {
        format!("expected IP:PORT such as 127.0.0.1:18944 or [::1]:18944, got {text:?}")
    })
}

/// A checked server configuration (without the token, which `voxhap serve` shares with the HTTP server).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IgtlConfig {
    /// Where to listen; port 0 picks a free port.
    pub addr: SocketAddr,
    /// Streaming rate (Hz), in [`RATE_RANGE_HZ`].
    pub rate_hz: u32,
    /// A connection the server could not write to for this long is closed; within
    /// [`IDLE_TIMEOUT_RANGE_S`] seconds.
    pub idle_timeout: Duration,
}

/// Why the server did not start.
#[derive(Debug, thiserror::Error)]
pub enum IgtlError {
    #[error(
        "--igtl {addr}: not a loopback address, so anyone who can reach it could see the session and, with \
         the token, load volumes; add --igtl-allow-remote to allow that, or use 127.0.0.1"
    )]
    RemoteNotAllowed { addr: SocketAddr },
    #[error("--igtl-rate {0} Hz is outside 1 ..= 1000 Hz")]
    Rate(u32),
    #[error("--igtl-idle-timeout {0:?} is outside 1 s ..= 3600 s")]
    IdleTimeout(Duration),
    #[error("--igtl {addr}: cannot listen there: {source}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("the OpenIGTLink server's image folder: {0}")]
    Folder(#[from] volume_file::VolumeFileError),
}

impl IgtlArgs {
    /// The configuration these flags ask for; `None` without `--igtl`.
    pub fn resolve(&self) -> Result<Option<IgtlConfig>, IgtlError> {
        let Some(addr) = self.igtl else {
            return Ok(None);
        };
        let config = IgtlConfig {
            addr,
            rate_hz: self.igtl_rate,
            idle_timeout: Duration::from_secs(self.igtl_idle_timeout),
        };
        config.check(self.igtl_allow_remote)?;
        Ok(Some(config))
    }
}

impl IgtlConfig {
    /// A configuration on `addr` with the default rate and idle timeout.
    pub fn new(addr: SocketAddr) -> Self {
        IgtlConfig {
            addr,
            rate_hz: DEFAULT_RATE_HZ,
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
        }
    }

    /// Refuses a rate or an idle timeout out of range.
    fn check_values(&self) -> Result<(), IgtlError> {
        if !RATE_RANGE_HZ.contains(&self.rate_hz) {
            return Err(IgtlError::Rate(self.rate_hz));
        }
        let range = Duration::from_secs(*IDLE_TIMEOUT_RANGE_S.start())
            ..=Duration::from_secs(*IDLE_TIMEOUT_RANGE_S.end());
        if !range.contains(&self.idle_timeout) {
            return Err(IgtlError::IdleTimeout(self.idle_timeout));
        }
        Ok(())
    }

    /// Refuses a non-loopback address unless `allow_remote`, and values out of range.
    pub fn check(&self, allow_remote: bool) -> Result<(), IgtlError> {
        self.check_values()?;
        if !allow_remote && !self.addr.ip().is_loopback() {
            return Err(IgtlError::RemoteNotAllowed { addr: self.addr });
        }
        Ok(())
    }
}

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
struct Counters {
    clients: AtomicUsize,
    frames_sent: AtomicU64,
    frames_dropped: AtomicU64,
    clients_evicted: AtomicU64,
    idle_closed: AtomicU64,
    large_bodies_refused: AtomicU64,
    images_loaded: AtomicU64,
}

/// One tick's stream, encoded for both header versions.
struct Frame {
    v1: Vec<u8>,
    v2: Vec<u8>,
}

/// What every task shares.
struct Shared {
    api: Arc<dyn SessionApi>,
    token: String,
    counters: Counters,
    frames: broadcast::Sender<Arc<Frame>>,
    /// The newest STATUS, encoded for both header versions (sent to new clients first).
    status: Mutex<Option<Arc<Frame>>>,
    folder: Mutex<Option<ImageFolder>>,
    /// One IMAGE decoded and loaded at a time.
    images: Semaphore,
    /// [`LARGE_BODY_BUDGET_BYTES`] in KiB: a body over [`UNAUTHENTICATED_BODY_BYTES`] holds its size's
    /// share while it is read and handled.
    large_bodies: Arc<Semaphore>,
    /// The connections that count towards [`MAX_CLIENTS`], oldest first.
    table: Mutex<Vec<Arc<Connection>>>,
    idle_timeout: Duration,
    /// The zero of the millisecond times in [`Connection`].
    epoch: tokio::time::Instant,
    clock: WallClock,
}

impl Shared {
    /// Milliseconds since the server started.
    fn now_ms(&self) -> u64 {
        u64::try_from(self.epoch.elapsed().as_millis()).unwrap_or(u64::MAX)
    }
}

/// What the accept loop knows of a connection, to choose whom to close when the table is full.
struct Connection {
    /// When the client's last byte arrived (ms since the server started; the accept at first).
    heard_ms: AtomicU64,
    /// When the write in progress started ([`NOT_WRITING`] when none is).
    writing_since_ms: AtomicU64,
    authorised: AtomicBool,
    /// Told to close, to make room.
    evicted: Notify,
}

/// [`Connection::writing_since_ms`] when no write is in progress.
const NOT_WRITING: u64 = u64::MAX;
/// A write in progress for longer than this counts as stalled (the client is not reading) when choosing
/// whom to close.
const STALLED_AFTER_MS: u64 = 1000;

impl Connection {
    fn new(now_ms: u64) -> Self {
        Connection {
            heard_ms: AtomicU64::new(now_ms),
            writing_since_ms: AtomicU64::new(NOT_WRITING),
            authorised: AtomicBool::new(false),
            evicted: Notify::new(),
        }
    }

    fn candidate(&self, now_ms: u64) -> Candidate {
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

/// Maps the session's tick time to wall-clock time (ns since the Unix epoch), fixed at the first snapshot.
#[derive(Default)]
struct WallClock {
    epoch_ns: Mutex<Option<u64>>,
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl WallClock {
    fn at(&self, t_s: f64) -> u64 {
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

/// Metres to millimetres.
const MM_PER_M: f64 = 1000.0;

/// The four transforms of `snapshot`, appended to `out` with header `version`.
fn encode_stream(out: &mut Vec<u8>, version: u16, snapshot: &Snapshot, timestamp: u64) {
    let items = [
        (PROBE_DEVICE, snapshot.probe_m * MM_PER_M),
        (PROXY_DEVICE, snapshot.proxy_m * MM_PER_M),
        (
            PROBE_VELOCITY_DEVICE,
            snapshot.probe_velocity_m_per_s * MM_PER_M,
        ),
        (FORCE_DEVICE, snapshot.sent_force_n),
    ];
    for (device, translation) in items {
        // A non-finite value is never sent: it becomes zero (the snapshot's values are checked by the servo
        // already; this is the last guard before another program).
        let translation = if translation.is_finite() {
            translation
        } else {
            DVec3::ZERO
        };
        codec::encode_message(out, version, "TRANSFORM", device, timestamp, &[], |o| {
            Transform::translation(translation).encode(o)
        });
    }
}

/// The STATUS that describes `snapshot` (or a session that has not ticked yet).
fn status_of(snapshot: Option<&Snapshot>) -> (u16, &'static str, String) {
    match snapshot {
        None => (
            status_code::DEVICE_NOT_READY,
            "NotReady",
            "the servo loop has not ticked yet".to_owned(),
        ),
        Some(s) => {
            let (code, name) = match (s.connected, s.engaged) {
                (true, true) => (status_code::OK, "OK"),
                (true, false) => (status_code::DEVICE_NOT_READY, "NotEngaged"),
                (false, _) => (status_code::DEVICE_DISABLED, "Disconnected"),
            };
            let bound = if s.error_bound_m.is_finite() {
                format!("{:.3e} m", s.error_bound_m)
            } else {
                "none".to_owned()
            };
            (
                code,
                name,
                format!(
                    "tick {} t {:.3} s; device {}, force {}; |force| {:.3} N; certificate bound {bound}",
                    s.tick,
                    s.t_s,
                    if s.connected { "connected" } else { "disconnected" },
                    if s.engaged { "engaged" } else { "not engaged" },
                    s.sent_force_n.length()
                ),
            )
        }
    }
}

fn status_frame(shared: &Shared, snapshot: Option<&Snapshot>) -> Arc<Frame> {
    let (code, name, message) = status_of(snapshot);
    let timestamp = codec::timestamp_from_unix_ns(
        snapshot.map_or_else(unix_now_ns, |s| shared.clock.at(s.t_s)),
    );
    let encode = |version| {
        let mut out = Vec::with_capacity(128);
        codec::encode_message(
            &mut out,
            version,
            "STATUS",
            STATUS_DEVICE,
            timestamp,
            &[],
            |o| codec::encode_status(o, code, 0, name, &message),
        );
        out
    };
    Arc::new(Frame {
        v1: encode(1),
        v2: encode(2),
    })
}

/// The streamer: every `period`, when a client listens and the tick advanced, one frame of the four
/// transforms; every [`STATUS_INTERVAL`] a STATUS.
async fn stream(shared: Arc<Shared>, period: Duration, mut stop: watch::Receiver<bool>) {
    let mut sample = tokio::time::interval(period);
    sample.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut status = tokio::time::interval(STATUS_INTERVAL);
    status.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut last_tick = None;
    loop {
        tokio::select! {
            _ = stop.changed() => break,
            _ = sample.tick() => {
                if shared.frames.receiver_count() == 0 {
                    continue;
                }
                let Some(snapshot) = shared.api.snapshot() else { continue };
                if last_tick == Some(snapshot.tick) {
                    continue;
                }
                last_tick = Some(snapshot.tick);
                let timestamp = codec::timestamp_from_unix_ns(shared.clock.at(snapshot.t_s));
                let mut v1 = Vec::with_capacity(4 * 106);
                encode_stream(&mut v1, 1, &snapshot, timestamp);
                let mut v2 = Vec::with_capacity(4 * 120);
                encode_stream(&mut v2, 2, &snapshot, timestamp);
                let _ = shared.frames.send(Arc::new(Frame { v1, v2 }));
            }
            _ = status.tick() => {
                let frame = status_frame(&shared, shared.api.snapshot().as_ref());
                if let Ok(mut slot) = shared.status.lock() {
                    *slot = Some(frame.clone());
                }
                if shared.frames.receiver_count() > 0 {
                    let _ = shared.frames.send(frame);
                }
            }
        }
    }
}

/// The accept loop: one reader and one writer task per client. When [`MAX_CLIENTS`] are connected, the
/// connection [`choose_victim`] picks is told to close and the newcomer takes its place at once.
async fn accept(listener: TcpListener, shared: Arc<Shared>, mut stop: watch::Receiver<bool>) {
    loop {
        let accepted = tokio::select! {
            _ = stop.changed() => break,
            accepted = listener.accept() => accepted,
        };
        let Ok((socket, _)) = accepted else {
            // Out of file descriptors and the like: wait a moment rather than spin.
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let _ = socket.set_nodelay(true);
        let _ = socket2::SockRef::from(&socket).set_send_buffer_size(SEND_BUFFER_BYTES);
        let now_ms = shared.now_ms();
        let connection = Arc::new(Connection::new(now_ms));
        let victim = {
            let Ok(mut table) = shared.table.lock() else {
                break;
            };
            let victim = if table.len() >= MAX_CLIENTS {
                let candidates: Vec<Candidate> =
                    table.iter().map(|c| c.candidate(now_ms)).collect();
                choose_victim(&candidates).map(|index| table.remove(index))
            } else {
                None
            };
            table.push(connection.clone());
            victim
        };
        if let Some(victim) = victim {
            shared
                .counters
                .clients_evicted
                .fetch_add(1, Ordering::Relaxed);
            victim.evicted.notify_one();
        }
        shared.counters.clients.fetch_add(1, Ordering::AcqRel);
        tokio::spawn(client(socket, connection, shared.clone(), stop.clone()));
    }
}

/// KiB, rounded up (the unit of [`Shared::large_bodies`]).
fn kib(bytes: u64) -> u32 {
    u32::try_from(bytes.div_ceil(1024)).unwrap_or(u32::MAX)
}

/// A reply the reader asks the writer to send: STATUS content for `device`.
struct Reply {
    device: String,
    code: u16,
    error_name: &'static str,
    message: String,
}

impl Reply {
    fn new(device: &str, code: u16, error_name: &'static str, message: impl Into<String>) -> Self {
        Reply {
            device: device.to_owned(),
            code,
            error_name,
            message: message.into(),
        }
    }
}

/// Writes `bytes`, marking the write in progress on `connection`; false when the socket failed or
/// a message could not be written whole within the idle timeout (counted).
async fn write_marked(
    writer: &mut OwnedWriteHalf,
    bytes: &[u8],
    connection: &Connection,
    shared: &Shared,
) -> bool {
    connection
        .writing_since_ms
        .store(shared.now_ms(), Ordering::Relaxed);
    let written = tokio::time::timeout(shared.idle_timeout, writer.write_all(bytes)).await;
    connection
        .writing_since_ms
        .store(NOT_WRITING, Ordering::Relaxed);
    match written {
        Ok(result) => result.is_ok(),
        Err(_) => {
            shared.counters.idle_closed.fetch_add(1, Ordering::Relaxed);
            false
        }
    }
}

/// One connection: a writer (stream frames and replies) and this task reading requests.
async fn client(
    socket: TcpStream,
    connection: Arc<Connection>,
    shared: Arc<Shared>,
    mut stop: watch::Receiver<bool>,
) {
    let (mut reader, mut writer) = socket.into_split();
    let version = Arc::new(AtomicU16::new(1));
    let (reply_tx, mut reply_rx) = mpsc::channel::<Reply>(REPLY_QUEUE);
    let mut frames = shared.frames.subscribe();
    let initial = shared.status.lock().ok().and_then(|s| s.clone());
    let writer_shared = shared.clone();
    let writer_connection = connection.clone();
    let writer_version = version.clone();
    let (writer_done_tx, mut writer_done) = oneshot::channel::<()>();
    let writer_task = tokio::spawn(async move {
        let shared = writer_shared;
        let connection = writer_connection;
        let frame_bytes = |frame: &Frame, version: u16| -> Vec<u8> {
            if version >= 2 {
                frame.v2.clone()
            } else {
                frame.v1.clone()
            }
        };
        let initial =
            initial.unwrap_or_else(|| status_frame(&shared, shared.api.snapshot().as_ref()));
        let bytes = frame_bytes(&initial, writer_version.load(Ordering::Relaxed));
        let mut failed = !write_marked(&mut writer, &bytes, &connection, &shared).await;
        while !failed {
            tokio::select! {
                frame = frames.recv() => match frame {
                    Ok(frame) => {
                        let bytes = frame_bytes(&frame, writer_version.load(Ordering::Relaxed));
                        failed = !write_marked(&mut writer, &bytes, &connection, &shared).await;
                        if !failed {
                            shared.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(lost)) => {
                        shared.counters.frames_dropped.fetch_add(lost, Ordering::Relaxed);
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                },
                reply = reply_rx.recv() => match reply {
                    Some(reply) => {
                        let mut out = Vec::with_capacity(64 + reply.message.len());
                        let timestamp = codec::timestamp_from_unix_ns(unix_now_ns());
                        codec::encode_message(
                            &mut out,
                            writer_version.load(Ordering::Relaxed),
                            "STATUS",
                            &reply.device,
                            timestamp,
                            &[],
                            |o| codec::encode_status(o, reply.code, 0, reply.error_name, &reply.message),
                        );
                        failed = !write_marked(&mut writer, &out, &connection, &shared).await;
                    }
                    None => break,
                },
            }
        }
        let _ = writer.shutdown().await;
        let _ = writer_done_tx.send(());
    });
    let (target_tx, target_rx) = watch::channel::<Option<DVec3>>(None);
    let target_task = tokio::spawn(apply_targets(shared.clone(), target_rx, reply_tx.clone()));
    let mut session = ClientSession {
        shared: shared.clone(),
        connection: connection.clone(),
        replies: reply_tx,
        targets: target_tx,
        version,
    };
    let mut linger = false;
    loop {
        let authorised = connection.authorised.load(Ordering::Relaxed);
        tokio::select! {
            _ = stop.changed() => break,
            _ = &mut writer_done => break,
            () = connection.evicted.notified() => {
                let _ = session.replies.try_send(Reply::new(
                    STATUS_DEVICE,
                    status_code::BUSY,
                    "Evicted",
                    format!(
                        "voxhap closes this connection to make room for a new client ({MAX_CLIENTS} were \
                         connected; connections without the token, not reading, or silent longest go first)"
                    ),
                ));
                break;
            }
            outcome = read_message(&mut reader, authorised, &shared, &connection) => match outcome {
                Ok(Some(message)) => {
                    let Incoming { header, body, budget } = message;
                    let handled = session.handle(header, body).await;
                    drop(budget);
                    if handled.is_err() {
                        break;
                    }
                }
                Ok(None) => break,
                Err(problem) => {
                    linger = problem.linger;
                    session.reply(Reply::new(STATUS_DEVICE, problem.code, problem.name, problem.message)).await;
                    break;
                }
            }
        }
    }
    drop(session);
    target_task.abort();
    // The writer ends when its reply queue closes; one stuck on a client that does not read is aborted.
    let writer_abort = writer_task.abort_handle();
    if tokio::time::timeout(Duration::from_secs(1), writer_task)
        .await
        .is_err()
    {
        writer_abort.abort();
    }
    if linger {
        // The refusal is written and the write side shut: read and drop (never store) a bounded amount of
        // what the client still sends, so that closing does not reset the connection before it reads the
        // refusal.
        let mut scratch = [0u8; 16 * 1024];
        let mut discard = (&mut reader).take(LINGER_BYTES);
        let _ = tokio::time::timeout(LINGER_TIME, async {
            while matches!(discard.read(&mut scratch).await, Ok(n) if n > 0) {}
        })
        .await;
    }
    if let Ok(mut table) = shared.table.lock() {
        table.retain(|c| !Arc::ptr_eq(c, &connection));
    }
    shared.counters.clients.fetch_sub(1, Ordering::AcqRel);
}

/// Why a connection is closed after a bad message.
struct ReadProblem {
    code: u16,
    name: &'static str,
    message: String,
    /// The client may still be sending the refused body: discard a bounded amount before closing.
    linger: bool,
}

impl ReadProblem {
    fn new(code: u16, name: &'static str, message: String) -> Self {
        ReadProblem {
            code,
            name,
            message,
            linger: false,
        }
    }
}

/// A whole message read from a client, with its share of the large-body budget (if it needed one).
struct Incoming {
    header: Header,
    body: Vec<u8>,
    budget: Option<OwnedSemaphorePermit>,
}

/// Reads one message: `Ok(None)` at a clean end of the connection. A bad CRC is not a read problem: the
/// message is framed, so it is returned with its CRC left for the caller to check. A body larger than
/// [`UNAUTHENTICATED_BODY_BYTES`] is refused from the header when the connection is not `authorised`, and
/// otherwise waits for its share of [`LARGE_BODY_BUDGET_BYTES`] before a byte of it is read.
async fn read_message<R: AsyncRead + Unpin>(
    reader: &mut R,
    authorised: bool,
    shared: &Shared,
    connection: &Connection,
) -> Result<Option<Incoming>, ReadProblem> {
    let closing = |what: String| {
        ReadProblem::new(
            status_code::CONFIGURATION_ERROR,
            "Error",
            format!("voxhap closes the connection: {what}"),
        )
    };
    let heard = || {
        connection
            .heard_ms
            .store(shared.now_ms(), Ordering::Relaxed)
    };
    let mut raw = [0u8; HEADER_BYTES];
    match reader.read(&mut raw[..1]).await {
        Ok(0) | Err(_) => return Ok(None),
        Ok(_) => heard(),
    }
    let rest = tokio::time::timeout(MESSAGE_TIMEOUT, reader.read_exact(&mut raw[1..])).await;
    let header = match rest {
        // Without the token the smaller limit below applies first, so that the answer is "send the token".
        Ok(Ok(_)) => Header::decode(&raw, if authorised { MAX_BODY_BYTES } else { u64::MAX })
            .map_err(|e| closing(e.to_string()))?,
        Ok(Err(_)) => return Ok(None),
        Err(_) => {
            return Err(closing(format!(
                "a message header did not arrive whole within {} s",
                MESSAGE_TIMEOUT.as_secs()
            )))
        }
    };
    heard();
    let mut budget = None;
    if header.body_size > UNAUTHENTICATED_BODY_BYTES {
        if !authorised {
            shared
                .counters
                .large_bodies_refused
                .fetch_add(1, Ordering::Relaxed);
            return Err(ReadProblem {
                code: status_code::ACCESS_DENIED,
                name: "AccessDenied",
                message: format!(
                    "voxhap closes the connection: {} {:?} announces a {}-byte body, and a connection without \
                     the control token may send at most {UNAUTHENTICATED_BODY_BYTES} bytes; send the STRING \
                     \"token <T>\" first (T is printed by voxhap serve as 'igtl: control token T')",
                    header.type_name, header.device_name, header.body_size
                ),
                linger: true,
            });
        }
        let share = kib(header.body_size);
        let waited = tokio::time::timeout(
            MESSAGE_TIMEOUT,
            shared.large_bodies.clone().acquire_many_owned(share),
        )
        .await;
        budget = match waited {
            Ok(Ok(permit)) => Some(permit),
            Ok(Err(_)) => return Ok(None),
            Err(_) => {
                return Err(ReadProblem::new(
                    status_code::NOT_ENOUGH_RESOURCE,
                    "Busy",
                    format!(
                        "voxhap closes the connection: other clients' large messages held the \
                         {LARGE_BODY_BUDGET_BYTES}-byte budget for {} s; send the {}-byte {} again later",
                        MESSAGE_TIMEOUT.as_secs(),
                        header.body_size,
                        header.type_name
                    ),
                ))
            }
        };
    }
    let body_size = header.body_size;
    let read_body = async {
        // Grows with the bytes that actually arrive, never to the claimed size up front.
        let mut body = Vec::with_capacity(body_size.min(64 * 1024) as usize);
        let read = reader.take(body_size).read_to_end(&mut body).await?;
        Ok::<_, std::io::Error>((read, body))
    };
    match tokio::time::timeout(MESSAGE_TIMEOUT, read_body).await {
        Ok(Ok((read, body))) if read as u64 == body_size => {
            heard();
            Ok(Some(Incoming {
                header,
                body,
                budget,
            }))
        }
        Ok(_) => Ok(None),
        Err(_) => Err(closing(format!(
            "the {body_size}-byte body of {} {:?} did not arrive whole within {} s of its header",
            header.type_name,
            header.device_name,
            MESSAGE_TIMEOUT.as_secs()
        ))),
    }
}

/// Applies the newest `ProbeTarget` of one client, one at a time, on the blocking pool.
async fn apply_targets(
    shared: Arc<Shared>,
    mut targets: watch::Receiver<Option<DVec3>>,
    replies: mpsc::Sender<Reply>,
) {
    while targets.changed().await.is_ok() {
        let Some(target_m) = *targets.borrow_and_update() else {
            continue;
        };
        let api = shared.api.clone();
        let applied = tokio::task::spawn_blocking(move || {
            api.control(ControlCommand::SetHandTarget {
                position_m: Some(target_m.to_array()),
            })
        })
        .await;
        let failure = match applied {
            Ok(Ok(_)) => None,
            Ok(Err(error)) => Some(error.to_string()),
            Err(_) => Some("the request failed inside the server".to_owned()),
        };
        if let Some(message) = failure {
            let _ = replies
                .send(Reply::new(
                    PROBE_TARGET_DEVICE,
                    status_code::CONFIGURATION_ERROR,
                    "Refused",
                    message,
                ))
                .await;
        }
    }
}

/// The request side of one connection.
struct ClientSession {
    shared: Arc<Shared>,
    /// Holds whether this connection sent the token (the accept loop reads it when choosing whom to close).
    connection: Arc<Connection>,
    replies: mpsc::Sender<Reply>,
    targets: watch::Sender<Option<DVec3>>,
    version: Arc<AtomicU16>,
}

/// The connection is gone (the writer stopped).
struct Gone;

fn control_code(error: &ControlError) -> u16 {
    match error {
        ControlError::Invalid(_) => status_code::CONFIGURATION_ERROR,
        ControlError::NotFound(_) => status_code::NOT_FOUND,
        ControlError::Conflict(_) => status_code::BUSY,
        ControlError::Unavailable(_) => status_code::DEVICE_NOT_READY,
    }
}

impl ClientSession {
    fn authorised(&self) -> bool {
        self.connection.authorised.load(Ordering::Relaxed)
    }

    /// Records whether `given` is the token; true when it is.
    fn authorise(&self, given: &str) -> bool {
        let matches = token_matches(&self.shared.token, given);
        self.connection.authorised.store(matches, Ordering::Relaxed);
        matches
    }

    async fn reply(&self, reply: Reply) -> bool {
        self.replies.send(reply).await.is_ok()
    }

    /// Answers one request; `Err` when the connection is gone.
    async fn handle(&mut self, header: Header, raw: Vec<u8>) -> Result<(), Gone> {
        let device = header.device_name.clone();
        let sent = |ok: bool| if ok { Ok(()) } else { Err(Gone) };
        if let Err(error) = header.check_crc(&raw) {
            let reply = Reply::new(
                &device,
                status_code::CHECKSUM_ERROR,
                "ChecksumError",
                format!("{} {device:?} dropped: {error}", header.type_name),
            );
            return sent(self.reply(reply).await);
        }
        // The client speaks this header version: answer and stream in it from now on.
        self.version.store(header.version, Ordering::Relaxed);
        let body = match Body::split(header.version, &raw) {
            Ok(body) => body,
            Err(error) => {
                let reply = Reply::new(
                    &device,
                    status_code::CONFIGURATION_ERROR,
                    "Error",
                    format!("{} {device:?}: {error}", header.type_name),
                );
                return sent(self.reply(reply).await);
            }
        };
        if let Some(token) = body.metadata_value(TOKEN_METADATA_KEY) {
            self.authorise(token);
        }
        match header.type_name.as_str() {
            "STRING" => {
                let reply = match codec::decode_string(body.content) {
                    Ok(text) => self.string(&device, &text),
                    Err(error) => Reply::new(
                        &device,
                        status_code::CONFIGURATION_ERROR,
                        "Error",
                        error.to_string(),
                    ),
                };
                sent(self.reply(reply).await)
            }
            "TRANSFORM" if device == PROBE_TARGET_DEVICE => {
                if !self.authorised() {
                    return sent(self.reply(self.denied(&device, "ProbeTarget")).await);
                }
                match Transform::decode(body.content) {
                    Ok(transform) => {
                        let _ = self.targets.send(Some(transform.translation / MM_PER_M));
                        Ok(())
                    }
                    Err(error) => {
                        let reply = Reply::new(
                            &device,
                            status_code::CONFIGURATION_ERROR,
                            "Error",
                            error.to_string(),
                        );
                        sent(self.reply(reply).await)
                    }
                }
            }
            "IMAGE" => {
                if !self.authorised() {
                    return sent(self.reply(self.denied(&device, "IMAGE")).await);
                }
                let volume = body.metadata_value("volume").map(str::to_owned);
                // The body moves into the blocking task (decode and write happen there), never copied.
                let start = body.content.as_ptr() as usize - raw.as_ptr() as usize;
                let content = start..start + body.content.len();
                drop(body);
                let reply = self.image(&device, raw, content, volume).await;
                sent(self.reply(reply).await)
            }
            "GET_STATUS" => {
                let (code, name, message) = status_of(self.shared.api.snapshot().as_ref());
                sent(self.reply(Reply::new(&device, code, name, message)).await)
            }
            // TRANSFORMs of other names (Slicer may echo nodes back), STATUS, and other types: ignored.
            _ => Ok(()),
        }
    }

    fn denied(&self, device: &str, what: &str) -> Reply {
        Reply::new(
            device,
            status_code::ACCESS_DENIED,
            "AccessDenied",
            format!(
                "{what} needs the control token: send the STRING \"token <T>\" first, or the metadata entry \
                 \"{TOKEN_METADATA_KEY}\" (T is printed by voxhap serve as 'igtl: control token T')"
            ),
        )
    }

    fn string(&mut self, device: &str, text: &str) -> Reply {
        let text = text.trim();
        match text.split_once(' ') {
            Some(("token", given)) => {
                if self.authorise(given.trim()) {
                    Reply::new(
                        device,
                        status_code::OK,
                        "OK",
                        "token accepted: this connection may load volumes and move the hand",
                    )
                } else {
                    Reply::new(
                        device,
                        status_code::ACCESS_DENIED,
                        "AccessDenied",
                        "wrong token",
                    )
                }
            }
            _ => Reply::new(
                device,
                status_code::UNKNOWN_INSTRUCTION,
                "UnknownCommand",
                format!(
                    "unknown STRING command {:?}; voxhap understands \"token <T>\"",
                    text.chars().take(40).collect::<String>()
                ),
            ),
        }
    }

    /// Decodes, writes and loads an IMAGE; the STATUS that answers it.
    async fn image(
        &self,
        device: &str,
        raw: Vec<u8>,
        content: std::ops::Range<usize>,
        volume: Option<String>,
    ) -> Reply {
        let Ok(_permit) = self.shared.images.acquire().await else {
            return Reply::new(
                device,
                status_code::DEVICE_NOT_READY,
                "Error",
                "the server is stopping",
            );
        };
        let shared = self.shared.clone();
        let device_name = device.to_owned();
        let loaded = tokio::task::spawn_blocking(move || -> Result<String, (u16, String)> {
            let image = codec::decode_image(&raw[content], MAX_IMAGE_VOXELS)
                .map_err(|e| (status_code::CONFIGURATION_ERROR, e.to_string()))?;
            drop(raw);
            let path = {
                let mut folder = shared.folder.lock().map_err(|_| {
                    (status_code::UNKNOWN_ERROR, "the image folder is unavailable".to_owned())
                })?;
                let folder = folder.as_mut().ok_or((
                    status_code::DEVICE_NOT_READY,
                    "the server is stopping".to_owned(),
                ))?;
                folder
                    .write(&device_name, &image)
                    .map_err(|e| (status_code::NOT_ENOUGH_RESOURCE, e.to_string()))?
            };
            let dims = image.dims;
            let (lo, hi) = image
                .values
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
            drop(image);
            let replaced = volume.clone();
            let reply = shared
                .api
                .control(ControlCommand::LoadVolume { path, name: volume })
                .map_err(|e| (control_code(&e), e.to_string()))?;
            shared.counters.images_loaded.fetch_add(1, Ordering::Relaxed);
            let refits = refit_surfaces(shared.api.as_ref(), replaced.as_deref(), lo, hi);
            Ok(format!(
                "volume {device_name:?} loaded: {} x {} x {} voxels, values {lo} to {hi}; scene generation {}{refits}",
                dims[0], dims[1], dims[2], reply.scene_generation
            ))
        })
        .await;
        match loaded {
            Ok(Ok(message)) => Reply::new(device, status_code::OK, "OK", message),
            Ok(Err((code, message))) => {
                Reply::new(device, code, "Error", format!("IMAGE refused: {message}"))
            }
            Err(_) => Reply::new(
                device,
                status_code::UNKNOWN_ERROR,
                "Error",
                "the IMAGE failed inside the server",
            ),
        }
    }
}

/// After an IMAGE replaced the volume `replaced` (default: the first), a surface mode on it whose surface
/// the new values cannot show (the value where its transfer reaches half strength lies outside `lo ..= hi`)
/// gets a transfer fitted to the image, as `voxhap serve --volume` does for a lone volume: 0 N at 45 % of
/// the range, the mode's largest strength at 50 %. Returns what was changed, for the STATUS text.
fn refit_surfaces(api: &dyn SessionApi, replaced: Option<&str>, lo: f32, hi: f32) -> String {
    use voxhap_core::haptics::modes::{ModeKind, TransferFunction};
    use voxhap_view::volume::half_strength_value;
    let scene = api.scene();
    let Some(name) = replaced.or_else(|| scene.volumes.first().map(|v| v.name.as_str())) else {
        return String::new();
    };
    let (lo, hi) = (f64::from(lo), f64::from(hi));
    if hi <= lo {
        return String::new();
    }
    let mut changed = String::new();
    for mode in &scene.modes {
        let Some(transfer) = mode.transfer.as_ref() else {
            continue;
        };
        if mode.kind != ModeKind::Surface || mode.volume.as_deref() != Some(name) {
            continue;
        }
        let fits = half_strength_value(transfer).is_some_and(|iso| lo < iso && iso < hi);
        if fits {
            continue;
        }
        let span = hi - lo;
        let Ok(fitted) = TransferFunction::new(vec![
            [lo + 0.45 * span, 0.0],
            [lo + 0.5 * span, transfer.max_strength_n().max(1e-3)],
        ]) else {
            continue;
        };
        let points = fitted.points().to_vec();
        let mode_name = mode.display_name().to_owned();
        if api
            .control(ControlCommand::SetTransfer {
                mode: mode_name.clone(),
                transfer: fitted,
            })
            .is_ok()
        {
            changed.push_str(&format!(
                "; the transfer of surface mode {mode_name:?} did not fit these values and is now {points:?}"
            ));
        }
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        args: IgtlArgs,
    }

    fn parse(args: &[&str]) -> Result<IgtlArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("voxhap").chain(args.iter().copied())).map(|c| c.args)
    }

    #[test]
    fn off_by_default_and_a_bare_flag_is_loopback_18944_at_60_hz() {
        assert_eq!(parse(&[]).unwrap().resolve().unwrap(), None);
        let config = parse(&["--igtl"]).unwrap().resolve().unwrap().unwrap();
        assert_eq!(config.addr, DEFAULT_ADDR);
        assert_eq!(config.rate_hz, 60);
        let config = parse(&["--igtl", "localhost:0", "--igtl-rate", "250"])
            .unwrap()
            .resolve()
            .unwrap()
            .unwrap();
        assert_eq!((config.addr.port(), config.rate_hz), (0, 250));
        assert_eq!(config.idle_timeout, Duration::from_secs(30));
        let config = parse(&["--igtl", "--igtl-idle-timeout", "5"])
            .unwrap()
            .resolve()
            .unwrap()
            .unwrap();
        assert_eq!(config.idle_timeout, Duration::from_secs(5));
    }

    #[test]
    fn an_idle_timeout_out_of_range_is_refused() {
        for bad in ["0", "3601", "-1", "1.5"] {
            assert!(
                parse(&["--igtl", "--igtl-idle-timeout", bad]).is_err(),
                "{bad} accepted"
            );
        }
        let mut config = IgtlConfig::new(DEFAULT_ADDR);
        config.idle_timeout = Duration::from_millis(500);
        let error = config.check(false).unwrap_err().to_string();
        assert!(error.contains("--igtl-idle-timeout"), "{error}");
    }

    /// The documented order (module header): without the token first, then stalled, then silent longest,
    /// then the oldest.
    #[test]
    fn the_connection_closed_for_a_newcomer_follows_the_documented_order() {
        let c = |authorised, stalled, silent_ms| Candidate {
            authorised,
            stalled,
            silent_ms,
        };
        assert_eq!(choose_victim(&[]), None);
        // Equal: the oldest.
        assert_eq!(
            choose_victim(&[c(false, false, 5), c(false, false, 5)]),
            Some(0)
        );
        // Silent longest.
        assert_eq!(
            choose_victim(&[c(false, false, 5), c(false, false, 9)]),
            Some(1)
        );
        // A stalled one before one silent longer.
        assert_eq!(
            choose_victim(&[c(false, false, 90_000), c(false, true, 10)]),
            Some(1)
        );
        // One without the token before a stalled, silent token holder.
        assert_eq!(
            choose_victim(&[c(true, true, 90_000), c(false, false, 0)]),
            Some(1)
        );
        // All with the token: the same order among them.
        assert_eq!(
            choose_victim(&[c(true, false, 7), c(true, true, 1), c(true, false, 8)]),
            Some(1)
        );
    }

    #[test]
    fn a_remote_address_needs_the_flag_and_bad_values_are_refused() {
        let error = parse(&["--igtl", "0.0.0.0:18944"])
            .unwrap()
            .resolve()
            .unwrap_err();
        assert!(error.to_string().contains("--igtl-allow-remote"), "{error}");
        assert!(parse(&["--igtl", "0.0.0.0:18944", "--igtl-allow-remote"])
            .unwrap()
            .resolve()
            .unwrap()
            .is_some());
        for bad in [
            &["--igtl-rate", "0"][..],
            &["--igtl", "--igtl-rate", "1001"],
            &["--igtl", "18944"],
            &["--igtl-allow-remote"],
        ] {
            assert!(parse(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn the_stream_is_millimetres_and_newtons_and_never_non_finite() {
        let snapshot = Snapshot {
            probe_m: DVec3::new(0.01, -0.02, 0.03),
            proxy_m: DVec3::new(0.0, 0.0, 0.001),
            probe_velocity_m_per_s: DVec3::new(f64::NAN, 0.0, 0.0),
            sent_force_n: DVec3::new(0.5, 0.0, -1.5),
            ..Snapshot::example()
        };
        let mut out = Vec::new();
        encode_stream(&mut out, 1, &snapshot, 0);
        let mut at = 0;
        let mut seen = Vec::new();
        while at < out.len() {
            let raw: &[u8; HEADER_BYTES] = out[at..at + HEADER_BYTES].try_into().unwrap();
            let header = Header::decode(raw, 1000).unwrap();
            let body = &out[at + HEADER_BYTES..at + HEADER_BYTES + header.body_size as usize];
            header.check_crc(body).unwrap();
            let transform = Transform::decode(body).unwrap();
            assert_eq!(transform.rotation, glam::DMat3::IDENTITY);
            seen.push((header.device_name, transform.translation));
            at += HEADER_BYTES + header.body_size as usize;
        }
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-4;
        assert_eq!(seen.len(), 4);
        assert_eq!(seen[0].0, "Probe");
        assert!(close(seen[0].1, DVec3::new(10.0, -20.0, 30.0)));
        assert!(close(seen[1].1, DVec3::new(0.0, 0.0, 1.0)));
        assert_eq!(seen[2].0, "ProbeVelocity");
        assert_eq!(seen[2].1, DVec3::ZERO);
        assert_eq!(seen[3].0, "Force");
        assert!(close(seen[3].1, DVec3::new(0.5, 0.0, -1.5)));
    }
}
