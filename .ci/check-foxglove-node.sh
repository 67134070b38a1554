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

command -v node >/dev/null 2>&1 || missing "node is not installed"
command -v npm >/dev/null 2>&1 || missing "npm is not installed"

make_work_dir voxhap-foxglove-node
trap 'exit 130' INT TERM

echo "$name: installing @foxglove/ws-protocol, ws and protobufjs into $WORK (node $(node --version), npm $(npm --version 2>/dev/null))"
if ! timeout 120 npm install --prefix "$WORK" --no-audit --no-fund --no-save --loglevel=error \
  @foxglove/ws-protocol ws protobufjs >"$WORK/npm.log" 2>&1; then
  tail -n 5 "$WORK/npm.log" | sed "s/^/$name: npm: /"
  missing "npm install of @foxglove/ws-protocol, ws and protobufjs failed (offline or no registry access)"
fi
versions=$(cd "$WORK" && node -e 'for (const p of ["@foxglove/ws-protocol", "ws", "protobufjs"]) process.stdout.write(`${p}@${require(`${p}/package.json`).version} `)')
echo "$name: installed $versions"

find_voxhap "$name"
# Long enough for a loaded CI machine; stopped below as soon as the client is done.
serve_args=(serve --foxglove 127.0.0.1:0 --duration 600 --no-http)
echo "$name: starting $VOXHAP ${serve_args[*]}"
"$VOXHAP" "${serve_args[@]}" >"$WORK/serve.out" 2>"$WORK/serve.err" &
SERVER_PID=$!

url=""
for _ in $(seq 1 600); do
  line=$(grep -m1 '^foxglove: listening on ws://' "$WORK/serve.out" || true)
  if [ -n "$line" ]; then
    url=${line#foxglove: listening on }
    break
  fi
  if ! kill -0 "$SERVER_PID" 2>/dev/null; then
    cat "$WORK/serve.out" "$WORK/serve.err" | sed "s/^/$name: serve: /" >&2
    fail "voxhap serve exited before its Foxglove server was listening"
  fi
  sleep 0.1
done
[ -n "$url" ] || fail "voxhap serve did not print 'foxglove: listening on ws://...' within 60 s"
echo "$name: voxhap serve is listening on $url"

cp .ci/foxglove-subscribe.mjs "$WORK/"
if ! node "$WORK/foxglove-subscribe.mjs" "$url" contrib/foxglove/voxhap-layout.json \
  "${VOXHAP_FOXGLOVE_MESSAGES:-60}" "${VOXHAP_FOXGLOVE_TIMEOUT_MS:-120000}"; then
  sed "s/^/$name: serve: /" "$WORK/serve.err" >&2
  fail "the Node client's checks failed (see above)"
fi

kill "$SERVER_PID" 2>/dev/null || true
wait "$SERVER_PID" 2>/dev/null || true
SERVER_PID=""
echo "$name: passed"
