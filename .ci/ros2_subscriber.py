#!/usr/bin/env python3
"""An independent ROS 2 subscriber for .ci/check-ros2.sh: Eclipse Cyclone DDS (PyPI `cyclonedds`, the DDS
that ROS 2's default rmw on several distributions uses; voxhap uses RustDDS) subscribes to a running
`voxhap serve --ros2 ... --http ...` with the ROS 2 topic and type names, the message types declared here
from their .msg files, and checks the values against the same server's /api/state.

- Discovery: Cyclone's built-in DCPSPublication topic lists the five writers under their DDS names
  (rt/voxhap/..., package::msg::dds_::Type_), reliable, the operating state transient local.
- measured_cp: with the simulated hand held in free space (POST /api/hand), the pose equals /api/state's
  probe_m, frame "world", identity orientation.
- measured_cf / setpoint_cf: pressed into the ball, the wrenches equal /api/state's rendered_force_n and
  force_n (the force sent).
- measured_cv: finite, zero angular part; near zero at rest.
- operating_state: ENABLED, homed, while /api/state says engaged; received at once by a late subscriber
  (transient local).
- The publishing rate is printed (not asserted: it depends on the machine's load).
- servo_cf (with `serve --external-force`): voxhap's reader of rt/voxhap/servo_cf is discovered with the ROS 2
  names and best-effort QoS; wrenches published from here as `ros2 topic pub` would (reliable writer, frame
  "world") show in /api/state's external_force_n exactly; a wrench in another frame and
  one with a NaN force are refused (external_force_n stays zero); once publishing stops, external_force_n
  returns to zero (the staleness timeout).

Usage: ros2_subscriber.py DOMAIN_ID HTTP_URL TOKEN. CYCLONEDDS_URI must keep Cyclone on the loopback
interface (check-ros2.sh sets it). Exit 0 when every check passes; otherwise 1 with the failed check.
"""

import json
import math
import sys
import time
import urllib.request
from dataclasses import dataclass

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


# The ROS 2 types, field by field as their .msg files (builtin_interfaces, std_msgs, geometry_msgs from ROS 2's
# common interfaces; crtk_msgs 1.3.0), under the DDS names ROS 2 gives them.
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    header: Header
    twist: Twist


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3
    torque: Vector3


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header
    wrench: Wrench


@dataclass
class OperatingState(IdlStruct, typename="crtk_msgs::msg::dds_::OperatingState_"):
    header: Header
    state: str
    is_homed: bool
    is_busy: bool


def fail(message):
    print(f"ros2_subscriber: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def check(condition, message):
    if not condition:
        fail(message)


def http_json(url, body=None, token=None):
    request = urllib.request.Request(url, data=None if body is None else json.dumps(body).encode())
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
        request.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.load(response)


STREAM_QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile,
                 Policy.History.KeepLast(10))
LATCHED_QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.TransientLocal,
                  Policy.History.KeepLast(1))


def newest(reader, what, timeout=30.0):
    """The newest sample arriving after this call (samples already queued are dropped first)."""
    reader.take(N=1000)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        samples = reader.take(N=1000)
        if samples:
            return samples[-1]
        time.sleep(0.01)
    fail(f"no {what} sample within {timeout} s")


def vec(v):
    return [v.x, v.y, v.z]


def close(a, b, tolerance):
    return all(math.isfinite(x) for x in a) and max(abs(x - y) for x, y in zip(a, b)) <= tolerance


def main():
    domain_id, http, token = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    participant = DomainParticipant(domain_id)
    readers = {}
    for name, kind in [("measured_cp", PoseStamped), ("measured_cv", TwistStamped),
                       ("measured_cf", WrenchStamped), ("setpoint_cf", WrenchStamped)]:
        readers[name] = DataReader(participant, Topic(participant, f"rt/voxhap/{name}", kind), qos=STREAM_QOS)

    # 1. Every writer discovered under its ROS 2 name and type, with the QoS docs/ros2.md gives.
    expected = {
        "rt/voxhap/measured_cp": "geometry_msgs::msg::dds_::PoseStamped_",
        "rt/voxhap/measured_cv": "geometry_msgs::msg::dds_::TwistStamped_",
        "rt/voxhap/measured_cf": "geometry_msgs::msg::dds_::WrenchStamped_",
        "rt/voxhap/setpoint_cf": "geometry_msgs::msg::dds_::WrenchStamped_",
        "rt/voxhap/operating_state": "crtk_msgs::msg::dds_::OperatingState_",
    }
    publications = BuiltinDataReader(participant, BuiltinTopicDcpsPublication)
    found = {}
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and len(found) < len(expected):
        for sample in publications.take(N=100):
            if sample.topic_name in expected:
                found[sample.topic_name] = sample
        time.sleep(0.05)
    check(set(found) == set(expected), f"writers discovered: {sorted(found)}; expected {sorted(expected)}")
    for topic, sample in found.items():
        check(sample.type_name == expected[topic], f"{topic}: type {sample.type_name}, expected {expected[topic]}")
        reliability = sample.qos[Policy.Reliability]
        check(isinstance(reliability, Policy.Reliability.Reliable), f"{topic}: {reliability}, expected reliable")
        durability = sample.qos[Policy.Durability]
        wanted = Policy.Durability.TransientLocal if topic.endswith("operating_state") else Policy.Durability.Volatile
        check(durability == wanted, f"{topic}: {durability}, expected {wanted}")
    print(f"ros2_subscriber: {len(found)} writers discovered with ROS 2 names, types and QoS")

    # 2. The rate (printed only).
    readers["measured_cp"].take(N=1000)
    count, end = 0, time.monotonic() + 2.0
    while time.monotonic() < end:
        count += len(readers["measured_cp"].take(N=1000))
        time.sleep(0.02)
    print(f"ros2_subscriber: measured_cp at {count / 2.0:.1f} Hz over 2 s")
    check(count > 0, "no measured_cp in 2 s")

    # 3. Free space: the hand held 40 mm above the ball; measured_cp equals /api/state's probe_m.
    target = [0.0, 0.0, 0.04]
    http_json(f"{http}/api/hand", {"position_m": target}, token)
    time.sleep(3.0)
    before = http_json(f"{http}/api/state")
    pose = newest(readers["measured_cp"], "measured_cp")
    after = http_json(f"{http}/api/state")
    position = vec(pose.pose.position)
    moved = max(abs(a - b) for a, b in zip(before["probe_m"], after["probe_m"]))
    check(close(position, before["probe_m"], 1e-6 + moved),
          f"measured_cp {position} against /api/state probe_m {before['probe_m']} (moved {moved} m meanwhile)")
    check(close(position, target, 0.003), f"measured_cp {position} m is not near the hand target {target} m")
    o = pose.pose.orientation
    check([o.x, o.y, o.z, o.w] == [0.0, 0.0, 0.0, 1.0], f"orientation {o}")
    check(pose.header.frame_id == "world", f"frame_id {pose.header.frame_id!r}")
    stamp = pose.header.stamp.sec + pose.header.stamp.nanosec * 1e-9
    check(abs(stamp - time.time()) < 60.0, f"stamp {stamp} is not wall-clock time (now {time.time()})")
    twist = newest(readers["measured_cv"], "measured_cv").twist
    check(close(vec(twist.linear), [0.0, 0.0, 0.0], 0.05), f"measured_cv {vec(twist.linear)} m/s at rest")
    check(vec(twist.angular) == [0.0, 0.0, 0.0], f"angular {vec(twist.angular)}")
    print(f"ros2_subscriber: measured_cp {position} m = /api/state probe_m {before['probe_m']} m")

    # 4. Pressed onto the ball's top: measured_cf = rendered_force_n, setpoint_cf = force_n (the force sent). The
    # surface is at about z = 30 mm; the hand lowered 1 mm at a time to 6 mm below it presses with about 1.1 N
    # (the hand's 300 N/m spring against the 500 N/m coupling), below the surface's 2 N yield, so the proxy stays
    # on top and the force is steady (inside the ball, past the surface, only viscous drag acts: none at rest).
    for z_mm in [31.0 - i for i in range(8)]:
        http_json(f"{http}/api/hand", {"position_m": [0.0, 0.0, z_mm / 1000.0]}, token)
        time.sleep(0.25)
    time.sleep(3.0)
    before = http_json(f"{http}/api/state")
    measured = vec(newest(readers["measured_cf"], "measured_cf").wrench.force)
    setpoint = newest(readers["setpoint_cf"], "setpoint_cf").wrench
    after = http_json(f"{http}/api/state")
    drift = max(abs(a - b) for a, b in zip(before["force_n"], after["force_n"]))
    check(math.hypot(*before["force_n"]) > 0.1, f"no force inside the ball: /api/state force_n {before['force_n']}")
    check(close(measured, before["rendered_force_n"], 1e-6 + drift),
          f"measured_cf {measured} N against /api/state rendered_force_n {before['rendered_force_n']} N")
    check(close(vec(setpoint.force), before["force_n"], 1e-6 + drift),
          f"setpoint_cf {vec(setpoint.force)} N against /api/state force_n {before['force_n']} N")
    check(vec(setpoint.torque) == [0.0, 0.0, 0.0], f"torque {vec(setpoint.torque)}")
    check(setpoint.force.z > 0, f"the ball's top pushes up (+z): {vec(setpoint.force)}")
    print(f"ros2_subscriber: setpoint_cf {vec(setpoint.force)} N = /api/state force_n {before['force_n']} N; "
          f"measured_cf {measured} N = rendered_force_n")

    # 5. The operating state, read by a subscriber that joins now (transient local: the current state at once).
    state_reader = DataReader(participant, Topic(participant, "rt/voxhap/operating_state", OperatingState),
                              qos=LATCHED_QOS)
    deadline = time.monotonic() + 30.0
    states = []
    while time.monotonic() < deadline and not states:
        states = state_reader.take(N=10)
        time.sleep(0.01)
    check(states, "no operating_state within 30 s")
    state = states[-1]
    engaged = http_json(f"{http}/api/state")["engaged"]
    check(engaged, "/api/state says not engaged")
    check(state.state == "ENABLED" and state.is_homed and not state.is_busy,
          f"operating_state {state.state} homed {state.is_homed} busy {state.is_busy} while engaged")
    print(f"ros2_subscriber: operating_state {state.state} (homed, not busy) while engaged")
    check_servo_cf(participant, http, token)
    http_json(f"{http}/api/hand", {"position_m": None}, token)
    print("ros2_subscriber: OK")


def wrench(force, frame="world"):
    return WrenchStamped(
        header=Header(stamp=Time(sec=int(time.time()), nanosec=0), frame_id=frame),
        wrench=Wrench(force=Vector3(*force), torque=Vector3(0.0, 0.0, 0.0)),
    )


def publish_for(writer, message, seconds, rate_hz=50.0):
    """Publishes `message` at `rate_hz` for `seconds` (as `ros2 topic pub -r 50` does)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        writer.write(message)
        time.sleep(1.0 / rate_hz)


def check_servo_cf(participant, http, token):
    # voxhap's reader, found under its ROS 2 name and type, best effort.
    subscriptions = BuiltinDataReader(participant, BuiltinTopicDcpsSubscription)
    reader = None
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and reader is None:
        for sample in subscriptions.take(N=100):
            if sample.topic_name == "rt/voxhap/servo_cf":
                reader = sample
        time.sleep(0.05)
    check(reader is not None, "no reader of rt/voxhap/servo_cf discovered (serve --external-force)")
    check(reader.type_name == "geometry_msgs::msg::dds_::WrenchStamped_", f"servo_cf type {reader.type_name}")
    check(reader.qos[Policy.Reliability] == Policy.Reliability.BestEffort,
          f"servo_cf reader {reader.qos[Policy.Reliability]}, expected best effort")
    print("ros2_subscriber: voxhap's servo_cf reader discovered (WrenchStamped, best effort)")

    # The hand in free space, 40 mm above the ball: the scene renders nothing there.
    http_json(f"{http}/api/hand", {"position_m": [0.0, 0.0, 0.04]}, token)
    time.sleep(2.0)
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile,
              Policy.History.KeepLast(10))
    writer = DataWriter(participant, Topic(participant, "rt/voxhap/servo_cf", WrenchStamped), qos=qos)
    force = [0.3, -0.2, 0.1]
    # Until voxhap has the wrench (discovery takes a moment), then 2 s more.
    deadline = time.monotonic() + 30.0
    state = http_json(f"{http}/api/state")
    while time.monotonic() < deadline and state["external_force_n"] != force:
        publish_for(writer, wrench(force), 0.2)
        state = http_json(f"{http}/api/state")
    check(state["external_force_n"] == force,
          f"/api/state external_force_n {state['external_force_n']} while publishing {force} on servo_cf")
    publish_for(writer, wrench(force), 2.0)
    state = http_json(f"{http}/api/state")
    check(state["external_force_n"] == force, f"external_force_n {state['external_force_n']}, published {force}")
    print(f"ros2_subscriber: servo_cf {force} N -> /api/state external_force_n {state['external_force_n']}, "
          f"force_n {state['force_n']}")

    # Stopped: zero after the staleness timeout (polled; no timing asserted beyond a generous guard).
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and state["external_force_n"] != [0.0, 0.0, 0.0]:
        time.sleep(0.05)
        state = http_json(f"{http}/api/state")
    check(state["external_force_n"] == [0.0, 0.0, 0.0],
          f"external_force_n {state['external_force_n']} after publishing stopped")
    print("ros2_subscriber: servo_cf stopped -> external_force_n back to zero")

    # Refused: another frame, a NaN force. Neither reaches the session.
    for bad, frame in [([0.5, 0.0, 0.0], "base_link"), ([math.nan, 0.0, 0.0], "world")]:
        publish_for(writer, wrench(bad, frame), 1.0)
        state = http_json(f"{http}/api/state")
        check(state["external_force_n"] == [0.0, 0.0, 0.0],
              f"a wrench {bad} in frame {frame!r} reached the session: external_force_n {state['external_force_n']}")
    print("ros2_subscriber: servo_cf in frame 'base_link' and with a NaN force refused")


if __name__ == "__main__":
    main()
