#!/usr/bin/env bash
# Checks voxhap's OpenIGTLink server with an independent client: pyigtl (PyPI, the Python OpenIGTLink
# library Slicer users script with) runs .ci/igtl_client.py against a running `voxhap serve --igtl`:
# the streamed TRANSFORMs and STATUS (CRC-64 checked by pyigtl's CRC), the rate, RAS millimetres, the force,
# IMAGE refused without the token and loaded with it, a protocol-3 client authorised by metadata.
#
# Installs pyigtl with pip (into the user's Python, like .ci/run does for mcap). In CI (CI=true) a failed
# install fails the check; elsewhere it skips with a message. Takes about 20 s once voxhap is built.
#
# Environment: VOXHAP_BIN (a voxhap binary to use instead of building target/release/voxhap, e.g.
# target/release/voxhap after cargo test --release), VOXHAP_IGTL_RATE (default 60).
set -euo pipefail
cd "$(dirname "$0")/.."

name=check-igtl
. .ci/lib.sh

need_python "pyigtl, numpy" pyigtl
echo "$name: $(python3 -c 'from importlib.metadata import version as v; print("pyigtl", v("pyigtl"), "numpy", v("numpy"))')"

make_work_dir voxhap-igtl
trap 'exit 130' INT TERM
find_voxhap "$name"

token=igtl-check-token-0123
rate=${VOXHAP_IGTL_RATE:-60}
start_serve --igtl 127.0.0.1:0 --igtl-rate "$rate" --http 127.0.0.1:0 --token "$token" --no-foxglove --duration 120
serve_listening igtl
igtl=$LISTENING
serve_listening http
http=$LISTENING
grep -q "^igtl: control token $token\$" "$WORK/serve.out" || fail "voxhap serve did not print 'igtl: control token $token'"
echo "$name: voxhap serve: OpenIGTLink on $igtl, HTTP on $http"

if ! timeout 120 python3 .ci/igtl_client.py "$igtl" "$http" "$token" "$rate"; then
  sed "s/^/$name: serve: /" "$WORK/serve.err" >&2
  fail "the pyigtl client's checks failed (see above)"
fi
echo "$name: passed"
