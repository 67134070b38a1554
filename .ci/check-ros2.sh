#!/usr/bin/env bash
# Checks `voxhap serve --ros2` with an independent DDS: Eclipse Cyclone DDS's Python package (PyPI
# `cyclonedds`, which ships its own libddsc) runs .ci/ros2_subscriber.py: the five CRTK writers under their
# ROS 2 DDS names, types and QoS, and their values against /api/state of the same server; and, serve running
# with --external-force, wrenches it publishes on /voxhap/servo_cf against /api/state's external_force_n.
#
# Nothing leaves this machine: voxhap runs with --ros2-localhost-only (RustDDS on the loopback interface
# only), Cyclone with CYCLONEDDS_URI below (loopback interface, no multicast, unicast discovery to
# 127.0.0.1), on a domain id of its own.
#
# Installs cyclonedds with pip. In CI (CI=true) a failed install fails the check; elsewhere it skips with a
# message. Takes about 30 s once voxhap is built.
#
# Environment: VOXHAP_BIN (a voxhap binary to use instead of building target/release/voxhap),
# VOXHAP_ROS2_DOMAIN (default 150 + this shell's pid modulo 50).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-ros2
. .ci/lib.sh

need_python "cyclonedds" cyclonedds
echo "$name: $(python3 -c 'from importlib.metadata import version as v; print("cyclonedds", v("cyclonedds"))')"

make_work_dir voxhap-ros2
trap 'exit 130' INT TERM
find_voxhap "$name"

token=ros2-check-token-0123
domain=${VOXHAP_ROS2_DOMAIN:-$((150 + $$ % 50))}
export CYCLONEDDS_URI='<CycloneDDS><Domain Id="any"><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
start_serve --ros2 --ros2-domain "$domain" --ros2-localhost-only --http 127.0.0.1:0 --token "$token" \
  --no-foxglove --duration 150 --external-force
serve_listening http
http=$LISTENING
serve_waits_for '^ros2: publishing' "'ros2: publishing ...'"
echo "$name: voxhap serve: $(grep '^ros2: publishing' "$WORK/serve.out"); HTTP on $http"
grep -q '^ros2: subscribed to /voxhap/servo_cf (geometry_msgs/msg/WrenchStamped, best effort)' "$WORK/serve.out" \
  && grep -q '^external force: accepted (set_external_force, /voxhap/servo_cf), added before the safety pipeline, zero 0.1 s after the last one$' "$WORK/serve.out" \
  || fail "voxhap serve --ros2 --external-force did not print its external force lines: $(cat "$WORK/serve.out")"

if ! timeout 140 python3 .ci/ros2_subscriber.py "$domain" "$http" "$token"; then
  sed "s/^/$name: serve: /" "$WORK/serve.err" >&2
  fail "the Cyclone DDS subscriber's checks failed (see above)"
fi
# serve's own account of the servo_cf wrenches, printed when it stops.
kill -TERM "$SERVER_PID"
wait "$SERVER_PID" || fail "voxhap serve failed when stopped: $(cat "$WORK/serve.err")"
taken=$(sed -n 's/^ros2: \/voxhap\/servo_cf: \([0-9]*\) wrenches taken, \([0-9]*\) refused.*/\1 \2/p' "$WORK/serve.out")
echo "$name: serve: ${taken:-nothing} (taken refused)"
read -r n_taken n_refused <<<"${taken:-0 0}"
[ "$n_taken" -gt 0 ] && [ "$n_refused" -gt 0 ] \
  || fail "serve did not report servo_cf wrenches both taken and refused: $(grep servo_cf "$WORK/serve.out" "$WORK/serve.err")"
grep -q "wrench refused: frame_id \"base_link\"" "$WORK/serve.err" \
  || fail "serve did not say why the base_link wrench was refused: $(cat "$WORK/serve.err")"
echo "$name: passed"
