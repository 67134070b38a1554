#!/usr/bin/env bash
# Builds the voxhap Python package (python/: PyO3 native module, abi3, built by maturin through pip) and runs
# its pytest tests (python/tests) against real files, sims and live sessions (voxhap.Session), then runs
# examples/figure7_force_penetration.ipynb (its code cells as plain Python, python/bench/run_notebook.py)
# with TMPDIR pointing to an empty folder, and fails if the notebook left anything there or in the
# repository.
#
# Installs maturin, pytest, pandas, pyarrow and matplotlib with pip, then `pip install ./python` (a release build, to
# reuse the dependency builds of the README's commands, which build in the release profile), timed, and fails if
# the build changed a tracked file (python/Cargo.lock is used --locked). In CI (CI set) a failed install fails the
# check; elsewhere it skips with a visible message when pip or maturin cannot be had. Then times
# voxhap.read_trace against pd.read_parquet on a ten-minute trace (python/bench/load_trace.py --read-trace;
# printed, and failing above VOXHAP_READ_TRACE_MAX_RATIO when that is set: on a shared runner the ratio is
# noisy).
#
# Environment: VOXHAP_BIN (a voxhap binary for the tests that write CSV/MCAP traces; default
# target/release/voxhap, built by cargo when missing).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-python
. .ci/lib.sh

need_python "maturin, pytest, pandas, pyarrow, matplotlib" maturin pytest pandas pyarrow matplotlib
export VOXHAP_BIN=${VOXHAP_BIN:-target/release/voxhap}
[ -x "$VOXHAP_BIN" ] || cargo build --release --quiet --bin voxhap || fail "cargo build --release failed"
export VOXHAP_BIN=$(realpath "$VOXHAP_BIN")
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}
echo "$name: pip install ./python: maturin builds the native module voxhap._voxhap (PyO3, abi3) and the crates it calls (voxhap-core, -io, -record, -servo), cargo --release --locked into $CARGO_TARGET_DIR, reusing what cargo build --release compiled there (minutes on 2 busy cores)"
tracked_before=$(git status --porcelain --untracked-files=no 2>/dev/null || true)
started=$(date +%s)
python3 -m pip install --quiet --disable-pip-version-check --no-build-isolation ./python \
  || fail "pip install ./python failed"
echo "$name: pip install ./python took $(($(date +%s) - started)) s (load average $(cut -d' ' -f1 /proc/loadavg), $(nproc) cores)"
tracked_after=$(git status --porcelain --untracked-files=no 2>/dev/null || true)
[ "$tracked_before" = "$tracked_after" ] \
  || fail "pip install ./python changed tracked files: $(diff <(echo "$tracked_before") <(echo "$tracked_after"))"
# The installed module carries no debug information: no .debug_* section in its ELF section table.
python3 - <<'PY' || fail "the installed voxhap._voxhap carries debug information"
import os, struct, sys, voxhap._voxhap as m
data = open(m.__file__, "rb").read()
shoff, = struct.unpack_from("<Q", data, 0x28)
shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)
names_at = struct.unpack_from("<Q", data, shoff + shstrndx * shentsize + 0x18)[0]
names = [data[names_at + struct.unpack_from("<I", data, shoff + i * shentsize)[0]:].split(b"\0", 1)[0].decode()
         for i in range(shnum)]
debug = [n for n in names if n.startswith(".debug")]
print(f"check-python: installed {os.path.basename(m.__file__)}: {len(data) / 1e6:.1f} MB, debug sections: {debug or 'none'}")
sys.exit(1 if debug else 0)
PY
python3 -m pytest -q python/tests || fail "pytest python/tests failed"
echo "$name: voxhap.read_trace against pd.read_parquet on a ten-minute trace"
make_work_dir voxhap-read-trace
"$VOXHAP_BIN" sim sims/multimodal.toml --out "$WORK/ten.parquet" --duration 600 >/dev/null \
  || fail "voxhap sim for the ten-minute trace failed"
ratio_args=()
[ -z "${VOXHAP_READ_TRACE_MAX_RATIO:-}" ] || ratio_args=(--max-ratio "$VOXHAP_READ_TRACE_MAX_RATIO")
python3 python/bench/load_trace.py "$WORK/ten.parquet" --repeat 7 --read-trace "${ratio_args[@]}" \
  || fail "voxhap.read_trace against pd.read_parquet failed"
rm -rf "$WORK"
echo "$name: examples/figure7_force_penetration.ipynb"
make_work_dir voxhap-notebook
untracked_before=$(git status --porcelain --untracked-files=all 2>/dev/null || true)
TMPDIR=$WORK python3 python/bench/run_notebook.py examples/figure7_force_penetration.ipynb \
  || fail "the figure 7 notebook failed"
left=$(find "$WORK" -mindepth 1 -print -quit)
[ -z "$left" ] || fail "the notebook left files in its temporary folder: $(ls -A "$WORK")"
untracked_after=$(git status --porcelain --untracked-files=all 2>/dev/null || true)
[ "$untracked_before" = "$untracked_after" ] \
  || fail "the notebook changed the repository: $(diff <(echo "$untracked_before") <(echo "$untracked_after"))"
echo "$name: passed"
