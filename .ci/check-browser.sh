#!/usr/bin/env bash
# Headless-browser check of the built-in page, run from .ci/run after the tests.
#
# Starts `voxhap serve` (simulated arm, built-in scene) on a free loopback port, then with headless Chromium:
#   1. dumps the DOM and checks the page received states (the tick counter it writes is > 0), connected its
#      WebSocket and built the mode controls from the scene, and that its "Device proxy" line says there is no
#      local model (.ci/device_proxy_check.py);
#   2. takes two screenshots a couple of seconds apart and checks both are real 1280x900 pictures with a
#      greyscale slice drawn in the views, and that the views changed between them (.ci/screenshot_check.py;
#      each screenshot is taken again until it shows that, or 120 s pass);
#   3. if node and npm are there, installs playwright-core into a temporary directory (never the repo) and
#      runs .ci/browser-e2e.js: drag the virtual hand in a view, set the stiffness, scale a mode; then at
#      390x844 (a phone): no horizontal overflow, the mode on/off switch, peak strength 0 and back keeping the
#      breakpoints, typed breakpoints, slices within 200 KiB/s, the status line and the measured stream rate;
#      then a wrong token: the page says so and a drag sends no request; then, with a second serve on
#      `voxhap mock-device --local-model`, that the "Device proxy" line shows the device's own proxy
#      (.ci/device_proxy_check.py live, .ci/device-proxy-page.js).
# Skips (exit 0) with a message when no Chromium, node or npm can be found or installed, except in CI (CI set),
# where that fails. Exit 1 on a failed check.
#
# Environment: VOXHAP_BIN (use this binary), KEEP_SCREENSHOTS=DIR (copy the PNGs there),
# SKIP_E2E=1 (skip step 3).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-browser
. .ci/lib.sh
say() { echo "$name: $*"; }

need_chromium "the page was not checked"
command -v python3 >/dev/null 2>&1 || missing "python3 is needed to check the screenshots"
say "using $CHROMIUM ($("$CHROMIUM" --version 2>/dev/null | head -1))"

# ---- the server binary
find_voxhap check-browser
make_work_dir check-browser

TOKEN=TESTTOKEN
start_serve --http 127.0.0.1:0 --token "$TOKEN" --duration 900
serve_listening http
BASE=$LISTENING

server_log() { echo "--- server output:" >&2; serve_output | tail -n 30 >&2 || true; }

# Wait (up to 30 s) for /api/state to answer with a state.
if ! python3 - "$BASE" <<'EOF'
import json, sys, time, urllib.request
base = sys.argv[1]
end = time.time() + 30
while time.time() < end:
    try:
        with urllib.request.urlopen(base + "/api/state", timeout=2) as r:
            if json.load(r).get("tick", 0) > 0:
                sys.exit(0)
    except Exception:
        pass
    time.sleep(0.2)
sys.exit(1)
EOF
then
  server_log
  fail "the server did not answer GET /api/state with a state within 30 s"
fi
say "server is up"

chrome() {
  timeout 90 "$CHROMIUM" --headless=new --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
    --no-first-run --user-data-dir="$WORK/profile" --window-size=1280,900 "$@" 2>>"$WORK/chromium.log"
}

URL="$BASE/?token=$TOKEN"

# ---- 1. DOM: the page wrote a tick number, its WebSocket is live, the mode controls were built. Dumped again
# (with a longer virtual-time budget) until it shows that, or 120 s pass: on a loaded machine the first state
# can arrive after a fixed budget ends.
cat >"$WORK/dom_check.py" <<'EOF'
import re, sys
dom = open(sys.argv[1], encoding="utf-8", errors="replace").read()
def fail(msg):
    print("check-browser: FAIL: " + msg, file=sys.stderr)
    sys.exit(1)
tag = re.search(r'<output[^>]*\bid="st-tick"[^>]*>([^<]*)<', dom)
if not tag:
    fail("the dumped DOM has no #st-tick element (did the page load?)")
attr = re.search(r'data-tick="(\d+)"', tag.group(0))
tick = int(attr.group(1)) if attr else 0
if tick <= 0:
    fail("the page shows no tick > 0 (#st-tick: %r): no state reached it" % tag.group(1))
conn = re.search(r'<p[^>]*\bid="conn"[^>]*>', dom)
if not conn or "conn-up" not in conn.group(0):
    text = re.search(r'id="conn-text"[^>]*>([^<]*)<', dom)
    fail("the WebSocket is not live: %s" % (text.group(1) if text else "no #conn element"))
modes = len(re.findall(r'<fieldset[^>]*class="mode"', dom))
if modes < 1:
    fail("no mode controls were built from the scene")
print("check-browser: ok: the page shows tick %d, a live WebSocket and %d mode control groups" % (tick, modes))
EOF
dom_budget=4000
dom_deadline=$((SECONDS + 120))
until chrome --virtual-time-budget=$dom_budget --dump-dom "$URL" >"$WORK/dom.html" && python3 "$WORK/dom_check.py" "$WORK/dom.html"; do
  if [ "$SECONDS" -ge "$dom_deadline" ]; then
    tail -n 20 "$WORK/chromium.log" >&2 || true
    server_log
    fail "the dumped DOM did not show a live page within 120 s (see above)"
  fi
  say "the DOM does not show it yet (virtual-time budget $dom_budget ms); dumping again"
  dom_budget=$((dom_budget * 2 > 24000 ? 24000 : dom_budget * 2))
  sleep 1
done

python3 .ci/device_proxy_check.py none "$WORK/dom.html" || fail "the Device proxy line (see above)"

# ---- 2. Two screenshots a couple of seconds apart, each taken again (with a longer virtual-time budget) until
# it shows what is checked, or 120 s pass: on a loaded machine the first state and the slice can arrive after
# a fixed budget ends, and a screenshot taken before the slice is drawn proves nothing about the page.
shoot_until() { # FILE [PREVIOUS]: a screenshot with a greyscale slice (and, given PREVIOUS, changed views)
  local out=$1 previous=${2:-} budget=3000 attempt=0 rc
  local deadline=$((SECONDS + 120))
  while :; do
    attempt=$((attempt + 1))
    rm -f "$out"
    if chrome --virtual-time-budget=$budget --screenshot="$out" "$URL" >/dev/null && [ -s "$out" ]; then
      python3 .ci/screenshot_check.py "$out" $previous && return 0
      rc=$?
      [ "$rc" = 3 ] || { server_log; exit 1; }
    else
      say "chromium --screenshot failed or timed out (last lines of its log:)"
      tail -n 5 "$WORK/chromium.log" || true
    fi
    if [ "$SECONDS" -ge "$deadline" ]; then
      server_log
      fail "$(basename "$out"): not there after $attempt screenshots in 120 s (see above)"
    fi
    say "$(basename "$out"): not yet (screenshot $attempt, virtual-time budget $budget ms); taking another"
    budget=$((budget * 2 > 24000 ? 24000 : budget * 2))
    sleep 1
  done
}
shoot_until "$WORK/shot1.png"
sleep 2
shoot_until "$WORK/shot2.png" "$WORK/shot1.png"
if [ -n "${KEEP_SCREENSHOTS:-}" ]; then
  mkdir -p "$KEEP_SCREENSHOTS"
  cp "$WORK/shot1.png" "$WORK/shot2.png" "$KEEP_SCREENSHOTS/"
  say "screenshots kept in $KEEP_SCREENSHOTS"
fi

# ---- 3. Drag the virtual hand and use the controls (playwright-core).
if [ "${SKIP_E2E:-}" = "1" ]; then
  say "SKIP: browser interaction test (SKIP_E2E=1)"
else
  need_node_npm "the browser interaction test was not run"
  npm_into "$WORK/npm" "browser interaction test: npm install of playwright-core" install --no-save playwright-core
  NODE_PATH="$WORK/npm/node_modules" timeout 600 node .ci/browser-e2e.js "$BASE" "$TOKEN" "$CHROMIUM" \
    || { server_log; fail "the browser interaction test failed"; }
  NODE_PATH="$WORK/npm/node_modules" python3 .ci/device_proxy_check.py live "$VOXHAP" "$CHROMIUM" "$WORK" \
    || fail "the Device proxy line with a local-model device (see above)"
fi

kill -0 "$SERVER_PID" 2>/dev/null || { server_log; fail "the server exited during the checks"; }
say "all checks passed"
