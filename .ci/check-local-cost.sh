#!/usr/bin/env bash
# The device-side local loop's cost per cycle (docs/local-model.md, "What a cycle costs"): crates/local/measure-cost.sh
# counts every cycle's instructions with callgrind; this checks the page's claims about them: surface-following
# families (corner, wedge, mixed) under 10 000 instructions at their worst, a cold start under 50 000.
set -euo pipefail
cd "$(dirname "$0")/.."
name=check-local-cost
. .ci/lib.sh
if ! command -v valgrind >/dev/null 2>&1; then
  if in_ci; then
    { apt-get update -qq && apt-get install -y -qq valgrind; } >/dev/null || fail "apt-get install valgrind failed"
  else
    skip "valgrind is not installed (apt-get install valgrind)"
  fi
fi
table=$(bash crates/local/measure-cost.sh 400) || fail "crates/local/measure-cost.sh failed"
echo "$table"
echo "$table" | awk -v name="$name" '
  $1 == "corner" || $1 == "wedge" || $1 == "mixed" { if ($5 >= 10000) { print name ": FAILED: " $1 " max " $5 " >= 10000"; bad = 1 } }
  $1 == "cold" { if ($5 >= 50000) { print name ": FAILED: cold max " $5 " >= 50000"; bad = 1 } }
  END { exit bad }' || exit 1
echo "$name: the local loop's cost per cycle is within docs/local-model.md's figures"
