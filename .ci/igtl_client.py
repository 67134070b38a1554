#!/usr/bin/env python3
"""An independent OpenIGTLink client for .ci/check-igtl.sh: pyigtl (PyPI) talks to a running
`voxhap serve --igtl ... --http ...` and checks what docs/slicer.md promises.

- The stream: TRANSFORM Probe, Proxy, ProbeVelocity, Force and STATUS, every message's CRC-64 checked with
  pyigtl's own CRC function, header version 1 until the client speaks version 2; the Probe rate at most
  --igtl-rate (best-effort: a busy machine sends fewer, so no lower bound is checked).
- pyigtl has no STATUS message class (it decodes IMAGE, POINT, POSITION, STRING, TRANSFORM), so its client
  cannot show voxhap's STATUS replies: this script reads them from a raw socket (docs/slicer.md says so).
- RAS millimetres: with the simulated hand held at a target by ProbeTarget, Probe equals the HTTP state's
  probe_m x 1000; Force equals k (Proxy - Probe) / 1000 (newtons, RAS).
- IMAGE: refused (STATUS 5) without the token, the scene unchanged: the 96 kB ball is over the 64 KiB a
  connection without the token may send, so it is refused from its header and the connection closed;
  accepted (STATUS 1) after the STRING "token <T>", and /api/scene then reports the sent volume's size and
  bounds in metres.
- No lockout: with 16 idle connections open (the most the server takes), pyigtl's own client still
  connects and receives the poses.
- A protocol-3 client (header version 2) authorised by the metadata entry "token".

Usage: igtl_client.py IGTL_HOST:PORT HTTP_URL TOKEN RATE_HZ. Exit 0 when every check passes; otherwise 1 with
the failed check on stderr.
"""

import json
import socket
import struct
import sys
import time
import urllib.request

import numpy as np
import pyigtl
from pyigtl.messages import CRC64, MessageBase

HEADER = 58


def fail(message):
    print(f"igtl_client: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def check(condition, message):
    if not condition:
        fail(message)


class Raw:
    """A plain socket that sends pyigtl-packed messages and parses what comes back, CRC checked."""

    def __init__(self, host, port):
        self.sock = socket.create_connection((host, port), timeout=5)
        self.buffer = b""

    def send(self, message):
        self.sock.sendall(message.pack())

    def _read(self, n, deadline):
        while len(self.buffer) < n:
            self.sock.settimeout(max(0.01, deadline - time.time()))
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError("voxhap closed the connection")
            self.buffer += chunk
        data, self.buffer = self.buffer[:n], self.buffer[n:]
        return data

    def next(self, timeout=5.0):
        """(version, type, device, body content, metadata) of the next message."""
        deadline = time.time() + timeout
        header = self._read(HEADER, deadline)
        fields = MessageBase.parse_header(header)
        (crc,) = struct.unpack("> Q", header[50:58])
        body = self._read(fields["body_size"], deadline)
        check(CRC64(body) == crc, f"CRC-64 mismatch on {fields['message_type']} {fields['device_name']}")
        content = body
        if fields["header_version"] >= 2:
            ext, meta_header, meta_size, _ = struct.unpack("> H H I I", body[:12])
            content = body[ext:len(body) - meta_header - meta_size]
        return fields["header_version"], fields["message_type"], fields["device_name"], content

    def wait_for(self, kind, device=None, timeout=5.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            version, message_type, name, content = self.next(deadline - time.time())
            if message_type == kind and (device is None or name == device):
                return version, content
        fail(f"no {kind} {device or ''} within {timeout} s")

    def status(self, device, timeout=10.0):
        _, content = self.wait_for("STATUS", device, timeout)
        code, sub_code, name = struct.unpack("> H q 20s", content[:30])
        return code, content[30:].split(b"\0")[0].decode()

    def closed_by_server(self, timeout=5.0):
        """True when the server closes the connection within `timeout` (whatever it sends first is read)."""
        deadline = time.time() + timeout
        try:
            while time.time() < deadline:
                self.sock.settimeout(max(0.01, deadline - time.time()))
                if not self.sock.recv(65536):
                    return True
        except (ConnectionResetError, BrokenPipeError):
            return True
        except socket.timeout:
            return False
        return False

    def close(self):
        self.sock.close()


def transform(content):
    values = struct.unpack("> 12f", content)
    matrix = np.array(values[:9]).reshape(3, 3).T
    return matrix, np.array(values[9:])


def http_json(url):
    with urllib.request.urlopen(url, timeout=5) as response:
        return json.load(response)


def latest_frame(raw, timeout=3.0):
    """The four transforms of one tick (they arrive together, in this order)."""
    frame = {}
    deadline = time.time() + timeout
    while time.time() < deadline:
        _, message_type, name, content = raw.next(deadline - time.time())
        if message_type != "TRANSFORM":
            continue
        if name == "Probe":
            frame = {}
        frame[name] = transform(content)
        if len(frame) == 4:
            return frame
    fail("no complete Probe/Proxy/ProbeVelocity/Force frame")


def frames_for(raw, seconds):
    """Reads for `seconds` and returns the last complete frame and its header version."""
    frame, last, version = {}, None, None
    deadline = time.time() + seconds
    while time.time() < deadline:
        message_version, message_type, name, content = raw.next()
        if message_type != "TRANSFORM":
            continue
        if name == "Probe":
            frame = {}
        frame[name] = transform(content)
        if len(frame) == 4:
            last, version = frame, message_version
    check(last is not None, f"no complete frame within {seconds} s")
    return last, version


def main():
    if len(sys.argv) != 5:
        fail("usage: igtl_client.py HOST:PORT HTTP_URL TOKEN RATE_HZ")
    host, port = sys.argv[1].rsplit(":", 1)
    port = int(port)
    http, token, rate_hz = sys.argv[2].rstrip("/"), sys.argv[3], float(sys.argv[4])

    # 1. pyigtl's own client receives the poses.
    client = pyigtl.OpenIGTLinkClient(host=host, port=port)
    probe = client.wait_for_message("Probe", timeout=10)
    check(probe is not None, "pyigtl.OpenIGTLinkClient received no Probe TRANSFORM within 10 s")
    check(np.allclose(probe.matrix[0:3, 0:3], np.eye(3)), f"Probe rotation is not the identity: {probe.matrix}")
    force = client.wait_for_message("Force", timeout=5)
    check(force is not None and np.allclose(force.matrix[0:3, 0:3], np.eye(3)), "no Force TRANSFORM")
    client.stop()
    print(f"igtl_client: pyigtl client got Probe {probe.matrix[0:3, 3]} mm and Force {force.matrix[0:3, 3]} N")

    # 2. The stream on a raw connection: names, CRCs, header version 1, the rate.
    raw = Raw(host, port)
    seen, versions, probes = set(), set(), 0
    started = time.time()
    while time.time() - started < 3.0:
        version, message_type, name, _ = raw.next()
        versions.add(version)
        seen.add((message_type, name))
        if (message_type, name) == ("TRANSFORM", "Probe"):
            probes += 1
    elapsed = time.time() - started
    for wanted in [("TRANSFORM", d) for d in ("Probe", "Proxy", "ProbeVelocity", "Force")] + [("STATUS", "voxhap")]:
        check(wanted in seen, f"{wanted} never arrived (saw {sorted(seen)})")
    check(versions == {1}, f"header versions {versions}, expected only 1 before the client speaks version 2")
    measured = probes / elapsed
    # Best-effort (docs/slicer.md): never above the asked rate, fewer on a busy machine.
    check(probes > 0 and measured <= 1.15 * rate_hz, f"Probe at {measured:.1f} Hz, asked for {rate_hz} Hz")
    check(pyigtl.messages.MessageBase.create_message("STATUS") is None,
          "pyigtl now decodes STATUS: docs/slicer.md says it cannot show STATUS replies")
    print(f"igtl_client: stream OK: {probes} Probe messages in {elapsed:.2f} s ({measured:.1f} Hz, asked {rate_hz})")

    # 3. IMAGE without the token is refused and changes nothing.
    before = http_json(f"{http}/api/scene")["volumes"][0]
    nk, nj, ni = 20, 30, 40
    k, j, i = np.meshgrid(np.arange(nk), np.arange(nj), np.arange(ni), indexing="ij")
    spacing = 1.5
    centre = np.array([(ni - 1) / 2, (nj - 1) / 2, (nk - 1) / 2]) * spacing
    distance = np.sqrt((i * spacing - centre[0]) ** 2 + (j * spacing - centre[1]) ** 2 + (k * spacing - centre[2]) ** 2)
    voxels = np.clip(1.0 - (distance - 10.0) / 6.0, 0.0, 1.0).astype(np.float32)  # 1 inside 10 mm, 0 past 16 mm
    ijk_to_ras = np.diag([spacing, spacing, spacing, 1.0])
    origin_mm = np.array([-29.25, -21.75, -14.25])  # so the ball is centred on the RAS origin
    ijk_to_ras[0:3, 3] = origin_mm
    image = pyigtl.ImageMessage(voxels, ijk_to_world_matrix=ijk_to_ras, world_coordinate_system="ras", device_name="Ball")
    raw.send(image)
    # Refused from its header (the body is over 64 KiB): STATUS 5 under the server's device name, then closed.
    code, text = raw.status("voxhap")
    while code != 5:
        code, text = raw.status("voxhap")
    check(code == 5 and "65536" in text, f"IMAGE without the token answered {code} {text!r}, expected 5 (access denied)")
    check(raw.closed_by_server(), "the connection stayed open after a large body without the token")
    raw.close()
    check(http_json(f"{http}/api/scene")["volumes"][0] == before, "the scene changed after a refused IMAGE")
    print(f"igtl_client: IMAGE without the token refused: {text}")
    raw = Raw(host, port)

    # 4. A wrong token is refused, the right one accepted; then the IMAGE loads.
    raw.send(pyigtl.StringMessage("token not-the-token", device_name="Login"))
    code, _ = raw.status("Login")
    check(code == 5, f"a wrong token answered {code}, expected 5")
    raw.send(pyigtl.StringMessage(f"token {token}", device_name="Login"))
    code, text = raw.status("Login")
    check(code == 1, f"the right token answered {code} {text!r}, expected 1")
    raw.send(image)
    code, text = raw.status("Ball", timeout=30)
    check(code == 1, f"IMAGE with the token answered {code} {text!r}, expected 1")
    volume = http_json(f"{http}/api/scene")["volumes"][0]
    check(volume["dims"] == [ni, nj, nk], f"loaded volume dims {volume['dims']}, expected {[ni, nj, nk]}")
    expected_min = origin_mm / 1000.0
    expected_max = (origin_mm + spacing * np.array([ni - 1, nj - 1, nk - 1])) / 1000.0
    check(np.allclose(volume["min_m"], expected_min, atol=1e-6) and np.allclose(volume["max_m"], expected_max, atol=1e-6),
          f"loaded bounds {volume['min_m']} .. {volume['max_m']} m, expected {expected_min} .. {expected_max}")
    print(f"igtl_client: IMAGE loaded: {text}")
    raw.close()

    # 5. ProbeTarget in free space: Probe (mm) equals the HTTP probe_m x 1000 once settled.
    raw = Raw(host, port)
    raw.send(pyigtl.StringMessage(f"token {token}", device_name="Login"))
    check(raw.status("Login")[0] == 1, "token refused on a second connection")
    target = np.array([0.0, 0.0, 40.0])  # 40 mm above the ball, outside the volume
    message = pyigtl.TransformMessage(np.eye(4), device_name="ProbeTarget")
    message.matrix[0:3, 3] = target
    raw.send(message)
    time.sleep(2.5)
    raw.close()
    raw = Raw(host, port)
    frame = latest_frame(raw)
    state = http_json(f"{http}/api/state")
    probe_mm = frame["Probe"][1]
    check(np.linalg.norm(probe_mm - target) < 3.0, f"Probe {probe_mm} mm is not near the target {target} mm")
    check(np.allclose(probe_mm, np.array(state["probe_m"]) * 1000.0, atol=0.5),
          f"IGTL Probe {probe_mm} mm against HTTP probe_m {state['probe_m']} m")
    check(np.allclose(state["hand_target_m"], target / 1000.0), f"hand target {state['hand_target_m']}")
    print(f"igtl_client: RAS millimetres OK: Probe {probe_mm} mm, HTTP probe_m {state['probe_m']} m")

    # 7 (first, while the scene is as left by 5). No lockout: 16 idle connections, then pyigtl's client.
    idle = [socket.create_connection((host, port), timeout=5) for _ in range(16)]
    time.sleep(0.5)
    client = pyigtl.OpenIGTLinkClient(host=host, port=port)
    probe = client.wait_for_message("Probe", timeout=10)
    check(probe is not None, "with 16 idle connections open, pyigtl's client received no Probe within 10 s")
    client.stop()
    for sock in idle:
        sock.close()
    print("igtl_client: 16 idle connections did not lock out pyigtl's client")

    # 6. Pressed into the ball: Force = k (Proxy - Probe), newtons, RAS.
    k_n_per_m = http_json(f"{http}/api/scene")["stiffness_n_per_m"]
    raw.close()
    control = Raw(host, port)
    # Lower the hand onto the ball's top in 1 mm steps (a drop from far above would carry the arm through
    # the surface, whose strength is at most 2 N), to 5 mm under the surface (value 0.5 at 13 mm from the
    # centre): the hand's 300 N/m spring against k = 500 N/m leaves about 1 N on the surface.
    for z_mm in [20.0, 20.0, 20.0] + list(np.arange(19.0, 7.5, -1.0)):
        v3 = pyigtl.TransformMessage(np.eye(4), device_name="ProbeTarget")
        v3.header_version = 2
        v3.metadata = {"token": token}
        v3.matrix[0:3, 3] = [0.0, 0.0, z_mm]
        control.send(v3)
        frames_for(control, 0.25)
    frame, version = frames_for(control, 3.0)
    check(version == 2, f"a client speaking header version 2 still gets version {version}")
    force_n = frame["Force"][1]
    expected = k_n_per_m * (frame["Proxy"][1] - frame["Probe"][1]) / 1000.0
    check(np.linalg.norm(force_n) > 0.3, f"no force inside the ball: {force_n} N")
    check(np.linalg.norm(force_n - expected) < 0.05 + 0.05 * np.linalg.norm(expected),
          f"Force {force_n} N, expected k (Proxy - Probe) = {expected} N")
    check(force_n[2] > 0, f"the ball's top should push up (+S), got {force_n} N")
    control.close()
    print(f"igtl_client: Force OK: {force_n} N = k (Proxy - Probe) {expected} N; protocol 3 metadata token OK")
    print("igtl_client: OK")


if __name__ == "__main__":
    main()
