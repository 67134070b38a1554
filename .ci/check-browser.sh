#!/usr/bin/env bash
# Headless-browser check of the built-in page, run from .ci/run after the tests.
#
# Starts `voxhap serve` (simulated arm, built-in scene) on a free loopback port, then with headless Chromium:
#   1. dumps the DOM and checks the page received states (the tick counter it writes is > 0), connected its
#      WebSocket and built the mode controls from the scene;
#   2. takes two screenshots a couple of seconds apart and checks both are real 1280x900 pictures with a
#      greyscale slice drawn in the views, and that the views changed between them;
#   3. if node and npm are there, installs playwright-core into a temporary directory (never the repo) and
#      runs .ci/browser-e2e.js: drag the virtual hand in a view, set the stiffness, scale a mode; then at
#      390x844 (a phone): no horizontal overflow, the mode on/off switch, peak strength 0 and back keeping the
#      breakpoints, typed breakpoints, slices within 200 KiB/s, the status line and the measured stream rate;
#      then a wrong token: the page says so and a drag sends no request.
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

# ---- Chromium
find_chromium() {
  local name
  for name in chromium chromium-browser; do
    if command -v "$name" >/dev/null 2>&1; then
      command -v "$name"
      return 0
    fi
  done
  return 1
}
CHROMIUM=$(find_chromium || true)
if [ -z "$CHROMIUM" ] && [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  say "chromium not found; trying apt-get install -y chromium"
  export DEBIAN_FRONTEND=noninteractive
  if ! timeout 300 apt-get install -y -qq chromium >/tmp/check-browser-apt.log 2>&1; then
    timeout 120 apt-get update -qq >>/tmp/check-browser-apt.log 2>&1 || true
    timeout 300 apt-get install -y -qq chromium >>/tmp/check-browser-apt.log 2>&1 || true
  fi
  CHROMIUM=$(find_chromium || true)
fi
if [ -z "$CHROMIUM" ]; then
  missing "no chromium or chromium-browser found (and it could not be installed); the page was not checked"
fi
command -v python3 >/dev/null 2>&1 || missing "python3 is needed to check the screenshots"
say "using $CHROMIUM ($("$CHROMIUM" --version 2>/dev/null | head -1))"

# ---- the server binary
find_voxhap check-browser
make_work_dir check-browser

PORT=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
TOKEN=TESTTOKEN
BASE="http://127.0.0.1:$PORT"
say "starting $VOXHAP serve on $BASE"
"$VOXHAP" serve --http "127.0.0.1:$PORT" --token "$TOKEN" --duration 60 >"$WORK/server.log" 2>&1 &
SERVER_PID=$!

server_log() { echo "--- server output:" >&2; tail -n 30 "$WORK/server.log" >&2 || true; }

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
  timeout 40 "$CHROMIUM" --headless=new --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
    --no-first-run --user-data-dir="$WORK/profile" --window-size=1280,900 "$@" 2>>"$WORK/chromium.log"
}

URL="$BASE/?token=$TOKEN"

# ---- 1. DOM: the page wrote a tick number, its WebSocket is live, the mode controls were built.
chrome --virtual-time-budget=4000 --dump-dom "$URL" >"$WORK/dom.html" || { tail -n 20 "$WORK/chromium.log" >&2; fail "chromium --dump-dom failed"; }
python3 - "$WORK/dom.html" <<'EOF' || { server_log; exit 1; }
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

# ---- 2. Two screenshots a couple of seconds apart.
chrome --virtual-time-budget=3000 --screenshot="$WORK/shot1.png" "$URL" >/dev/null || fail "chromium --screenshot failed"
sleep 2
chrome --virtual-time-budget=3000 --screenshot="$WORK/shot2.png" "$URL" >/dev/null || fail "chromium --screenshot failed"
if [ -n "${KEEP_SCREENSHOTS:-}" ]; then
  mkdir -p "$KEEP_SCREENSHOTS"
  cp "$WORK/shot1.png" "$WORK/shot2.png" "$KEEP_SCREENSHOTS/"
  say "screenshots kept in $KEEP_SCREENSHOTS"
fi
python3 - "$WORK/shot1.png" "$WORK/shot2.png" <<'EOF' || { server_log; exit 1; }
import struct, sys, zlib

def fail(msg):
    print("check-browser: FAIL: " + msg, file=sys.stderr)
    sys.exit(1)

def decode(path):
    """Width, height and rows of RGB(A) bytes of an 8-bit truecolour PNG (standard library only)."""
    data = open(path, "rb").read()
    if len(data) < 10000 or data[:8] != b"\x89PNG\r\n\x1a\n":
        fail("%s is not a plausible PNG (%d bytes)" % (path, len(data)))
    pos, idat, head = 8, [], None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            head = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = head
    if depth != 8 or colour not in (2, 6) or interlace:
        fail("%s: unexpected PNG format (depth %d, colour type %d)" % (path, depth, colour))
    bpp = 3 if colour == 2 else 4
    raw = zlib.decompress(b"".join(idat))
    stride = width * bpp
    rows, prev = [], bytearray(stride)
    for y in range(height):
        f = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        if f == 1:
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 255
        elif f == 2:
            line = bytearray((a + b) & 255 for a, b in zip(line, prev))
        elif f == 3:
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 255
        elif f == 4:
            for i in range(stride):
                a = line[i - bpp] if i >= bpp else 0
                b = prev[i]
                c = prev[i - bpp] if i >= bpp else 0
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(line)
        prev = line
    return width, height, bpp, rows

shots = [decode(p) for p in sys.argv[1:3]]
for (w, h, bpp, rows), path in zip(shots, sys.argv[1:3]):
    if (w, h) != (1280, 900):
        fail("%s is %dx%d, expected 1280x900" % (path, w, h))
    colours = set()
    grey = 0
    for y in range(0, h, 2):
        row = rows[y]
        for x in range(0, w * bpp, 2 * bpp):
            px = bytes(row[x:x + 3])
            colours.add(px)
            if px[0] == px[1] == px[2] and px[0] >= 40 and y > 80 and x < 905 * bpp:
                grey += 1
    if len(colours) < 50:
        fail("%s looks blank (%d colours)" % (path, len(colours)))
    if grey < 2000:
        fail("%s: no greyscale slice in the views (%d grey pixels sampled)" % (path, grey))
    print("check-browser: ok: %s: %dx%d, %d colours, %d greyscale slice pixels sampled" % (path.rsplit("/", 1)[1], w, h, len(colours), grey))

# The views (left part of the page, below the header) must have changed between the two screenshots.
(_, _, bpp, a), (_, _, _, b) = shots
changed = sum(1 for y in range(90, 520) for x in range(0, 905 * bpp, bpp) if a[y][x:x + 3] != b[y][x:x + 3])
if changed < 50:
    fail("the views did not change between the two screenshots (%d pixels differ)" % changed)
print("check-browser: ok: %d pixels of the views changed between the screenshots" % changed)
EOF

# ---- 3. Drag the virtual hand and use the controls (playwright-core).
if [ "${SKIP_E2E:-}" = "1" ]; then
  say "SKIP: browser interaction test (SKIP_E2E=1)"
elif ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  missing "browser interaction test: node or npm not found"
else
  mkdir -p "$WORK/npm"
  if (cd "$WORK/npm" && timeout 120 npm install --silent --no-audit --no-fund --no-save playwright-core >"$WORK/npm.log" 2>&1); then
    NODE_PATH="$WORK/npm/node_modules" timeout 150 node .ci/browser-e2e.js "$BASE" "$TOKEN" "$CHROMIUM" \
      || { server_log; fail "the browser interaction test failed"; }
  else
    missing "browser interaction test: npm could not install playwright-core: $(tail -n 1 "$WORK/npm.log")"
  fi
fi

kill -0 "$SERVER_PID" 2>/dev/null || { server_log; fail "the server exited during the checks"; }
say "all checks passed"
