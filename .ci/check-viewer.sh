#!/usr/bin/env bash
# voxhap's recordings and live view in a real Foxglove viewer: Foxglove Studio 1.48 (the open-source line Lichtblick
# forked from), mounted from the prebuilt web bundle the npm package @foxglove/studio-base ships (its "browser"
# file, with React 17 from npm; .ci/viewer/index.html and app.js mount its App as Foxglove's own web app does), in
# headless Chromium driven by playwright-core. Versions are pinned by .ci/viewer/package-lock.json (`npm ci` into a
# temporary directory, never the repository). .ci/viewer/check.mjs opens, each with the shipped layout
# contrib/foxglove/voxhap-layout.json:
#   1. a `voxhap sim --out` recording, served over HTTP on 127.0.0.1 and opened at its last message;
#   2. the live view of a running `voxhap serve --foxglove` (the Foxglove WebSocket);
# and fails on any problem the viewer reports (the data source's Problems list, an error in a panel's settings
# tree, a notification, a crashed panel, an error the app reports or logs, a page error, a request to any host
# but 127.0.0.1) or any panel of the layout left empty (3D: coloured pixels drawn; Plot: a value in the legend
# for every series and lines in their colours; StateTransitions: coloured bars; RawMessages: a message shown).
# It prints what it measured per panel and keeps the screenshots when KEEP_SCREENSHOTS=DIR is set.
#
# Skips (exit 0, with a message) when Chromium, node or npm is missing or the npm install fails, except in CI
# (CI set), where that fails; in CI as root, apt-get installs Chromium when missing.
# Environment: VOXHAP_BIN (a voxhap binary instead of building target/release/voxhap), KEEP_SCREENSHOTS=DIR.
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-viewer
. .ci/lib.sh
say() { echo "$name: $*"; }
started=$(date +%s)

need_chromium
need_node_npm

make_work_dir voxhap-viewer
trap 'exit 130' INT TERM

say "npm ci of .ci/viewer/package-lock.json into $WORK (node $(node --version), $("$CHROMIUM" --version 2>/dev/null | head -1))"
cp .ci/viewer/package.json .ci/viewer/package-lock.json "$WORK/"
npm_into "$WORK" "npm ci of .ci/viewer (@foxglove/studio-base, react, react-dom, playwright-core)" ci
say "installed $(npm_versions "$WORK" @foxglove/studio-base react react-dom playwright-core)in $(($(date +%s) - started)) s"

find_voxhap "$name"
"$VOXHAP" sim sims/sphere_surface.toml --out "$WORK/sim.mcap" --duration 2 >"$WORK/sim.out" 2>&1 \
  || { cat "$WORK/sim.out" >&2; fail "voxhap sim --out failed"; }

start_serve --foxglove 127.0.0.1:0 --duration 900 --no-http
serve_listening foxglove
url=$LISTENING

mkdir -p "$WORK/shots"
status=0
timeout 600 node .ci/viewer/check.mjs "$WORK" .ci/viewer contrib/foxglove/voxhap-layout.json "$CHROMIUM" "$WORK/shots" \
  "recording:$WORK/sim.mcap" "live:$url" || status=$?
if [ -n "${KEEP_SCREENSHOTS:-}" ]; then
  mkdir -p "$KEEP_SCREENSHOTS"
  cp "$WORK"/shots/*.png "$KEEP_SCREENSHOTS/" 2>/dev/null || true
fi
say "took $(($(date +%s) - started)) s"
if [ "$status" != 0 ]; then
  sed "s/^/$name: serve: /" "$WORK/serve.err" | tail -n 20 >&2
  fail "Foxglove Studio reported a problem or left a panel empty (see above)"
fi
say "passed"
