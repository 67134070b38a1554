#!/usr/bin/env bash
# The reference firmware in C (firmware/), proven three ways against the real host:
#   1. `make -C firmware test`: the library's unit tests (host gcc, -std=c99 -pedantic -Werror) against
#      protocol/vectors and SPEC.md (and the Arduino sketch compiled as C++ against a stub Arduino.h);
#   2. the host port (firmware/ports/host): the library in a process behind a pseudo-terminal with a simulated arm;
#      `voxhap serve --device serial:PTY` drives it through engage, rendering, garbage in both directions, a
#      stalled host (SIGSTOP: the firmware's watchdog must trip), a board reset (a new pseudo-terminal: the host
#      must reconnect), a latching fault, and a stop; firmware/tools/check_log.py checks the firmware's own log;
#   3. the Cortex-M4 image (firmware/ports/mps2-an386) booted in qemu-system-arm with its UART on a pseudo-terminal:
#      serve engages it, renders the built-in scene for several seconds and stops; the log the firmware writes on
#      its second UART is checked the same way.
#
# In CI (CI=true) the tools are installed from Debian (make, gcc, g++, gcc-arm-none-eabi, libnewlib-arm-none-eabi,
# qemu-system-arm) and a failed install fails the check; elsewhere a missing tool skips visibly.
# Environment: VOXHAP_BIN (a voxhap binary instead of building target/release/voxhap), FIRMWARE_SKIP_QEMU=1
# (only parts 1 and 2, for a quick run by hand; never set in CI).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-firmware
. .ci/lib.sh

need_apt() {
  local missing_pkgs=()
  for tool_pkg in "$@"; do
    command -v "${tool_pkg%%:*}" >/dev/null 2>&1 || missing_pkgs+=("${tool_pkg#*:}")
  done
  [ ${#missing_pkgs[@]} -eq 0 ] && return 0
  if in_ci && command -v apt-get >/dev/null 2>&1; then
    echo "$name: installing ${missing_pkgs[*]} with apt-get"
    local sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    { $sudo apt-get update -qq && $sudo apt-get install -y -qq "${missing_pkgs[@]}" >/dev/null; } \
      || fail "apt-get install ${missing_pkgs[*]} failed"
  else
    missing "${missing_pkgs[*]} not installed"
  fi
}

need_apt make:make cc:gcc c++:g++ python3:python3
make_work_dir voxhap-firmware
trap 'exit 130' INT TERM
started=$(date +%s)

# ------------------------------------------------------------------------------------------ 1. unit tests
make -s -C firmware test || fail "make -C firmware test failed"
python3 firmware/tools/test_check_log.py || fail "firmware/tools/check_log.py misjudged a hand-written log"
make -s -C firmware host || fail "make -C firmware host failed"
make -s -C firmware sketch-check || fail "the Arduino sketch no longer compiles against the library (make -C firmware sketch-check)"
find_voxhap "$name"

PATIENCE=${FIRMWARE_PATIENCE:-120}  # seconds any one wait may take on a saturated machine; a quiet one needs ~2
DEVICE_PID=""
cleanup_device() {
  if [ -n "$DEVICE_PID" ] && kill -0 "$DEVICE_PID" 2>/dev/null; then
    kill "$DEVICE_PID" 2>/dev/null || true
    wait "$DEVICE_PID" 2>/dev/null || true
  fi
  stop_server_and_clean_up
}
trap cleanup_device EXIT

# Complete lines of log $1 so far (0 while it does not exist). A writer appends while the checks read: the last
# line may be only part of one (the host port's flush, QEMU's UART1 a byte at a time), and a part of an `A` line
# ("A 2652") has no zero fields, so it would read as a force. Every wait and test below looks only at these lines.
lines() { { wc -l <"$1"; } 2>/dev/null || echo 0; }
# The number of the first complete line of $1 after line $2 that matches awk condition $3; nothing when none does.
first_match() {
  local log=$1 from=$2 cond=$3 complete
  complete=$(lines "$log")
  awk -v from="$from" -v upto="$complete" "NR > upto { exit } NR > from && ($cond) { print NR; exit }" "$log" \
    2>/dev/null || true
}
# Waits until a complete line of $1 after line $2 matches awk condition $3, at most PATIENCE seconds of wall time,
# and sets MATCHED to its number; fails naming $4 (or when serve exits meanwhile).
wait_log() {
  local log=$1 from=$2 cond=$3 what=$4 deadline=$((SECONDS + PATIENCE))
  while MATCHED=$(first_match "$log" "$from" "$cond") && [ -z "$MATCHED" ]; do
    if [ -n "$SERVER_PID" ] && ! kill -0 "$SERVER_PID" 2>/dev/null; then
      sed "s/^/$name: serve: /" "$WORK/serve.out" >&2 || true
      fail "voxhap serve exited while waiting for $what"
    fi
    if [ "$SECONDS" -ge "$deadline" ]; then
      sed "s/^/$name: serve: /" "$WORK/serve.out" >&2 || true
      fail "no $what within $PATIENCE s"
    fi
    sleep 0.1
  done
}
# awk conditions on log lines (firmware/ports/common/fwlog.h)
NONZERO_FORCE='$1 == "A" && !($3 ~ /^[08]0000000$/ && $4 ~ /^[08]0000000$/ && $5 ~ /^[08]0000000$/)'
WATCHDOG_FAULT='$1 == "T" && $3 == "84" && $4 == "0"'

start_serve() {  # PORT, extra flags...
  local port=$1
  shift
  "$VOXHAP" serve --no-http --no-foxglove --rt off --device "serial:$port" "$@" >"$WORK/serve.out" 2>&1 &
  SERVER_PID=$!
}
stop_serve() {
  kill -TERM "$SERVER_PID"
  local waited=0
  while kill -0 "$SERVER_PID" 2>/dev/null; do
    [ "$waited" -ge 300 ] && fail "voxhap serve did not stop within 30 s of SIGTERM"
    sleep 0.1
    waited=$((waited + 1))
  done
  wait "$SERVER_PID" || fail "voxhap serve exited with status $? after SIGTERM: $(tail -5 "$WORK/serve.out")"
  SERVER_PID=""
}
# stop_serve_linked LOG COND WHAT SERVE-ARGS...: stops serve just after a complete line of LOG from now on matches
# awk condition COND (the device heard from serve: WHAT), and sets STOP_MARK to the log's length just before that
# stop. serve's stop sends zero, then Disable, on the link it has open; a loaded machine makes serve drop and
# rebuild its link at any moment, and a stop while it has none has nothing to send. So when serve's summary says it
# had no device at its stop, it is started again (start_serve SERVE-ARGS) and stopped again, 5 stops at most.
stop_serve_linked() {
  local log=$1 cond=$2 what=$3 attempt
  shift 3
  for attempt in 1 2 3 4 5; do
    if [ -z "$SERVER_PID" ]; then
      mv "$WORK/serve.out" "$WORK/serve-stop$((attempt - 1)).out"
      start_serve "$@"
    fi
    wait_log "$log" "$(lines "$log")" "$cond" "$what"
    STOP_MARK=$(lines "$log")
    stop_serve
    grep -q '^safety: output disconnected ' "$WORK/serve.out" || return 0
    echo "$name: serve had no link to the device at its stop (attempt $attempt); starting it again"
  done
  fail "serve had no link to the device at any of its 5 stops"
}

# ------------------------------------------------------------------------------------------ 2. host port
host_started=$(date +%s)
LOG=$WORK/host.log
firmware/build/voxhap-fw-host --link "$WORK/dev" --log "$LOG" --garbage-ms 250 >"$WORK/device.out" 2>&1 &
DEVICE_PID=$!
for _ in $(seq 1 100); do [ -L "$WORK/dev" ] && break; sleep 0.05; done
[ -L "$WORK/dev" ] || fail "the host port did not come up: $(cat "$WORK/device.out")"
start_serve "$WORK/dev"
echo "$name: host port: serve on $(readlink "$WORK/dev") (built-in scene), garbage both ways every 250 ms"

wait_log "$LOG" 0 "$NONZERO_FORCE" "force on the host port (engage)"
echo "$name: host port: engaged (log line $MATCHED)"

# A stalled host: SIGSTOP serve for 0.3 s while the device is Enabled; its watchdog must trip (zero force, Fault 0),
# and the host, resumed, must enable it again. If the host was not enabling it at that moment (a loaded machine
# makes it start over), try again.
tripped=0
for attempt in 1 2 3 4 5 6 7 8 9 10; do
  mark=$(lines "$LOG")
  wait_log "$LOG" "$mark" "$NONZERO_FORCE" "force before stall $attempt"
  mark=$(lines "$LOG")
  kill -STOP "$SERVER_PID"
  sleep 0.3
  kill -CONT "$SERVER_PID"
  sleep 0.2
  trip=$(first_match "$LOG" "$mark" "$WATCHDOG_FAULT")
  if [ -n "$trip" ]; then
    tripped=1
    break
  fi
done
[ "$tripped" = 1 ] || fail "the firmware's watchdog never tripped over 10 stalls of the host"
# Force again after the trip itself (a force applied before the trip, during the stall, does not count): the host
# has enabled the device again before the board reset below.
wait_log "$LOG" "$trip" "$NONZERO_FORCE" "force again after the watchdog trip"
echo "$name: host port: stalled host caught by the firmware watchdog (log line $trip), then re-enabled (line $MATCHED)"

# A board reset: the port closes its pseudo-terminal, restarts the firmware and opens a new one.
mark=$(lines "$LOG")
kill -USR1 "$DEVICE_PID"
wait_log "$LOG" "$mark" '$1 == "X" && $3 == "reset"' "reset of the host port"
reset_line=$MATCHED
wait_log "$LOG" "$reset_line" "$NONZERO_FORCE" "force after the reset (the host reconnects)"
echo "$name: host port: reset (log line $reset_line), reconnected and engaged again (line $MATCHED)"

# A latching fault (over-temperature): zero at once, and the host never clears it by itself.
mark=$(lines "$LOG")
kill -USR2 "$DEVICE_PID"
wait_log "$LOG" "$mark" '$1 == "T" && $3 == "84" && $4 == "2"' "Fault(OVER_TEMPERATURE)"
sleep 1
# A stop while serve talks to the device (zero SetForces: the latched fault keeps it off, also for a serve started
# again); the Disable must come after the stop itself (the one serve sent on the fault does not count).
stop_serve_linked "$LOG" '$1 == "S"' "a SetForce from serve before its stop" "$WORK/dev"
wait_log "$LOG" "$STOP_MARK" '$1 == "M" && $3 == "03"' "Disable after serve's stop"
kill -TERM "$DEVICE_PID"
wait "$DEVICE_PID" || fail "the host port exited with status $?"
DEVICE_PID=""
sed "s/^/$name: host port: /" "$WORK/device.out"
if ! python3 firmware/tools/check_log.py "$LOG" --max-force 5 --max-rise 1000 \
  --expect engaged,garbage,watchdog,reconnect,fault,stopped; then
  # The order of events (the log goes with the work folder): messages other than SetForce, replies, resets, faults.
  awk '$1 == "M" || $1 == "T" || ($1 == "X" && $3 !~ /^garbage/) { print NR ": " $0 }' "$LOG" |
    sed "s/^/$name: host port: log line /"
  grep -h -e '^device:' -e '^monitor:' "$WORK"/serve*.out | sed "s/^/$name: host port: serve: /" || true
  fail "the host port's log breaks the rules above"
fi
echo "$name: host port: passed in $(($(date +%s) - host_started)) s"

# ------------------------------------------------------------------------------------------ 3. QEMU Cortex-M
if [ "${FIRMWARE_SKIP_QEMU:-}" = 1 ] && ! in_ci; then
  skip "FIRMWARE_SKIP_QEMU=1: the QEMU part was not run (the unit tests and the host port passed)"
fi
. firmware/ports/mps2-an386/qemu-check.sh
echo "$name: passed in $(($(date +%s) - started)) s"
