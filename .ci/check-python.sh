#!/usr/bin/env bash
# Builds the voxhap Python package (python/: PyO3 native module, abi3, built by maturin through pip) and runs
# its pytest tests (python/tests) against real files, sims and live sessions (voxhap.Session), then runs
# examples/figure7_force_penetration.ipynb (its code cells as plain Python, python/bench/run_notebook.py)
# with TMPDIR pointing to an empty folder, and fails if the notebook left anything there or in the
# repository.
#
# Installs maturin, pytest, pandas, pyarrow and matplotlib with pip, then `pip install ./python` (a release build, to
# reuse the dependency builds of the README's commands, which build in the release profile). In CI (CI set) a failed
# install fails the check; elsewhere it skips with a visible message when pip or maturin cannot be had.
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
echo "$name: pip install ./python (maturin, release profile)"
python3 -m pip install --quiet --disable-pip-version-check --no-build-isolation \
  --config-settings=build-args=--profile=release ./python || fail "pip install ./python failed"
python3 -m pytest -q python/tests || fail "pytest python/tests failed"
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
