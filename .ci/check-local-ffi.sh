#!/usr/bin/env bash
# The C interface to voxhap-local (local-ffi): builds the no_std static library (its own workspace,
# panic = "abort"), checks that include/voxhap_local.h (hand-written) declares exactly the functions the library
# exports, then compiles local-ffi/tests/test_local_ffi.c with the host's gcc (-std=c99 -pedantic -Werror),
# links it against the library and runs it on protocol/vectors: it drives the device as a C firmware would and
# checks the force against SPEC section 10.5 for the vector local/local_model_wall.hex. Its checks and vector reader
# are the firmware tests' (firmware/tests/check.h).
#
# In CI (CI=true) a missing gcc is installed with apt-get and a failed install fails the check; elsewhere a missing
# gcc skips visibly.
set -euo pipefail
cd "$(dirname "$0")/.."
name=check-local-ffi
. .ci/lib.sh

if ! command -v gcc >/dev/null 2>&1 || ! command -v nm >/dev/null 2>&1; then
  if in_ci && command -v apt-get >/dev/null 2>&1; then
    echo "$name: installing gcc and binutils with apt-get"
    sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    { $sudo apt-get update -qq && $sudo apt-get install -y -qq gcc binutils >/dev/null; } \
      || fail "apt-get install gcc binutils failed"
  else
    missing "gcc or nm is not installed"
  fi
fi

target_dir="$PWD/target/local-ffi"
CARGO_TARGET_DIR="$target_dir" cargo build --release --quiet --manifest-path local-ffi/Cargo.toml \
  || fail "local-ffi does not build"
lib="$target_dir/release/libvoxhap_local_ffi.a"
header=local-ffi/include/voxhap_local.h

# The header and the library name the same functions.
exported=$(nm -g --defined-only "$lib" 2>/dev/null | awk '$2 == "T" && $3 ~ /^voxhap_local_/ { print $3 }' | sort -u)
declared=$(grep -oE '\bvoxhap_local_[a-z_]+\(' "$header" | tr -d '(' | sort -u)
[ -n "$exported" ] || fail "$lib exports no voxhap_local_ function"
if [ "$exported" != "$declared" ]; then
  diff <(echo "$declared") <(echo "$exported") >&2 || true
  fail "$header and the library disagree on the functions (< header, > library)"
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/$name.XXXXXX")
trap 'rm -rf "$work"' EXIT
gcc -std=c99 -Wall -Wextra -Werror -pedantic -Ilocal-ffi/include -Ifirmware/tests \
  local-ffi/tests/test_local_ffi.c "$lib" -lm -o "$work/test_local_ffi" \
  || fail "the C test does not compile or link against the library"
"$work/test_local_ffi" protocol/vectors || fail "the C test failed"
echo "$name: passed"
