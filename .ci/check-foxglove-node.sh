#!/usr/bin/env bash
# Checks voxhap's Foxglove live view with an independent client: the npm packages @foxglove/ws-protocol, ws
# and protobufjs (installed into a temporary directory, never the repository) subscribe on a running
# `voxhap serve` and must receive at least N messages on /voxhap/setpoint_cf, the volume's mesh and bounding box
# on /voxhap/volume, the three slices, and the frames `volume` and `volume_view` (the camera framing the layout follows)
# on /voxhap/volume_frame; the shipped layout contrib/foxglove/voxhap-layout.json must refer
# only to topics the server advertises (.ci/foxglove-subscribe.mjs).
#
# Skips (exit 0, with a message) when node or npm is missing or the npm install fails (offline), except in CI
# (CI set), where that fails. Fails (exit 1) with a message saying what went wrong otherwise. Takes well under two minutes once voxhap is built.
#
# Environment: VOXHAP_FOXGLOVE_MESSAGES (default 60), VOXHAP_FOXGLOVE_TIMEOUT_MS (default 15000), VOXHAP_BIN (a
# voxhap binary to use instead of building target/release/voxhap, e.g. the one `cargo test --release` built;
# a release build from scratch takes minutes).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-foxglove-node
. .ci/lib.sh

need_node_npm

make_work_dir voxhap-foxglove-node
trap 'exit 130' INT TERM

echo "$name: installing @foxglove/ws-protocol, ws and protobufjs into $WORK (node $(node --version), npm $(npm --version 2>/dev/null))"
npm_into "$WORK" "npm install of @foxglove/ws-protocol, ws and protobufjs" install --no-save @foxglove/ws-protocol ws protobufjs
echo "$name: installed $(npm_versions "$WORK" @foxglove/ws-protocol ws protobufjs)"

find_voxhap "$name"
# Long enough for a loaded CI machine; the exit trap stops it as soon as the client is done.
start_serve --foxglove 127.0.0.1:0 --duration 600 --no-http
serve_listening foxglove
url=$LISTENING
echo "$name: voxhap serve is listening on $url"

cp .ci/foxglove-subscribe.mjs "$WORK/"
if ! node "$WORK/foxglove-subscribe.mjs" "$url" contrib/foxglove/voxhap-layout.json \
  "${VOXHAP_FOXGLOVE_MESSAGES:-60}" "${VOXHAP_FOXGLOVE_TIMEOUT_MS:-120000}"; then
  sed "s/^/$name: serve: /" "$WORK/serve.err" >&2
  fail "the Node client's checks failed (see above)"
fi

echo "$name: passed"
