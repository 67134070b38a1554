#!/usr/bin/env bash
# Runs every cargo-fuzz target (fuzz/: the volume loaders, the trace readers, scene and solve files, control
# JSON, the device protocol decoder) for a few seconds each on the nightly toolchain. A crash, a leak, an
# allocation over the limit or a slow input fails CI; libFuzzer leaves the input in fuzz/artifacts/TARGET/.
# Add such an input to fuzz/regressions/TARGET/ (cargo test replays that folder) once it is fixed.
#
# FUZZ_SECONDS (default 8) is the time per target; with 10 targets the runs take about 2 minutes, after the
# build (about 8 CPU-minutes from scratch, 3 minutes after a change to voxhap).
# Skips, saying so, when no nightly toolchain is installed; fails when cargo-fuzz cannot be installed.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
seconds="${FUZZ_SECONDS:-8}"
if ! rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
  echo "ci: fuzz: SKIPPED: no nightly Rust toolchain here (rustup toolchain install nightly); the corpus of"
  echo "ci: fuzz: past crashes is still replayed by cargo test (tests/fuzz_corpus.rs)"
  exit 0
fi
if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
  echo "ci: fuzz: installing cargo-fuzz"
  if ! cargo install cargo-fuzz --locked; then
    echo "ci: fuzz: FAILED: cargo install cargo-fuzz --locked did not succeed" >&2
    exit 1
  fi
fi
started=$(date +%s)
cargo +nightly fuzz build
echo "ci: fuzz: targets built in $(( $(date +%s) - started )) s"
bin_dir="target/$(rustc +nightly -vV | sed -n 's/^host: //p')/release"
ran=$(date +%s)
for target in $(cargo +nightly fuzz list); do
  mkdir -p "corpus/$target"
  seeds=()
  if [ -d "regressions/$target" ]; then seeds+=("regressions/$target"); fi
  echo "ci: fuzz: $target for ${seconds} s"
  # The binaries cargo fuzz built, run directly (as `cargo fuzz run` does, without its cargo overhead).
  # -rss_limit_mb: more than 1 GiB for inputs of at most 64 KiB is an unbounded allocation, i.e. a bug.
  mkdir -p "artifacts/$target"
  "$bin_dir/$target" -artifact_prefix="artifacts/$target/" "corpus/$target" "${seeds[@]}" \
    -max_total_time="$seconds" -max_len=65536 -rss_limit_mb=1024 -timeout=10 -print_final_stats=0 \
    >"corpus/$target.log" 2>&1 || {
      tail -40 "corpus/$target.log"
      echo "ci: fuzz: FAILED: $target (input in fuzz/artifacts/$target/; reproduce with" \
        "cd fuzz && cargo +nightly fuzz run $target artifacts/$target/FILE)" >&2
      exit 1
    }
  grep -E '^(Done|#[0-9]+ *DONE)' "corpus/$target.log" | tail -1 || true
done
echo "ci: fuzz: every target ran ${seconds} s without a finding ($(( $(date +%s) - ran )) s of fuzzing, $(( $(date +%s) - started )) s in all)"
# In CI the fuzzers' build (about 2 GB in fuzz/target) is not needed again: the checks after this one write
# traces of hundreds of megabytes, and a CI machine's disk may be small. Kept elsewhere, as a build cache.
if [ "${CI:-}" = "true" ]; then
  rm -rf target
  echo "ci: fuzz: removed fuzz/target (the fuzzers' build) to free disk for the checks after it"
fi
