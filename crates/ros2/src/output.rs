//! The publishing thread: every [`publish_period`] it reads the session's newest snapshot and, when the
//! servo loop has ticked since, publishes the four CRTK streams; the operating state goes out when it
//! changes and once a second.
//!
//! The servo thread is untouched: the snapshot comes from the same triple buffer the other visualiser
//! outputs read (through the closure the caller gives), and DDS runs on RustDDS's own thread. A write that
//! cannot go out at once (a reliable reader's window is full) is dropped and counted, never waited on.

use crate::args::Ros2Settings;
use crate::crtk::{messages, operating_state_message};
use crate::error::Ros2Error;
use crate::messages::{OperatingState, PoseStamped, Time, TwistStamped, WrenchStamped};
use crate::servo_cf::{ExternalForceSink, ServoCfInput, ServoCfStats};
use crate::topics::{self, TopicSpec};
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::{Context, Name, Node, NodeName, NodeOptions, Publisher, Subscription};
use serde::Serialize;
use std::net::Ipv4Addr;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use voxhap_api::Snapshot;

/// The highest rate the streams are published at (Hz).
pub const MAX_PUBLISH_RATE_HZ: f64 = 100.0;

/// How often the operating state is published when it does not change.
pub const STATE_INTERVAL: Duration = Duration::from_secs(1);

/// Where the newest snapshot comes from (`SessionApi::snapshot` in `serve`).
pub type SnapshotSource = Box<dyn Fn() -> Option<Snapshot> + Send + 'static>;

/// The publishing period for a servo loop at `servo_rate_hz`: a whole number of servo periods, the fewest
/// that keep the rate at or below [`MAX_PUBLISH_RATE_HZ`] (1000 Hz servo: every 10th tick, 100 Hz; 250 Hz:
/// every 3rd, 83.3 Hz).
pub fn publish_period(servo_rate_hz: f64) -> Result<Duration, Ros2Error> {
    if !(servo_rate_hz.is_finite() && servo_rate_hz > 0.0) {
        return Err(Ros2Error::Rate {
            rate_hz: servo_rate_hz,
        });
    }
    let ticks = (servo_rate_hz / MAX_PUBLISH_RATE_HZ).ceil().max(1.0);
    Duration::try_from_secs_f64(ticks / servo_rate_hz).map_err(|_| Ros2Error::Rate {
        rate_hz: servo_rate_hz,
    })
}

/// What the publishing thread did, reported when it stops.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishStats {
    /// Snapshots published (each one sample on every stream).
    pub ticks_published: u64,
    /// Operating state messages published.
    pub states_published: u64,
    /// Writes DDS refused (dropped, not retried).
    pub failed_writes: u64,
    /// Messages left out because a value was not finite.
    pub non_finite: u64,
    /// What the `/voxhap/servo_cf` subscription took (`None`: no external force input).
    pub servo_cf: Option<ServoCfStats>,
}

/// The running ROS 2 output. Stops on [`Ros2Output::stop`] or when dropped.
pub struct Ros2Output {
    stop: Option<mpsc::Sender<()>>,
    thread: Option<JoinHandle<PublishStats>>,
    period: Duration,
    settings: Ros2Settings,
    /// The `/voxhap/servo_cf` subscription, stopped before the publishing thread drops the node.
    servo_cf: Option<ServoCfInput>,
}

struct Publishers {
    measured_cp: Publisher<PoseStamped>,
    measured_cv: Publisher<TwistStamped>,
    measured_cf: Publisher<WrenchStamped>,
    setpoint_cf: Publisher<WrenchStamped>,
    operating_state: Publisher<OperatingState>,
}

fn create_error(what: impl Into<String>) -> impl FnOnce(ros2_client::CreateError) -> Ros2Error {
    let what = what.into();
    move |cause| Ros2Error::Create {
        what,
        cause: cause.to_string(),
    }
}

fn publisher<M: Serialize>(node: &mut Node, spec: TopicSpec) -> Result<Publisher<M>, Ros2Error> {
    let name = Name::new(topics::NAMESPACE, spec.name).map_err(|cause| Ros2Error::Create {
        what: format!("topic {}", spec.ros_name()),
        cause: cause.to_string(),
    })?;
    let topic = node
        .create_topic(&name, spec.message_type(), &spec.qos())
        .map_err(create_error(format!("topic {}", spec.ros_name())))?;
    node.create_publisher(&topic, Some(spec.qos()))
        .map_err(create_error(format!("publisher {}", spec.ros_name())))
}

fn subscription<M: serde::de::DeserializeOwned + 'static>(
    node: &mut Node,
    spec: TopicSpec,
) -> Result<Subscription<M>, Ros2Error> {
    let name = Name::new(topics::NAMESPACE, spec.name).map_err(|cause| Ros2Error::Create {
        what: format!("topic {}", spec.ros_name()),
        cause: cause.to_string(),
    })?;
    let qos = topics::command_qos();
    let topic = node
        .create_topic(&name, spec.message_type(), &qos)
        .map_err(create_error(format!("topic {}", spec.ros_name())))?;
    node.create_subscription(&topic, Some(qos))
        .map_err(create_error(format!("subscription {}", spec.ros_name())))
}

/// The DDS participant for `settings`, as a ros2-client context.
pub fn create_context(settings: Ros2Settings) -> Result<Context, Ros2Error> {
    let mut builder = DomainParticipantBuilder::new(settings.domain_id);
    if settings.localhost_only {
        builder = builder.with_only_networks([Ipv4Addr::LOCALHOST]);
    }
    let participant = builder.build().map_err(|cause| Ros2Error::Participant {
        domain_id: settings.domain_id,
        cause: cause.to_string(),
    })?;
    Context::from_domain_participant(participant).map_err(|cause| Ros2Error::Participant {
        domain_id: settings.domain_id,
        cause: cause.to_string(),
    })
}

/// The `/voxhap/voxhap` node in `context`.
pub fn create_node(context: &Context) -> Result<Node, Ros2Error> {
    let name =
        NodeName::new(topics::NAMESPACE, topics::NODE_NAME).map_err(|cause| Ros2Error::Create {
            what: "the node name".to_owned(),
            cause: cause.to_string(),
        })?;
    context
        .new_node(
            name,
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .map_err(|cause| Ros2Error::Create {
            what: format!("node {}/{}", topics::NAMESPACE, topics::NODE_NAME),
            cause: cause.to_string(),
        })
}

impl Ros2Output {
    /// Creates the node and its publishers (errors come back here) and starts publishing from `source` at
    /// [`publish_period`]`(servo_rate_hz)`.
    pub fn start(
        settings: Ros2Settings,
        servo_rate_hz: f64,
        source: SnapshotSource,
    ) -> Result<Ros2Output, Ros2Error> {
        Self::start_with_servo_cf(settings, servo_rate_hz, source, None)
    }

    /// As [`Ros2Output::start`]; with `external_force`, also subscribes to `/voxhap/servo_cf` and hands each
    /// wrench's force to it (crate::servo_cf).
    pub fn start_with_servo_cf(
        settings: Ros2Settings,
        servo_rate_hz: f64,
        source: SnapshotSource,
        external_force: Option<ExternalForceSink>,
    ) -> Result<Ros2Output, Ros2Error> {
        let period = publish_period(servo_rate_hz)?;
        let mut node = create_node(&create_context(settings)?)?;
        let servo_cf = match external_force {
            Some(sink) => Some(ServoCfInput::start(
                subscription(&mut node, topics::SERVO_CF)?,
                sink,
            )?),
            None => None,
        };
        let publishers = Publishers {
            measured_cp: publisher(&mut node, topics::MEASURED_CP)?,
            measured_cv: publisher(&mut node, topics::MEASURED_CV)?,
            measured_cf: publisher(&mut node, topics::MEASURED_CF)?,
            setpoint_cf: publisher(&mut node, topics::SETPOINT_CF)?,
            operating_state: publisher(&mut node, topics::OPERATING_STATE)?,
        };
        let (stop, stopped) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("ros2".to_owned())
            .spawn(move || {
                let stats = run(&publishers, &source, period, &stopped);
                // The node (and with it the DDS participant) goes after its publishers.
                drop(publishers);
                drop(node);
                stats
            })
            .map_err(Ros2Error::Thread)?;
        Ok(Ros2Output {
            stop: Some(stop),
            thread: Some(thread),
            period,
            settings,
            servo_cf,
        })
    }

    /// The publishing period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The settings it runs with.
    pub fn settings(&self) -> Ros2Settings {
        self.settings
    }

    /// Stops publishing and leaves the DDS domain; what was published.
    pub fn stop(mut self) -> PublishStats {
        self.shutdown()
    }

    fn shutdown(&mut self) -> PublishStats {
        let servo_cf = self.servo_cf.take().map(ServoCfInput::stop);
        drop(self.stop.take());
        let mut stats: PublishStats = self
            .thread
            .take()
            .and_then(|thread| thread.join().ok())
            .unwrap_or_default();
        stats.servo_cf = servo_cf.or(stats.servo_cf);
        stats
    }
}

impl Drop for Ros2Output {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Maps the session's tick time to wall-clock time, fixed at the first snapshot (as the OpenIGTLink output
/// does), so stamps advance with the servo loop's own clock.
#[derive(Default)]
struct WallClock {
    epoch_ns: Option<u64>,
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl WallClock {
    fn at(&mut self, t_s: f64) -> Time {
        let tick_ns = if t_s.is_finite() {
            (t_s.max(0.0) * 1e9) as u64
        } else {
            0
        };
        let epoch = *self
            .epoch_ns
            .get_or_insert_with(|| unix_now_ns().saturating_sub(tick_ns));
        Time::from_unix_ns(epoch.saturating_add(tick_ns))
    }
}

fn send<M: Serialize>(publisher: &Publisher<M>, message: Option<M>, stats: &mut PublishStats) {
    match message {
        None => stats.non_finite += 1,
        Some(message) => {
            if publisher.publish(message).is_err() {
                stats.failed_writes += 1;
            }
        }
    }
}

fn run(
    publishers: &Publishers,
    source: &SnapshotSource,
    period: Duration,
    stopped: &mpsc::Receiver<()>,
) -> PublishStats {
    let mut stats = PublishStats::default();
    let mut clock = WallClock::default();
    let mut last_tick = None;
    let mut last_state: Option<(OperatingState, Instant)> = None;
    let mut next = Instant::now();
    // Until `stop` (a message, or the sender dropped).
    while let Err(RecvTimeoutError::Timeout) =
        stopped.recv_timeout(next.saturating_duration_since(Instant::now()))
    {
        let now = Instant::now();
        next += period;
        if next < now {
            // Behind (a busy machine): skip the missed periods rather than publish in a burst.
            next = now + period;
        }
        let snapshot = source();
        let stamp = match &snapshot {
            Some(s) => clock.at(s.t_s),
            None => Time::from_unix_ns(unix_now_ns()),
        };
        if let Some(s) = snapshot.as_ref().filter(|s| last_tick != Some(s.tick)) {
            last_tick = Some(s.tick);
            let m = messages(s, stamp);
            send(&publishers.measured_cp, m.measured_cp, &mut stats);
            send(&publishers.measured_cv, m.measured_cv, &mut stats);
            send(&publishers.measured_cf, m.measured_cf, &mut stats);
            send(&publishers.setpoint_cf, m.setpoint_cf, &mut stats);
            stats.ticks_published += 1;
        }
        let state = operating_state_message(snapshot.as_ref(), stamp);
        let due = last_state.as_ref().is_none_or(|(last, at)| {
            (last.state.as_str(), last.is_homed, last.is_busy)
                != (state.state.as_str(), state.is_homed, state.is_busy)
                || now.duration_since(*at) >= STATE_INTERVAL
        });
        if due {
            last_state = Some((state.clone(), now));
            send(&publishers.operating_state, Some(state), &mut stats);
            stats.states_published += 1;
        }
    }
    stats
}

#[cfg(test)]
#[path = "output_tests.rs"]
mod tests;
