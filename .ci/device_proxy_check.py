#!/usr/bin/env python3
"""The page's "Device proxy" line (web/index.html #st-device-proxy), without and with a local-model device.

Run by .ci/check-browser.sh:

  device_proxy_check.py none DOM_FILE
      the page of a serve without a local-model device (the simulated arm on the built-in scene) says
      "none (no local model)" on that line;
  device_proxy_check.py live VOXHAP CHROMIUM WORK_DIR
      starts `voxhap mock-device --pty --local-model` (its hand held still, so that its proxy stays put) and
      `voxhap serve` on it (built-in scene, HTTP on a free loopback port), waits until /api/state carries the
      device's report (`device_local`), then runs .ci/device-proxy-page.js (node, playwright-core from
      NODE_PATH), which watches the page until the line shows that proxy (its coordinates within 0.2 mm of
      /api/state's device_local.proxy_m), its bound and the model's number and age. Stops both processes.

Exit 0 when the check holds, 1 with a message naming what the page showed otherwise.
"""
import json
import re
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

NAME = "check-browser"
# The mock's hand holds still at 20 mm on x, inside the built-in scene's ball and its flow (sims/scenes/explore.toml).
ARM = """
[arm]
mass_kg = 0.1
damping_n_s_per_m = 1.0
workspace = { shape = "unbounded" }
[hand]
stiffness_n_per_m = 200.0
damping_n_s_per_m = 2.0
[path]
kind = "hold"
at_m = [0.02, 0.0, 0.0]
"""
# The mock's loop at 1 kHz and serve at 200 Hz: light enough that the link mostly holds on a loaded machine (a
# tick that falls back to SetForce carries no device report).


def fail(message):
    print(NAME + ": FAIL: " + message, file=sys.stderr)
    sys.exit(1)


def line_text(dom):
    """The text of #st-device-proxy in a dumped DOM, or None when the page has no such element."""
    match = re.search(r'<dd[^>]*\bid="st-device-proxy"[^>]*>([^<]*)<', dom)
    return match.group(1) if match else None


def check_none(dom_file):
    text = line_text(Path(dom_file).read_text(encoding="utf-8", errors="replace"))
    if text is None:
        fail("the page has no #st-device-proxy (the Device proxy line) element")
    if text != "none (no local model)":
        fail("without a local-model device the Device proxy line shows %r, not 'none (no local model)'" % text)
    print(NAME + ": ok: without a local-model device the Device proxy line says %r" % text)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def device_local(base):
    try:
        with urllib.request.urlopen(base + "/api/state", timeout=2) as response:
            return json.load(response).get("device_local")
    except Exception:
        return None


def stop(process):
    if process is not None and process.poll() is None:
        process.kill()
        process.wait()


def check_live(voxhap, chromium, work):
    work = Path(work)
    arm = work / "held-arm.toml"
    arm.write_text(ARM)
    mock_out = open(work / "mock.log", "w+")
    serve_out = open(work / "serve-mock.log", "w")
    mock = serve = None
    try:
        mock = subprocess.Popen(
            [voxhap, "mock-device", "--pty", "--local-model", "--local-rate-hz", "1000", "--arm", str(arm),
             "--duration", "600"],
            stdout=mock_out,
            stderr=subprocess.STDOUT,
        )
        path = None
        end = time.time() + 60
        while path is None and time.time() < end:
            time.sleep(0.2)
            mock_out.seek(0)
            found = re.search(r"^serving (\S+)$", mock_out.read(), re.M)
            path = found.group(1) if found else None
            if mock.poll() is not None:
                break
        if path is None:
            fail("voxhap mock-device did not say where it serves within 60 s")
        port = free_port()
        base = "http://127.0.0.1:%d" % port
        serve = subprocess.Popen(
            [voxhap, "serve", "--device", "mock:" + path, "--http", "127.0.0.1:%d" % port, "--no-foxglove",
             "--rt", "off", "--rate", "200", "--duration", "600"],
            stdout=serve_out,
            stderr=subprocess.STDOUT,
        )
        end = time.time() + 120
        while device_local(base) is None:
            if serve.poll() is not None or time.time() > end:
                fail("serve on the capable mock never reported the device's proxy in /api/state (see %s)"
                     % (work / "serve-mock.log"))
            time.sleep(0.2)
        # The page is watched in one long-lived browser (playwright-core, installed by check-browser.sh into
        # NODE_PATH) until it shows the report: a tick that falls back to SetForce carries none.
        page = subprocess.run(
            ["node", str(Path(__file__).with_name("device-proxy-page.js")), base, chromium], timeout=400
        )
        if page.returncode != 0:
            fail("the Device proxy line (see above; serve's output is in %s)" % (work / "serve-mock.log"))
    finally:
        stop(serve)
        stop(mock)
        mock_out.close()
        serve_out.close()


def main(argv):
    if len(argv) == 3 and argv[1] == "none":
        check_none(argv[2])
    elif len(argv) == 5 and argv[1] == "live":
        check_live(argv[2], argv[3], argv[4])
    else:
        fail("usage: device_proxy_check.py none DOM_FILE | live VOXHAP CHROMIUM WORK_DIR")


if __name__ == "__main__":
    main(sys.argv)
