#!/usr/bin/env bash
# The minimum Rust version we declare is true (run from .ci/run).
#
# 1. No package in a lock file needs a newer Rust than its workspace declares: every package's own
#    `rust-version`, as `cargo metadata` reports it, for the main workspace (Cargo.lock, rust-version in
#    Cargo.toml's [workspace.package]) and the Python module's (python/Cargo.lock, python/Cargo.toml).
# 2. Our own code calls no standard-library API newer than the declared version: clippy's
#    `incompatible_msrv` lint, which reads rust-version (on every target of both workspaces).
#
# Only one toolchain is installed, so this does not build with the old compiler itself; language features
# newer than the declared version are caught by the lock check only through the crates that use them.
# Fails (exit 1) naming each package that needs more, or each call clippy finds.
set -euo pipefail
cd "$(dirname "$0")/.."
name=check-msrv
. .ci/lib.sh
say() { echo "$name: $*"; }
command -v python3 >/dev/null 2>&1 || missing "python3 is needed to read cargo metadata"
make_work_dir check-msrv

# check_lock DIR: cargo metadata of the workspace in DIR against its declared rust-version.
check_lock() {
  local dir=$1
  (cd "$dir" && cargo metadata --format-version 1 --locked >"$WORK/metadata.json") ||
    fail "cargo metadata failed in $dir (network needed for packages not downloaded yet?)"
  python3 - "$WORK/metadata.json" "$dir" <<'PY'
import json, sys

meta = json.load(open(sys.argv[1]))
where = sys.argv[2]
members = set(meta["workspace_members"])

def version(text):
    parts = [int(p) for p in text.split(".")]
    return tuple(parts + [0] * (3 - len(parts)))

declared = {p["name"]: p.get("rust_version") for p in meta["packages"] if p["id"] in members}
missing = [name for name, v in declared.items() if not v]
if missing:
    print("check-msrv: FAILED: %s: workspace members without rust-version: %s" % (where, ", ".join(missing)), file=sys.stderr)
    sys.exit(1)
floor = min(version(v) for v in declared.values())
shown = ".".join(str(x) for x in floor)
needs = sorted(
    ((version(p["rust_version"]), p["name"], p["version"]) for p in meta["packages"]
     if p["id"] not in members and p.get("rust_version")),
    reverse=True,
)
too_new = [n for n in needs if n[0] > floor]
if too_new:
    for v, name, ver in too_new:
        print("check-msrv: %s: %s %s needs Rust %s" % (where, name, ver, ".".join(str(x) for x in v)), file=sys.stderr)
    print("check-msrv: FAILED: %s declares rust-version %s but %d locked packages need more: raise it to %s, or pin older "
          "versions (cargo update -p NAME --precise VERSION)" % (where, shown, len(too_new), ".".join(str(x) for x in too_new[0][0])),
          file=sys.stderr)
    sys.exit(1)
top = needs[0] if needs else None
print("check-msrv: ok: %s declares Rust %s; %d locked packages, the most demanding %s" % (
    where, shown, len(meta["packages"]),
    "%s %s (%s)" % (top[1], top[2], ".".join(str(x) for x in top[0])) if top else "none"))
PY
}

check_lock .
check_lock python

# Our own code: clippy with only incompatible_msrv turned into an error. The release profile shares the
# dependencies' builds with `cargo test --release` and `cargo clippy --release`.
say "clippy incompatible_msrv (main workspace)"
cargo clippy --release --locked --workspace --all-targets --quiet -- -A clippy::all -D clippy::incompatible_msrv ||
  fail "clippy found standard-library calls newer than Cargo.toml's rust-version (above)"
say "clippy incompatible_msrv (python/)"
(cd python && CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/../target} cargo clippy --release --locked --all-targets --quiet -- \
  -A clippy::all -D clippy::incompatible_msrv) ||
  fail "clippy found standard-library calls newer than python/Cargo.toml's rust-version (above)"
say "all checks passed"
