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

# Sets CHROMIUM to the Chromium on the PATH (chromium or chromium-browser). In CI as root, apt-get installs it
# when missing (its log in ${TMPDIR:-/tmp}/$name-apt.log); still none: missing (fails in CI, skips elsewhere),
# the message ending with $1 when given.
need_chromium() {
  CHROMIUM=$(find_chromium || true)
  if [ -z "$CHROMIUM" ] && in_ci && [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    local log="${TMPDIR:-/tmp}/$name-apt.log"
    echo "$name: chromium not found; apt-get install -y chromium (log: $log)"
    export DEBIAN_FRONTEND=noninteractive
    if ! timeout 300 apt-get install -y -qq chromium >"$log" 2>&1; then
      timeout 120 apt-get update -qq >>"$log" 2>&1 || true
      timeout 300 apt-get install -y -qq chromium >>"$log" 2>&1 || true
    fi
    CHROMIUM=$(find_chromium || true)
  fi
  [ -n "$CHROMIUM" ] || missing "no chromium or chromium-browser found (and it could not be installed)${1:+; $1}"
}
find_chromium() {
  local browser
  for browser in chromium chromium-browser; do
    if command -v "$browser" >/dev/null 2>&1; then
      command -v "$browser"
      return 0
    fi
  done
  return 1
}

# node and npm on the PATH, else missing.
need_node_npm() {
  command -v node >/dev/null 2>&1 || missing "node is not installed${1:+; $1}"
  command -v npm >/dev/null 2>&1 || missing "npm is not installed${1:+; $1}"
}

# npm_into DIR WHAT NPM-ARGS...: runs `npm NPM-ARGS...` in DIR (a temporary directory, never the repository),
# its output in DIR/npm.log; when it fails, shows the log's last lines and calls missing "WHAT failed ...".
npm_into() {
  local dir=$1 what=$2
  shift 2
  mkdir -p "$dir"
  if ! (cd "$dir" && timeout 300 npm --prefix "$dir" "$@" --no-audit --no-fund --loglevel=error >"$dir/npm.log" 2>&1); then
    tail -n 5 "$dir/npm.log" | sed "s/^/$name: npm: /"
    missing "$what failed (offline or no registry access)"
  fi
}

# npm_versions DIR PACKAGE...: prints "PACKAGE@VERSION " for each package installed in DIR.
npm_versions() {
  local dir=$1
  shift
  (cd "$dir" && node -e 'for (const p of process.argv.slice(1)) process.stdout.write(`${p}@${require(`${p}/package.json`).version} `)' "$@")
}

# start_serve ARG...: starts `$VOXHAP serve ARG...` in the background, its stdout in $WORK/serve.out and its
# stderr in $WORK/serve.err, and sets SERVER_PID (make_work_dir's exit trap stops it).
start_serve() {
  echo "$name: starting $VOXHAP serve $*"
  "$VOXHAP" serve "$@" >"$WORK/serve.out" 2>"$WORK/serve.err" &
  SERVER_PID=$!
}

# serve_output: what serve wrote so far, each line prefixed with "$name: serve: ".
serve_output() {
  cat "$WORK/serve.out" "$WORK/serve.err" | sed "s/^/$name: serve: /"
}

# serve_waits_for PATTERN WHAT: waits (up to 60 s) until serve's stdout has a line matching the grep PATTERN and
# sets SERVE_LINE to the first one; fails, showing serve's output, when serve exits first or the time runs out.
serve_waits_for() {
  local pattern=$1 what=$2
  SERVE_LINE=""
  for _ in $(seq 1 600); do
    SERVE_LINE=$(grep -m1 -e "$pattern" "$WORK/serve.out" || true)
    [ -n "$SERVE_LINE" ] && return 0
    if ! kill -0 "$SERVER_PID" 2>/dev/null; then
      serve_output >&2
      fail "voxhap serve exited before $what"
    fi
    sleep 0.1
  done
  serve_output >&2
  fail "voxhap serve did not print $what within 60 s"
}

# serve_listening SERVER: waits for serve's line "SERVER: listening on ADDRESS ..." (SERVER: http, foxglove,
# igtl) and sets LISTENING to ADDRESS.
serve_listening() {
  serve_waits_for "^$1: listening on " "'$1: listening on ...'"
  LISTENING=${SERVE_LINE#"$1: listening on "}
  LISTENING=${LISTENING%% *}
}
