#!/usr/bin/env bash
# Opens voxhap's MCAP files with the MCAP reader Lichtblick uses: npm @mcap/core at the version Lichtblick's
# packages/suite-base/package.json pins (2.0.2; Foxglove Studio 1.48 stops on the same problems). For a
# `voxhap serve --record` recording, a `voxhap sim --out` trace and a `voxhap trace repair` of a trace cut
# mid-way, .ci/mcap-viewer-check.mjs checks: the indexed reader opens it, every chunk has message indexes
# (that reader refuses "Chunks without message indexes"), the statistics' start time is the first message's log
# time (not 0, not 1970) and the end the last's, every message reads back in log-time order, and every JSON
# schema passes the viewers' JSON-schema reader (Lichtblick's parseJsonSchema, rule for rule).
#
# Skips (exit 0, with a message) when node or npm is missing or the npm install fails, except in CI (CI set),
# where that fails. Environment: VOXHAP_BIN (a voxhap binary instead of building target/release/voxhap).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-mcap-viewers
. .ci/lib.sh

command -v node >/dev/null 2>&1 || missing "node is not installed"
command -v npm >/dev/null 2>&1 || missing "npm is not installed"
make_work_dir voxhap-mcap-viewers
trap 'exit 130' INT TERM

MCAP_CORE=@mcap/core@2.0.2
echo "$name: installing $MCAP_CORE into $WORK (node $(node --version))"
if ! timeout 120 npm install --prefix "$WORK" --no-audit --no-fund --no-save --loglevel=error "$MCAP_CORE" \
  >"$WORK/npm.log" 2>&1; then
  tail -n 5 "$WORK/npm.log" | sed "s/^/$name: npm: /"
  missing "npm install of $MCAP_CORE failed (offline or no registry access)"
fi

find_voxhap "$name"
echo "$name: recording 3 s with $VOXHAP serve --record"
"$VOXHAP" serve --no-http --no-foxglove --duration 3 --record "$WORK/serve.mcap" >"$WORK/serve.out" 2>&1 \
  || { cat "$WORK/serve.out" >&2; fail "voxhap serve --record failed"; }
"$VOXHAP" sim sims/sphere_surface.toml --out "$WORK/sim.mcap" --duration 2 >"$WORK/sim.out" 2>&1 \
  || { cat "$WORK/sim.out" >&2; fail "voxhap sim --out failed"; }
size=$(stat -c %s "$WORK/sim.mcap")
head -c $((size * 2 / 3)) "$WORK/sim.mcap" >"$WORK/cut.mcap"
"$VOXHAP" trace repair "$WORK/cut.mcap" --out "$WORK/repaired.mcap" >"$WORK/repair.out" 2>&1 \
  || { cat "$WORK/repair.out" >&2; fail "voxhap trace repair failed"; }

cp .ci/mcap-viewer-check.mjs "$WORK/"
for file in serve sim repaired; do
  node "$WORK/mcap-viewer-check.mjs" "$WORK/$file.mcap" || fail "$file.mcap: the viewers' reader refuses it (see above)"
done
echo "$name: passed"
