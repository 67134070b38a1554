//! The server's limits, device names and flags (`--igtl`, `--igtl-rate`, `--igtl-idle-timeout`): what
//! `voxhap serve` checks before it starts the server.

use super::volume_file;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

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

pub(super) fn parse_addr(text: &str) -> Result<SocketAddr, crate::addr::ListenAddrError> {
    crate::addr::parse_listen_addr(text, DEFAULT_ADDR.port())
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
    pub(super) fn check_values(&self) -> Result<(), IgtlError> {
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
