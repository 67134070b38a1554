//! The ROS 2 output seen by a ROS 2 subscriber in the same test (a second DDS participant, ros2-client's
//! own reader, loopback only): the topics and DDS type names a ROS 2 node looks for, and the values of the
//! snapshot they were published from. The Python check (.ci/check-ros2.sh) does the same with Cyclone DDS,
//! an implementation voxhap does not use.

use glam::DVec3;
use ros2_client::{Name, Subscription};
use serde::de::DeserializeOwned;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use voxhap_api::Snapshot;
use voxhap_core::status::OutputState;
use voxhap_ros2::messages::{OperatingState, PoseStamped, TwistStamped, WrenchStamped};
use voxhap_ros2::output::{create_context, create_node};
use voxhap_ros2::topics::{self, TopicSpec};
use voxhap_ros2::{Ros2Output, Ros2Settings};

/// Generous: discovery on a busy machine. Only a guard against a hang, not a timing assertion.
const WAIT: Duration = Duration::from_secs(60);

fn settings() -> Ros2Settings {
    // A domain of its own per test process, so parallel runs on one machine do not see each other.
    Ros2Settings {
        domain_id: 100 + (std::process::id() % 100) as u16,
        localhost_only: true,
    }
}

fn snapshot() -> Snapshot {
    Snapshot {
        tick: 1234,
        t_s: 1.234,
        probe_m: DVec3::new(0.011, -0.022, 0.033),
        probe_velocity_m_per_s: DVec3::new(0.1, -0.2, 0.3),
        rendered_force_n: DVec3::new(1.25, -0.5, 2.0),
        sent_force_n: DVec3::new(0.75, -0.25, 1.0),
        output_state: OutputState::Faulted,
        engaged: false,
        ..Snapshot::example()
    }
}

fn subscribe<M: DeserializeOwned + 'static>(
    node: &mut ros2_client::Node,
    spec: TopicSpec,
) -> Subscription<M> {
    let topic = node
        .create_topic(
            &Name::new("/voxhap", spec.name).unwrap(),
            spec.message_type(),
            &spec.qos(),
        )
        .unwrap();
    node.create_subscription(&topic, Some(spec.qos())).unwrap()
}

fn first<M: DeserializeOwned + 'static>(subscription: &Subscription<M>, what: &str) -> M {
    let start = Instant::now();
    loop {
        if let Some((message, _)) = subscription.take().unwrap() {
            return message;
        }
        assert!(start.elapsed() < WAIT, "no {what} within {WAIT:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_ros2_subscriber_receives_every_crtk_topic_with_the_snapshot_values() {
    let settings = settings();
    // The servo loop ticks on: only a new tick is published, so each read is the next tick of the same state.
    let ticks = AtomicU64::new(0);
    let source = move || {
        Some(Snapshot {
            tick: ticks.fetch_add(1, Ordering::Relaxed),
            ..snapshot()
        })
    };
    let output = Ros2Output::start(settings, 1000.0, Box::new(source)).unwrap();
    let context = create_context(settings).unwrap();
    let mut node = create_node(&context).unwrap();
    let cp: Subscription<PoseStamped> = subscribe(&mut node, topics::MEASURED_CP);
    let cv: Subscription<TwistStamped> = subscribe(&mut node, topics::MEASURED_CV);
    let cf: Subscription<WrenchStamped> = subscribe(&mut node, topics::MEASURED_CF);
    let setpoint: Subscription<WrenchStamped> = subscribe(&mut node, topics::SETPOINT_CF);
    let state: Subscription<OperatingState> = subscribe(&mut node, topics::OPERATING_STATE);

    let pose = first(&cp, "measured_cp");
    assert_eq!(pose.header.frame_id, "world");
    let p = pose.pose.position;
    assert_eq!((p.x, p.y, p.z), (0.011, -0.022, 0.033));
    let o = pose.pose.orientation;
    assert_eq!((o.x, o.y, o.z, o.w), (0.0, 0.0, 0.0, 1.0));
    let twist = first(&cv, "measured_cv").twist.linear;
    assert_eq!((twist.x, twist.y, twist.z), (0.1, -0.2, 0.3));
    let measured = first(&cf, "measured_cf").wrench.force;
    assert_eq!((measured.x, measured.y, measured.z), (1.25, -0.5, 2.0));
    let sent = first(&setpoint, "setpoint_cf").wrench;
    assert_eq!(
        (sent.force.x, sent.force.y, sent.force.z),
        (0.75, -0.25, 1.0)
    );
    assert_eq!(
        (sent.torque.x, sent.torque.y, sent.torque.z),
        (0.0, 0.0, 0.0)
    );
    let operating = first(&state, "operating_state");
    assert_eq!(operating.state, "FAULT", "a faulted session is CRTK FAULT");
    assert!(operating.is_homed, "a connected device");

    // The DDS names a ROS 2 node uses (ROS 2 design, "Topic and Service name mapping to DDS":
    // topics under rt/, types as package::msg::dds_::Type_).
    let writers: Vec<(String, String)> = context
        .domain_participant()
        .discovered_writers()
        .into_iter()
        .map(|w| {
            (
                w.publication_topic_data.topic_name,
                w.publication_topic_data.type_name,
            )
        })
        .collect();
    for (topic, type_name) in [
        (
            "rt/voxhap/measured_cp",
            "geometry_msgs::msg::dds_::PoseStamped_",
        ),
        (
            "rt/voxhap/measured_cv",
            "geometry_msgs::msg::dds_::TwistStamped_",
        ),
        (
            "rt/voxhap/measured_cf",
            "geometry_msgs::msg::dds_::WrenchStamped_",
        ),
        (
            "rt/voxhap/setpoint_cf",
            "geometry_msgs::msg::dds_::WrenchStamped_",
        ),
        (
            "rt/voxhap/operating_state",
            "crtk_msgs::msg::dds_::OperatingState_",
        ),
    ] {
        assert!(
            writers.iter().any(|(t, ty)| t == topic && ty == type_name),
            "{topic} ({type_name}) not among the writers {writers:?}"
        );
    }
    let stats = output.stop();
    assert!(
        stats.ticks_published >= 1 && stats.states_published >= 1,
        "{stats:?}"
    );
    assert_eq!(stats.non_finite, 0);
}
