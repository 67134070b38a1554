# Shared by the .ci/check-*.sh scripts (sourced, after they define fail()).

# Sets VOXHAP to the binary to run: $VOXHAP_BIN when given (e.g. target/debug/voxhap after cargo test), else
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
