# Part 3 of .ci/check-firmware.sh (sourced by it: uses its need_apt, wait_log, start_serve, stop_serve_linked, WORK):
# the Cortex-M4 image in qemu-system-arm -M mps2-an386, its UART0 on a pseudo-terminal that `voxhap serve`
# drives, its UART1 (the firmware's event log) in a file that firmware/tools/check_log.py checks.

need_apt arm-none-eabi-gcc:gcc-arm-none-eabi qemu-system-arm:qemu-system-arm
if [ ! -f "$(arm-none-eabi-gcc -print-file-name=nano.specs)" ]; then
  need_apt /nonexistent/newlib:libnewlib-arm-none-eabi
fi
qemu_started=$(date +%s)
make -s -C firmware qemu >"$WORK/arm-build.out" 2>&1 || { cat "$WORK/arm-build.out" >&2; fail "make -C firmware qemu failed"; }
echo "$name: qemu: $(arm-none-eabi-gcc --version | head -1); $(qemu-system-arm --version | head -1)"
arm-none-eabi-size firmware/build/mps2-an386.elf | sed "s/^/$name: qemu: size: /"

# Instructions per control cycle, under -icount shift=0 (1 instruction = 1 ns of virtual time).
bench=$(timeout 120 qemu-system-arm -M mps2-an386 -nographic -monitor none -serial stdio -icount shift=0 \
  -semihosting-config enable=on,target=native -kernel firmware/build/mps2-an386-bench.elf 2>&1) \
  || fail "the bench image did not run in qemu: $bench"
echo "$name: qemu: $bench"
case "$bench" in *"frames ok 2002; enabled 1"*) ;; *) fail "the bench image did not decode its frames: $bench" ;; esac

QLOG=$WORK/qemu-uart1.log
qemu-system-arm -M mps2-an386 -nographic -monitor none -serial pty -serial "file:$QLOG" \
  -kernel firmware/build/mps2-an386.elf >"$WORK/qemu.out" 2>&1 &
QEMU_PID=$!
stop_qemu() {
  if [ -n "${QEMU_PID:-}" ] && kill -0 "$QEMU_PID" 2>/dev/null; then
    kill "$QEMU_PID" 2>/dev/null || true
    wait "$QEMU_PID" 2>/dev/null || true
  fi
  cleanup_device
}
trap stop_qemu EXIT
pty=""
for _ in $(seq 1 100); do
  pty=$(sed -n 's/.*char device redirected to \(\/dev\/pts\/[0-9]*\) (label serial0).*/\1/p' "$WORK/qemu.out" | head -1)
  [ -n "$pty" ] && break
  kill -0 "$QEMU_PID" 2>/dev/null || fail "qemu exited: $(cat "$WORK/qemu.out")"
  sleep 0.1
done
[ -n "$pty" ] || fail "qemu did not report its UART0 pseudo-terminal: $(cat "$WORK/qemu.out")"
wait_log "$QLOG" 0 '$1 == "X" && $3 == "reset"' "the firmware's start-up line on UART1"
echo "$name: qemu: mps2-an386 booted, UART0 on $pty"

# QEMU notices that a pseudo-terminal was opened only when it next polls it (about once a second): a connect
# timeout of 10 s leaves room for that on a busy machine. The servo rate: QEMU's CMSDK UART model holds one
# received byte, so each byte of a SetForce waits for the emulated CPU to read it and for QEMU's main loop to
# deliver the next (two thread wake-ups per byte): a SetForce -> State round trip measured 1.2 ms median (7 ms at
# the 90th percentile) on a loaded 2-core machine, longer than the half period the host waits at 1 kHz. At 250 Hz
# (a 4 ms period) the link holds; the firmware's own work is about 3 400 instructions per cycle (bench above).
rate=${FIRMWARE_QEMU_RATE:-250}
start_serve "$pty" --connect-timeout 10 --rate "$rate"
wait_log "$QLOG" 0 "$NONZERO_FORCE" "force on the QEMU board (engage)"
engaged=$(date +%s)
echo "$name: qemu: engaged at $rate Hz; rendering the built-in scene for 6 s"
sleep 6
# Stop while force is flowing (a loaded machine can make the host drop and rebuild the link at any moment; its
# stop sends zero and Disable only on an open link: stop_serve_linked starts serve again when it had none).
stop_serve_linked "$QLOG" "$NONZERO_FORCE" "force on the QEMU board before the stop" "$pty" --connect-timeout 10 \
  --rate "$rate"
wait_log "$QLOG" "$STOP_MARK" '$1 == "M" && $3 == "03"' "Disable on the QEMU board after serve's stop"
sleep 0.2
kill "$QEMU_PID"
wait "$QEMU_PID" 2>/dev/null || true
QEMU_PID=""
grep -E '^(stopped|rate|device errors|safety)' "$WORK/serve.out" | sed "s/^/$name: qemu: serve: /" || true
awk '$1 == "A" && !($3 ~ /^[08]0000000$/ && $4 ~ /^[08]0000000$/ && $5 ~ /^[08]0000000$/) {
       if (!first) first = $2; last = $2; n++ }
     END { printf "'"$name"': qemu: non-zero force over %.2f s of device time (%d control cycles)\n", (last - first) / 1e6, n }' "$QLOG"
python3 firmware/tools/check_log.py "$QLOG" --max-force 5 --max-rise 1000 --host-rate "$rate" --expect engaged,stopped \
  || fail "the QEMU board's log breaks the rules above"
echo "$name: qemu: passed in $(($(date +%s) - qemu_started)) s ($(($(date +%s) - engaged)) s from engage to the end)"
