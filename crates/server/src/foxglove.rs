//! The Foxglove live view: the `foxglove` SDK's WebSocket server (protocol `foxglove.sdk.v1`, and the same protocol
//! under its older name `foxglove.websocket.v1` through [`crate::foxglove_relay`]; default
//! `ws://127.0.0.1:8765`) and a publisher task that samples the running session and logs it on Foxglove
//! channels, so Foxglove or Lichtblick shows the session in 3D with plots.
//!
//! Where it sits (docs/design.md, "Threads"): a task on `voxhap serve`'s tokio runtime. It reads the servo only
//! through [`SessionApi`] (the triple-buffer snapshot and the atomic statistics), at `--foxglove-rate`
//! (default 60 Hz), and only publishes when the tick advanced; the SDK queues messages per client and drops
//! the oldest for a slow one, so no client can slow the servo thread. Nothing is read or encoded for
//! topics no client subscribed to.
//!
//! Topics (frame `world` is voxhap's world space, RAS metres; pose, velocity and force topics carry CRTK
//! names, see `voxhap_view::topics` for the table with the old names):
//!
//! | topic | schema | rate |
//! |---|---|---|
//! | `/voxhap/measured_cp`, `/voxhap/setpoint_cp` | `foxglove.FrameTransform` (frames `probe`, `proxy` in `world`) | sampled |
//! | `/voxhap/measured_cv` | `foxglove.Vector3`: probe velocity (m/s) | sampled |
//! | `/voxhap/setpoint_cf` | `foxglove.Vector3`: force sent to the device (N) | sampled |
//! | `/voxhap/operating_state` | `voxhap.OperatingState` (JSON, CRTK fields `state`, `is_homed`, `is_busy`; the tick's truth) | sampled |
//! | [`PRIMITIVES_TOPIC`] | `foxglove.SceneUpdate`: probe, proxy, force arrow, the tick's primitives ([`messages`]) | sampled |
//! | [`BOUND_TOPIC`] | `voxhap.Bound` (JSON): `tick`, `t_s`, `error_bound_m`, `sweeps`, `status` | sampled |
//! | [`STATS_TOPIC`] | `voxhap.Stats` (JSON): the [`voxhap_api::StatsReport`] | 1 Hz |
//! | `/voxhap/volume` | `foxglove.SceneUpdate`: the volume's bounding box and iso-surface ([`volume`]) | on each scene change and each new subscriber |
//! | `/voxhap/volume_frame` | `foxglove.FrameTransform`: frame `volume` at the volume's centre and frame `volume_view`, which the shipped layout's camera follows (`voxhap_view::topics::CameraFraming`) | with `/voxhap/volume` |
//! | [`SLICE_TOPICS`] | `foxglove.Grid`: slices normal to x, y, z through the proxy | [`SLICE_INTERVAL`] |
//! | `/voxhap/probe`, `/voxhap/proxy`, `/voxhap/force`, `/voxhap/servo_cf` | the old names of measured_cp, setpoint_cp, setpoint_cf (deprecated, removed in the next release) | sampled |
//!
//! Every topic but `measured_cv` and the deprecated names is also in MCAP traces
//! (`voxhap_record::foxglove_scene::RecordedScene`), so a recording shows the shipped layout's picture.
//! Message timestamps and log times are wall-clock: the session's tick time plus the wall time at which the
//! view first saw the session. The volume picture and the slices are computed on tokio's blocking pool, one
//! at a time, never on the servo thread.

pub use voxhap_view::{messages, volume};

use self::messages::{scene_update, BoundMessage, OperatingStateMessage, StatsMessage};
use self::volume::VolumePicture;
use ::foxglove::messages::{FrameTransform, Grid, SceneUpdate, Vector3};
use ::foxglove::websocket::{ChannelView, Client, ServerListener};
use ::foxglove::{Channel, Context, WebSocketServerHandle};
use glam::DVec3;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tokio::time::MissedTickBehavior;
use voxhap_api::{SessionApi, Snapshot};
use voxhap_view::topics::{
    frame_transform, set_translation, timestamp_from_ns, vector3, FORCE_TOPIC, MEASURED_CP_TOPIC,
    MEASURED_CV_TOPIC, OPERATING_STATE_TOPIC, PROBE_FRAME, PROBE_TOPIC, PROXY_FRAME, PROXY_TOPIC,
    SERVO_CF_TOPIC, SETPOINT_CF_TOPIC, SETPOINT_CP_TOPIC, VOLUME_FRAME_TOPIC, VOLUME_TOPIC,
};
pub use voxhap_view::topics::{BOUND_TOPIC, PRIMITIVES_TOPIC, STATS_TOPIC};

/// Where the live view listens unless `--foxglove` says otherwise (Foxglove's usual port, loopback).
pub const DEFAULT_ADDR: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 8765);
/// Default sampling rate (Hz).
pub const DEFAULT_RATE_HZ: u32 = 60;
/// Accepted sampling rates (Hz).
pub const RATE_RANGE_HZ: std::ops::RangeInclusive<u32> = 1..=1000;
pub use voxhap_view::topics::SLICE_TOPICS;
/// Every topic the live view advertises.
pub const TOPICS: [&str; 17] = [
    MEASURED_CP_TOPIC,
    SETPOINT_CP_TOPIC,
    MEASURED_CV_TOPIC,
    SETPOINT_CF_TOPIC,
    OPERATING_STATE_TOPIC,
    PRIMITIVES_TOPIC,
    BOUND_TOPIC,
    STATS_TOPIC,
    VOLUME_TOPIC,
    VOLUME_FRAME_TOPIC,
    SLICE_TOPICS[0],
    SLICE_TOPICS[1],
    SLICE_TOPICS[2],
    // Deprecated names, dropped in the next release.
    PROBE_TOPIC,
    PROXY_TOPIC,
    FORCE_TOPIC,
    SERVO_CF_TOPIC,
];
/// How often the slices through the proxy are sampled and sent (when subscribed).
pub const SLICE_INTERVAL: Duration = Duration::from_millis(250);
/// How long [`FoxgloveServer::stop`] waits for client connections to close.
pub const STOP_TIMEOUT: Duration = Duration::from_secs(2);
/// How often the statistics are published.
pub const STATS_INTERVAL: Duration = Duration::from_secs(1);

/// The live view's flags, flattened into `voxhap serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct FoxgloveArgs {
    /// Foxglove live view: WebSocket address for Foxglove or Lichtblick (protocol foxglove.sdk.v1)
    /// [default: 127.0.0.1:8765; when that is busy, serve warns and runs without the view]
    #[arg(long, value_name = "ADDR", value_parser = parse_addr)]
    pub foxglove: Option<SocketAddr>,
    /// Allow a non-loopback --foxglove address: anyone who can reach it can watch the session.
    #[arg(long)]
    pub foxglove_allow_remote: bool,
    /// How often the live view samples the session (Hz, 1 to 1000).
    #[arg(long, value_name = "HZ", default_value_t = DEFAULT_RATE_HZ,
          value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub foxglove_rate: u32,
    /// Do not start the Foxglove live view.
    #[arg(long, conflicts_with_all = ["foxglove", "foxglove_allow_remote"])]
    pub no_foxglove: bool,
}

fn parse_addr(text: &str) -> Result<SocketAddr, crate::addr::ListenAddrError> {
    crate::addr::parse_listen_addr(text, DEFAULT_ADDR.port())
}

/// A checked live-view configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FoxgloveConfig {
    /// Where to listen; port 0 picks a free port.
    pub addr: SocketAddr,
    /// True when the address was given (`--foxglove`): then a busy address is an error, not a warning.
    pub explicit: bool,
    /// Sampling rate (Hz), in [`RATE_RANGE_HZ`].
    pub rate_hz: u32,
}

impl FoxgloveConfig {
    /// A configuration for an explicitly given address (tests, embedding).
    pub fn at(addr: SocketAddr, rate_hz: u32) -> Self {
        FoxgloveConfig {
            addr,
            explicit: true,
            rate_hz,
        }
    }
}

/// Why the live view did not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveViewError {
    #[error(
        "--foxglove {addr}: not a loopback address, so anyone who can reach it could watch the session; \
         add --foxglove-allow-remote to allow that, or use 127.0.0.1"
    )]
    RemoteNotAllowed { addr: SocketAddr },
    #[error("--foxglove-rate {0} Hz is outside 1 ..= 1000 Hz")]
    Rate(u32),
    #[error(
        "--foxglove {addr}: the address is already in use (another voxhap or a Foxglove bridge?); \
         choose another with --foxglove ADDR or pass --no-foxglove"
    )]
    AddressInUse { addr: SocketAddr },
    #[error("--foxglove {addr}: could not start the Foxglove server: {source}")]
    Start {
        addr: SocketAddr,
        source: ::foxglove::FoxgloveError,
    },
}

impl FoxgloveArgs {
    /// The configuration these flags ask for; `None` with `--no-foxglove`. Checks the address and rate
    /// (call it before starting anything).
    pub fn resolve(&self) -> Result<Option<FoxgloveConfig>, LiveViewError> {
        if self.no_foxglove {
            return Ok(None);
        }
        let config = FoxgloveConfig {
            addr: self.foxglove.unwrap_or(DEFAULT_ADDR),
            explicit: self.foxglove.is_some(),
            rate_hz: self.foxglove_rate,
        };
        config.check(self.foxglove_allow_remote)?;
        Ok(Some(config))
    }
}

impl FoxgloveConfig {
    /// Refuses a non-loopback address unless `allow_remote`, and a rate out of range.
    pub fn check(&self, allow_remote: bool) -> Result<(), LiveViewError> {
        if !RATE_RANGE_HZ.contains(&self.rate_hz) {
            return Err(LiveViewError::Rate(self.rate_hz));
        }
        if !allow_remote && !self.addr.ip().is_loopback() {
            return Err(LiveViewError::RemoteNotAllowed { addr: self.addr });
        }
        Ok(())
    }
}

/// A running live view. Stop it with [`FoxgloveServer::stop`]; dropping it leaves the SDK's server running
/// until the runtime ends.
pub struct FoxgloveServer {
    /// The channels' and the server's context. The SDK holds it only weakly: without this, clients would
    /// connect but never see a channel.
    _context: Arc<Context>,
    handle: WebSocketServerHandle,
    addr: SocketAddr,
    stop: oneshot::Sender<()>,
    publisher: JoinHandle<()>,
    /// The front door on the public address (both subprotocol names).
    relay: JoinHandle<()>,
}

impl FoxgloveServer {
    /// Binds `config.addr` and starts publishing `api`. Call it inside a tokio runtime: the server and the
    /// publisher run on the current one. Does not check the address policy (see [`FoxgloveConfig::check`]).
    pub async fn start(
        api: Arc<dyn SessionApi>,
        config: &FoxgloveConfig,
    ) -> Result<FoxgloveServer, LiveViewError> {
        if !RATE_RANGE_HZ.contains(&config.rate_hz) {
            return Err(LiveViewError::Rate(config.rate_hz));
        }
        let context = Context::new();
        let channels = Channels::new(&context);
        let resend = Arc::new(ResendOnSubscribe::default());
        // The public address is the relay's (crate::foxglove_relay: both subprotocol names); the SDK's
        // server listens behind it on a loopback port.
        let listener = match tokio::net::TcpListener::bind(config.addr).await {
            Ok(listener) => listener,
            Err(error) if error.kind() == std::io::ErrorKind::AddrInUse => {
                return Err(LiveViewError::AddressInUse { addr: config.addr })
            }
            Err(error) => {
                return Err(LiveViewError::Start {
                    addr: config.addr,
                    source: ::foxglove::FoxgloveError::Bind(error),
                })
            }
        };
        let public = listener
            .local_addr()
            .map_err(|error| LiveViewError::Start {
                addr: config.addr,
                source: ::foxglove::FoxgloveError::Bind(error),
            })?;
        let inner = crate::foxglove_relay::inner_addr(config.addr);
        let host = match inner.ip() {
            IpAddr::V4(ip) => ip.to_string(),
            IpAddr::V6(ip) => format!("[{ip}]"),
        };
        let started = context
            .websocket_server()
            .name(format!("voxhap {}", env!("CARGO_PKG_VERSION")))
            .listener(resend.clone())
            .bind(host, inner.port())
            .start()
            .await;
        let handle = match started {
            Ok(handle) => handle,
            Err(::foxglove::FoxgloveError::Bind(error))
                if error.kind() == std::io::ErrorKind::AddrInUse =>
            {
                return Err(LiveViewError::AddressInUse { addr: config.addr })
            }
            Err(source) => {
                return Err(LiveViewError::Start {
                    addr: config.addr,
                    source,
                })
            }
        };
        let relay = tokio::spawn(crate::foxglove_relay::run(
            listener,
            SocketAddr::new(inner.ip(), handle.port()),
        ));
        let addr = public;
        let (stop, stopped) = oneshot::channel();
        let period = Duration::from_secs_f64(1.0 / f64::from(config.rate_hz));
        let publisher = tokio::spawn(publish(api, channels, resend, period, stopped));
        Ok(FoxgloveServer {
            _context: context,
            handle,
            addr,
            stop,
            publisher,
            relay,
        })
    }

    /// The address it listens on (with the real port when it was started on port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Clients connected now.
    pub fn client_count(&self) -> usize {
        self.handle.client_count()
    }

    /// Stops the publisher, closes every client connection and waits (at most [`STOP_TIMEOUT`]) for the
    /// server's tasks to end; tasks still running then are aborted.
    pub async fn stop(self) {
        let _ = self.stop.send(());
        let _ = self.publisher.await;
        let _ = tokio::time::timeout(STOP_TIMEOUT, self.handle.stop().wait()).await;
        self.relay.abort();
        let _ = self.relay.await;
    }
}

/// What `voxhap serve` does with the flags: start the view at `config`; when the default address is busy,
/// warn on stderr and go on without it (`Ok(None)`); an explicit busy address is an error.
pub async fn start_for_serve(
    api: Arc<dyn SessionApi>,
    config: Option<FoxgloveConfig>,
) -> Result<Option<FoxgloveServer>, LiveViewError> {
    let Some(config) = config else {
        return Ok(None);
    };
    match FoxgloveServer::start(api, &config).await {
        Ok(server) => Ok(Some(server)),
        Err(LiveViewError::AddressInUse { addr }) if !config.explicit => {
            eprintln!(
                "warning: foxglove: {addr} is already in use (another voxhap or a Foxglove bridge?); \
                 continuing without the Foxglove live view (choose an address with --foxglove ADDR, \
                 or --no-foxglove to silence this)"
            );
            Ok(None)
        }
        Err(error) => Err(error),
    }
}

/// Asks the publisher to send the volume picture again when a client subscribes to it (it is sent once per
/// scene otherwise, and a late subscriber would see nothing).
#[derive(Default)]
struct ResendOnSubscribe {
    volume: AtomicBool,
}

impl ServerListener for ResendOnSubscribe {
    fn on_subscribe(&self, _client: Client, channel: ChannelView) {
        if channel.topic() == VOLUME_TOPIC || channel.topic() == VOLUME_FRAME_TOPIC {
            self.volume.store(true, Ordering::Release);
        }
    }
}

/// The live view's channels, on their own [`Context`] (so several servers can run in one process).
struct Channels {
    measured_cp: Channel<FrameTransform>,
    setpoint_cp: Channel<FrameTransform>,
    measured_cv: Channel<Vector3>,
    setpoint_cf: Channel<Vector3>,
    operating_state: Channel<OperatingStateMessage>,
    primitives: Channel<SceneUpdate>,
    bound: Channel<BoundMessage>,
    stats: Channel<StatsMessage>,
    volume: Channel<SceneUpdate>,
    volume_frame: Channel<FrameTransform>,
    slices: [Channel<Grid>; 3],
    old_probe: Channel<FrameTransform>,
    old_proxy: Channel<FrameTransform>,
    old_force: Channel<Vector3>,
    old_servo_cf: Channel<Vector3>,
}

impl Channels {
    /// True when a client subscribed to one of the sampled topics.
    fn any_sampled_subscribed(&self) -> bool {
        self.measured_cp.has_sinks()
            || self.setpoint_cp.has_sinks()
            || self.measured_cv.has_sinks()
            || self.setpoint_cf.has_sinks()
            || self.operating_state.has_sinks()
            || self.primitives.has_sinks()
            || self.bound.has_sinks()
            || self.old_probe.has_sinks()
            || self.old_proxy.has_sinks()
            || self.old_force.has_sinks()
            || self.old_servo_cf.has_sinks()
    }

    fn volume_subscribed(&self) -> bool {
        self.volume.has_sinks() || self.volume_frame.has_sinks() || self.slices_subscribed()
    }

    fn slices_subscribed(&self) -> bool {
        self.slices.iter().any(Channel::has_sinks)
    }

    fn new(context: &Arc<Context>) -> Self {
        Channels {
            measured_cp: context.channel_builder(MEASURED_CP_TOPIC).build(),
            setpoint_cp: context.channel_builder(SETPOINT_CP_TOPIC).build(),
            measured_cv: context.channel_builder(MEASURED_CV_TOPIC).build(),
            setpoint_cf: context.channel_builder(SETPOINT_CF_TOPIC).build(),
            operating_state: context.channel_builder(OPERATING_STATE_TOPIC).build(),
            primitives: context.channel_builder(PRIMITIVES_TOPIC).build(),
            bound: context.channel_builder(BOUND_TOPIC).build(),
            stats: context.channel_builder(STATS_TOPIC).build(),
            volume: context.channel_builder(VOLUME_TOPIC).build(),
            volume_frame: context.channel_builder(VOLUME_FRAME_TOPIC).build(),
            slices: SLICE_TOPICS.map(|topic| context.channel_builder(topic).build()),
            old_probe: context.channel_builder(PROBE_TOPIC).build(),
            old_proxy: context.channel_builder(PROXY_TOPIC).build(),
            old_force: context.channel_builder(FORCE_TOPIC).build(),
            old_servo_cf: context.channel_builder(SERVO_CF_TOPIC).build(),
        }
    }
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// Turns snapshots into messages; keeps the reusable transforms and the tick-time-to-wall-clock offset.
struct Publisher {
    channels: Channels,
    probe: FrameTransform,
    proxy: FrameTransform,
    /// Wall-clock time (ns since the Unix epoch) of the session's tick time 0.
    epoch_ns: Option<u64>,
    last_tick: Option<u64>,
}

impl Publisher {
    fn new(channels: Channels) -> Self {
        Publisher {
            channels,
            probe: frame_transform(PROBE_FRAME, DVec3::ZERO, 0),
            proxy: frame_transform(PROXY_FRAME, DVec3::ZERO, 0),
            epoch_ns: None,
            last_tick: None,
        }
    }

    fn wall_ns(&mut self, t_s: f64) -> u64 {
        let tick_ns = (t_s.max(0.0) * 1e9) as u64;
        let epoch_ns = *self
            .epoch_ns
            .get_or_insert_with(|| unix_now_ns().saturating_sub(tick_ns));
        epoch_ns.saturating_add(tick_ns)
    }

    /// Publishes `snapshot` unless its tick was already published.
    fn snapshot(&mut self, snapshot: &Snapshot) {
        if self.last_tick == Some(snapshot.tick) {
            return;
        }
        self.last_tick = Some(snapshot.tick);
        let time_ns = self.wall_ns(snapshot.t_s);
        let c = &self.channels;
        set_translation(&mut self.probe, snapshot.probe_m, time_ns);
        set_translation(&mut self.proxy, snapshot.proxy_m, time_ns);
        for channel in [&c.measured_cp, &c.old_probe] {
            if channel.has_sinks() {
                channel.log_with_time(&self.probe, time_ns);
            }
        }
        for channel in [&c.setpoint_cp, &c.old_proxy] {
            if channel.has_sinks() {
                channel.log_with_time(&self.proxy, time_ns);
            }
        }
        for channel in [&c.setpoint_cf, &c.old_force, &c.old_servo_cf] {
            if channel.has_sinks() {
                channel.log_with_time(&vector3(snapshot.sent_force_n), time_ns);
            }
        }
        if c.measured_cv.has_sinks() {
            c.measured_cv
                .log_with_time(&vector3(snapshot.probe_velocity_m_per_s), time_ns);
        }
        if c.operating_state.has_sinks() {
            c.operating_state
                .log_with_time(&OperatingStateMessage::new(snapshot), time_ns);
        }
        if c.primitives.has_sinks() {
            let update = scene_update(snapshot, timestamp_from_ns(time_ns));
            c.primitives.log_with_time(&update, time_ns);
        }
        if c.bound.has_sinks() {
            c.bound.log_with_time(&BoundMessage::new(snapshot), time_ns);
        }
    }

    fn stats(&self, api: &dyn SessionApi) {
        if self.channels.stats.has_sinks() {
            self.channels
                .stats
                .log_with_time(&StatsMessage(api.stats()), unix_now_ns());
        }
    }

    /// Publishes the volume picture (bounds, mesh, the `volume` and `volume_view` frames).
    fn volume(&self, picture: &VolumePicture) {
        let time_ns = unix_now_ns();
        let (update, frames) = voxhap_record::foxglove_scene::volume_messages(
            &picture.description,
            picture.min_m,
            picture.max_m,
            picture.surface.as_ref(),
            time_ns,
        );
        self.channels.volume.log_with_time(&update, time_ns);
        for frame in frames {
            self.channels.volume_frame.log_with_time(&frame, time_ns);
        }
    }
}

/// What the blocking pool is computing for the publisher.
type Pending<T> = Option<JoinHandle<Result<T, voxhap_api::ControlError>>>;

/// The publisher task: samples `api` every `period` and publishes new ticks; statistics once a second; the
/// volume picture when the scene changes (or a client subscribes to it); the slices every
/// [`SLICE_INTERVAL`].
async fn publish(
    api: Arc<dyn SessionApi>,
    channels: Channels,
    resend: Arc<ResendOnSubscribe>,
    period: Duration,
    mut stop: oneshot::Receiver<()>,
) {
    let mut publisher = Publisher::new(channels);
    let mut sample = tokio::time::interval(period);
    sample.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut stats = tokio::time::interval(STATS_INTERVAL);
    stats.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut slices = tokio::time::interval(SLICE_INTERVAL);
    slices.set_missed_tick_behavior(MissedTickBehavior::Skip);
    // The scene generation the picture was built for, the picture, and the build in progress.
    let mut picture_generation: Option<u64> = None;
    let mut picture: Option<Arc<VolumePicture>> = None;
    let mut building: Pending<(u64, VolumePicture)> = None;
    let mut slicing: Pending<[Grid; 3]> = None;
    loop {
        tokio::select! {
            _ = &mut stop => break,
            _ = sample.tick() => {
                let snapshot = api.snapshot();
                if publisher.channels.any_sampled_subscribed() {
                    if let Some(snapshot) = &snapshot {
                        publisher.snapshot(snapshot);
                    }
                }
                // The volume picture: rebuilt when the scene changed, resent to new subscribers.
                if let Some(done) = building.take_if(|task| task.is_finished()) {
                    if let Ok(Ok((generation, built))) = done.await {
                        picture_generation = Some(generation);
                        let built = Arc::new(built);
                        publisher.volume(&built);
                        picture = Some(built);
                    } else {
                        // Keep the old picture; try again on the next scene change.
                        picture_generation = snapshot.as_ref().map(|s| s.scene_generation);
                    }
                }
                let generation = snapshot.as_ref().map(|s| s.scene_generation);
                if building.is_none()
                    && generation.is_some()
                    && generation != picture_generation
                    && publisher.channels.volume_subscribed()
                {
                    // Everyone subscribed now gets the picture when it is built.
                    resend.volume.store(false, Ordering::Release);
                    let api = api.clone();
                    let generation = generation.unwrap_or(0);
                    building = Some(tokio::task::spawn_blocking(move || {
                        volume::volume_picture(api.as_ref()).map(|p| (generation, p))
                    }));
                } else if resend.volume.swap(false, Ordering::AcqRel) {
                    if let Some(picture) = &picture {
                        publisher.volume(picture);
                    }
                }
            }
            _ = slices.tick() => {
                if let Some(done) = slicing.take_if(|task| task.is_finished()) {
                    if let Ok(Ok(grids)) = done.await {
                        for (channel, grid) in publisher.channels.slices.iter().zip(&grids) {
                            channel.log_with_time(grid, unix_now_ns());
                        }
                    }
                }
                let (Some(snapshot), Some(current)) = (api.snapshot(), picture.clone()) else { continue };
                if slicing.is_none() && publisher.channels.slices_subscribed() {
                    let api = api.clone();
                    let time_ns = publisher.wall_ns(snapshot.t_s);
                    slicing = Some(tokio::task::spawn_blocking(move || {
                        volume::slice_grids(api.as_ref(), &current.volume_name, snapshot.proxy_m, time_ns)
                    }));
                }
            }
            _ = stats.tick() => publisher.stats(api.as_ref()),
        }
    }
    for task in [
        building.map(|t| t.abort_handle()),
        slicing.map(|t| t.abort_handle()),
    ]
    .into_iter()
    .flatten()
    {
        task.abort();
    }
}

/// The shipped Foxglove layout (`contrib/foxglove/voxhap-layout.json`).
pub const SHIPPED_LAYOUT: &str = include_str!("../../../contrib/foxglove/voxhap-layout.json");

/// The topics a Foxglove layout refers to, in panel order: 3D panel topics, plot and state-transition
/// paths (up to the first `.`), raw-message panels' topic paths; `None` when `layout` has no panels.
pub fn layout_topics(layout: &serde_json::Value) -> Option<Vec<String>> {
    let mut topics = Vec::new();
    let topic_of = |path: &str| path.split('.').next().unwrap_or(path).to_owned();
    for config in layout["configById"].as_object()?.values() {
        if let Some(map) = config["topics"].as_object() {
            topics.extend(map.keys().cloned());
        }
        for path in config["paths"].as_array().into_iter().flatten() {
            topics.extend(path["value"].as_str().map(topic_of));
        }
        topics.extend(config["topicPath"].as_str().map(topic_of));
    }
    Some(topics)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(args: &[&str]) -> Result<FoxgloveArgs, clap::Error> {
        crate::config::parse_flags(args)
    }

    #[test]
    fn defaults_are_loopback_8765_at_60_hz_and_not_explicit() {
        let config = parse(&[]).unwrap().resolve().unwrap().unwrap();
        assert_eq!(config.addr, "127.0.0.1:8765".parse().unwrap());
        assert!(!config.explicit);
        assert_eq!(config.rate_hz, 60);
        assert_eq!(parse(&["--no-foxglove"]).unwrap().resolve().unwrap(), None);
    }

    #[test]
    fn a_remote_address_needs_the_flag() {
        let args = parse(&["--foxglove", "0.0.0.0:9000"]).unwrap();
        let error = args.resolve().unwrap_err();
        assert!(matches!(error, LiveViewError::RemoteNotAllowed { .. }));
        assert!(
            error.to_string().contains("--foxglove-allow-remote"),
            "{error}"
        );
        let args = parse(&["--foxglove", "0.0.0.0:9000", "--foxglove-allow-remote"]).unwrap();
        let config = args.resolve().unwrap().unwrap();
        assert!(config.explicit);
        for loopback in ["[::1]:9000", "localhost:9000", "127.0.0.2:9000"] {
            let config = parse(&["--foxglove", loopback]).unwrap().resolve().unwrap();
            assert!(config.is_some(), "{loopback}");
        }
    }

    #[test]
    fn the_shipped_layout_uses_only_current_topics_and_the_palette() {
        let layout: serde_json::Value = serde_json::from_str(SHIPPED_LAYOUT).unwrap();
        for id in layout["configById"].as_object().unwrap().keys() {
            assert!(id.contains('!'), "panel id {id}");
        }
        let topics = layout_topics(&layout).unwrap();
        assert!(topics.len() >= 8, "{topics:?}");
        let current = &TOPICS[..TOPICS.len() - 4];
        for topic in &topics {
            assert!(
                current.contains(&topic.as_str()),
                "{topic} is not advertised (or deprecated)"
            );
        }
        // The camera: follows the position of the frame the framing places, with the camera state the
        // framing assumes (CameraFraming).
        use voxhap_view::topics;
        let panel = &layout["configById"]["3D!voxhap"];
        assert_eq!(panel["followTf"], topics::VIEW_FRAME);
        assert_eq!(panel["followMode"], "follow-position");
        let camera = &panel["cameraState"];
        assert_eq!(camera["distance"], topics::LAYOUT_CAMERA_DISTANCE_M);
        assert_eq!(camera["phi"], topics::LAYOUT_CAMERA_PHI_DEG);
        assert_eq!(
            camera["thetaOffset"],
            topics::LAYOUT_CAMERA_THETA_OFFSET_DEG
        );
        assert_eq!(camera["fovy"], topics::LAYOUT_CAMERA_FOVY_DEG);
        assert_eq!(camera["perspective"], true);
        assert_eq!(camera["targetOffset"], serde_json::json!([0, 0, 0]));
        let colours = voxhap_view::palette::palette();
        let force = &layout["configById"]["Plot!force"]["paths"];
        for (axis, path) in force.as_array().unwrap().iter().enumerate() {
            assert_eq!(
                path["color"],
                colours.force_axes[axis].hex(),
                "force axis {axis}"
            );
        }
        let bound = &layout["configById"]["Plot!bound"]["paths"][0];
        assert_eq!(bound["color"], colours.proxy.hex());
    }

    #[test]
    fn bad_values_are_refused_by_the_parser() {
        for bad in [
            &["--foxglove-rate", "0"][..],
            &["--foxglove-rate", "1001"],
            &["--foxglove", "8765"],
            &["--foxglove", "example.org:80"],
            &["--no-foxglove", "--foxglove", "127.0.0.1:1"],
        ] {
            assert!(parse(bad).is_err(), "{bad:?} accepted");
        }
        assert_eq!(
            parse(&["--foxglove-rate", "1000"]).unwrap().foxglove_rate,
            1000
        );
    }
}
