#!/usr/bin/env bash
# Instructions per cycle of the device-side local loop (docs/local-model.md), counted by callgrind one cycle at a
# time: each call of `voxhap_local_measured_cycle` in crates/local/examples/cycle_cost.rs is dumped separately,
# so the maximum is a real per-cycle worst case, not an average. Prints one row per scene family:
# family, cycles, mean, median, max instructions per cycle, and the cycles per tick left at 600 MHz and 10 kHz.
# Usage: crates/local/measure-cost.sh [CYCLES per family, default 400]. Needs valgrind (callgrind).
set -euo pipefail
cd "$(dirname "$0")/../.."
cycles="${1:-400}"
if ! command -v valgrind >/dev/null; then
  echo "measure-cost: valgrind is not installed (apt-get install valgrind)" >&2
  exit 1
fi
cargo build --release -q -p voxhap-local --example cycle_cost
bin=target/release/examples/cycle_cost
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
printf '%-8s %7s %9s %9s %9s %s\n' family cycles mean median max "headroom at 60000"
for family in corner wedge mixed cold budget; do
  rm -f "$out"/cg.*
  valgrind --tool=callgrind --collect-atstart=no --toggle-collect=voxhap_local_measured_cycle \
    --dump-after=voxhap_local_measured_cycle --callgrind-out-file="$out/cg.%p" \
    "$bin" "$family" "$cycles" >/dev/null 2>"$out/log" || { cat "$out/log" >&2; exit 1; }
  # Each dump's "summary:" line is the instructions of one call.
  grep -h -E '^summary:' "$out"/cg.* | awk '{print $2}' | sort -n > "$out/costs"
  python3 - "$family" "$out/costs" <<'PY'
import statistics, sys
family, path = sys.argv[1], sys.argv[2]
costs = [int(x) for x in open(path) if x.strip() and int(x) > 0]
if not costs:
    sys.exit(f"measure-cost: no per-cycle dumps for {family}")
mx = max(costs)
print(f"{family:<8} {len(costs):7d} {statistics.mean(costs):9.0f} {statistics.median(costs):9.0f} {mx:9d} {60000 / mx:.1f}x")
PY
done
