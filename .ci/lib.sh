# Shared by the .ci/check-*.sh scripts (sourced at their top, after they set `name`).
#
# The rule (the project brief): a check that needs a tool skips with a visible message on a developer's machine
# when the tool cannot be had, but in CI (.ci/run exports CI=true) a tool that a registry provides (PyPI, npm,
# Debian) is installed, and a failed install FAILS the run. Only another toolchain (nightly Rust) may be
# skipped in CI, visibly.

skip() {
  echo "$name: SKIPPED: $*"
  exit 0
}
fail() {
  echo "$name: FAILED: $*" >&2
  exit 1
}
# True in a CI run (CI set to anything but "", "0" or "false").
in_ci() {
  [ -n "${CI:-}" ] && [ "${CI}" != "0" ] && [ "${CI}" != "false" ]
}
# A tool could not be had: fail in CI, skip visibly elsewhere.
missing() {
  if in_ci; then fail "$* (CI needs it)"; fi
  skip "$*"
}
# need_python "MODULE, ..." PACKAGE...: python3 with these modules, pip-installing PACKAGEs when an import fails.
need_python() {
  local imports=$1
  shift
  command -v python3 >/dev/null 2>&1 || missing "python3 is not installed"
  if ! python3 -c "import $imports" >/dev/null 2>&1; then
    echo "$name: installing $* with pip"
    python3 -m pip install --quiet --disable-pip-version-check "$@" || missing "pip install $* failed (offline?)"
  fi
}

# Sets VOXHAP to the binary to run: $VOXHAP_BIN when given (e.g. target/release/voxhap after cargo test --release), else
# target/release/voxhap, built by cargo (quick when up to date; minutes from scratch).
find_voxhap() {
  if [ -n "${VOXHAP_BIN:-}" ]; then
    VOXHAP=$VOXHAP_BIN
    [ -x "$VOXHAP" ] || fail "VOXHAP_BIN=$VOXHAP is not an executable"
  else
    echo "$1: building target/release/voxhap (cargo build --release; quick when up to date)"
    cargo build --release --quiet --bin voxhap || fail "cargo build --release failed"
    VOXHAP=target/release/voxhap
  fi
}

# Makes WORK a fresh temporary directory named after $1; on exit, stops the server whose pid is in
# SERVER_PID (when set) and removes WORK.
make_work_dir() {
  WORK=$(mktemp -d "${TMPDIR:-/tmp}/$1.XXXXXX")
  SERVER_PID=""
  trap stop_server_and_clean_up EXIT
}

stop_server_and_clean_up() {
  if [ -n "$SERVER_PID" ] && kill -0 "$SERVER_PID" 2>/dev/null; then
    kill "$SERVER_PID" 2>/dev/null || true
    wait "$SERVER_PID" 2>/dev/null || true
  fi
  rm -rf "$WORK"
}
