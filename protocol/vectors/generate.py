#!/usr/bin/env python3
"""Writes the protocol test vectors (*.hex) from SPEC.md's tables.

This is a second implementation of the wire format, independent of the Rust crate (its own CRC, COBS and field
packing with `struct`), so that the Rust tests, which check these files both ways, compare two readings of the spec.
Run from anywhere: `python3 protocol/vectors/generate.py`. Output is deterministic; commit the .hex files.
"""
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))


def crc16_ccitt_false(data):
    """Bitwise CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


assert crc16_ccitt_false(b"123456789") == 0x29B1


def cobs_encode(data):
    out = bytearray()
    block = bytearray()
    for byte in data:
        if byte == 0:
            out.append(len(block) + 1)
            out += block
            block = bytearray()
        else:
            block.append(byte)
            if len(block) == 254:
                out.append(255)
                out += block
                block = bytearray()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def serial_frame(msg_type, payload):
    body = bytes([msg_type]) + payload
    return cobs_encode(body + struct.pack("<H", crc16_ccitt_false(body))) + b"\x00"


def hid_report(report_id, msg_type, payload):
    report = bytes([report_id, msg_type]) + payload
    assert len(report) <= 64
    return report + bytes(64 - len(report))


def label(text):
    raw = text.encode("ascii")
    assert len(raw) <= 12
    return raw + bytes(12 - len(raw))


HOST, DEVICE = 0x01, 0x02  # HID report ids by direction

VECTORS = [
    ("hello", HOST, 0x01, struct.pack("<BB", 1, 1), "Hello: protocol version 1.1"),
    # SPEC section 2: a 1.1 device accepts a 1.0 host's Hello (same major) and a 1.1 host a 1.0 device's
    # DeviceInfo, so both 1.0 forms stay valid vectors.
    ("hello_v1_0", HOST, 0x01, struct.pack("<BB", 1, 0), "Hello: protocol version 1.0 (an older host)"),
    ("enable", HOST, 0x02, struct.pack("<I", 50_000), "Enable: watchdog timeout 50000 us"),
    ("disable", HOST, 0x03, b"", "Disable: no payload"),
    (
        "set_force",
        HOST,
        0x04,
        struct.pack("<I3fH", 7, 0.5, -1.25, 2.0, 0x0001),
        "SetForce: sequence 7, force (0.5, -1.25, 2.0) N, flags REQUEST_STATE (0x0001)",
    ),
    ("heartbeat", HOST, 0x05, struct.pack("<I", 42), "Heartbeat: counter 42"),
    ("clear_fault", HOST, 0x06, b"", "ClearFault: no payload"),
    ("set_state_rate", HOST, 0x07, struct.pack("<H", 1000), "SetStateRate: 1000 Hz"),
    (
        "device_info",
        DEVICE,
        0x81,
        struct.pack("<BB", 1, 1)
        + label("voxhap-sim")
        + label("SN0001")
        + struct.pack("<BBBB", 3, 3, 2, 0b0001_1100)
        + struct.pack("<3f3fff", -0.08, -0.06, -0.05, 0.08, 0.06, 0.05, 8.5, 2000.0),
        "DeviceInfo: v1.1, model voxhap-sim, serial SN0001, 3 position DOF, 3 force DOF, 2 buttons, "
        "rates {250, 500, 1000} Hz, workspace (-0.08, -0.06, -0.05)..(0.08, 0.06, 0.05) m, 8.5 N, 2000 N/m",
    ),
    (
        "device_info_v1_0",
        DEVICE,
        0x81,
        struct.pack("<BB", 1, 0)
        + label("voxhap-sim")
        + label("SN0001")
        + struct.pack("<BBBB", 3, 3, 2, 0b0001_1100)
        + struct.pack("<3f3fff", -0.08, -0.06, -0.05, 0.08, 0.06, 0.05, 8.5, 2000.0),
        "DeviceInfo: v1.0 (an older device), model voxhap-sim, serial SN0001, 3 position DOF, 3 force DOF, 2 buttons, "
        "rates {250, 500, 1000} Hz, workspace (-0.08, -0.06, -0.05)..(0.08, 0.06, 0.05) m, 8.5 N, 2000 N/m",
    ),
    (
        "state",
        DEVICE,
        0x82,
        struct.pack("<IQ3f3fIHHH", 1000, 1_234_567_890_123, 0.01, -0.02, 0.03, 0.1, 0.0, -0.25, 999, 0b01, 0x0003, 0),
        "State: sequence 1000, device time 1234567890123 us, position (0.01, -0.02, 0.03) m, velocity "
        "(0.1, 0.0, -0.25) m/s, last force sequence 999, buttons 0b01, status SESSION_OPEN|ENABLED, no faults",
    ),
    (
        "heartbeat_reply",
        DEVICE,
        0x83,
        struct.pack("<IQH", 42, 5_000_000, 0x0021),
        "HeartbeatReply: counter 42, device time 5000000 us, status SESSION_OPEN|LOCKSTEP",
    ),
    (
        "fault_watchdog",
        DEVICE,
        0x84,
        struct.pack("<BHQ", 0, 0, 75_000),
        "Fault: code 0 WATCHDOG_EXPIRED, no latched faults, device time 75000 us",
    ),
    (
        "fault_over_current",
        DEVICE,
        0x84,
        struct.pack("<BHQ", 3, 0b1010, 2_000_000),
        "Fault: code 3 OVER_CURRENT, latched faults OVER_CURRENT|EMERGENCY_STOP (0x000a), device time 2000000 us",
    ),
    ("rejected", DEVICE, 0x85, struct.pack("<BB", 0x02, 3), "Rejected: message type 0x02 (enable), reason 3 FAULTED"),
]


def oct_encode(direction):
    """SPEC section 10.3: octahedral unit vector, 16 bits a component (an independent reading of the text)."""
    x, y, z = direction
    l1 = abs(x) + abs(y) + abs(z)
    x, y, z = x / l1, y / l1, z / l1
    if z < 0:
        x, y = (1 - abs(y)) * (1 if x >= 0 else -1), (1 - abs(x)) * (1 if y >= 0 else -1)

    def q(c):
        r = c * 32767
        return int(r + 0.5) if r >= 0 else -int(-r + 0.5)

    return q(x), q(y)


def local_model(sequence, expiry_us, flags, stiffness, damping_mns, limit_mn, anchor, slots):
    """SPEC section 10.2: the 62-byte LocalModel payload; slots are (kind, offset_um, direction or None, strength_mn)."""
    kinds = 0
    body = b""
    for i in range(3):
        if i < len(slots):
            kind, offset, direction, strength = slots[i]
            kinds |= kind << (3 * i)
            oct_uv = oct_encode(direction) if direction else (0, 0)
            body += struct.pack("<3h2hH", *offset, *oct_uv, strength)
        else:
            body += bytes(12)
    head = struct.pack("<IHHHHH3f", sequence, expiry_us, flags | kinds, stiffness, damping_mns, limit_mn, *anchor)
    payload = head + body
    assert len(payload) == 62
    return payload


DIRECTED, POINT, LINE, PLANE = 1, 2, 3, 4
TRUNCATED = 0x8000
# SPEC section 10.2, kinds_flags bits 9-10: the device's passivity mode; bits 11-13: its most damping as a code c,
# 1.25 * 2**c N s/m.
PASSIVITY_OFF, PASSIVITY_OBSERVE, PASSIVITY_CONTROL = 0, 1, 2


def passivity(mode, damping_code):
    return (mode << 9) | (damping_code << 11)


# The optional local-model capability (SPEC section 10): in vectors/local/, so that a firmware without the
# capability checks the top folder alone.
LOCAL_VECTORS = [
    (
        "local_model",
        HOST,
        0x08,
        local_model(
            1234, 5000, TRUNCATED, 20000, 2500, 4000, (0.01, -0.02, 0.03),
            [
                (DIRECTED, (0, 0, 0), (-1.0, 0.0, 0.0), 250),
                (PLANE, (0, 0, -150), (0.0, 0.6, -0.8), 10000),
                (POINT, (100, -200, 300), None, 1500),
            ],
        ),
        "LocalModel: sequence 1234, expiry 5000 us, flags TRUNCATED, stiffness 20000 N/m, damping 2.5 N s/m, "
        "force limit 4.0 N, anchor (0.01, -0.02, 0.03) m; slot 0 directed (-1, 0, 0) 0.25 N; slot 1 plane at offset "
        "(0, 0, -150) um, normal (0, 0.6, -0.8), 10 N; slot 2 point at offset (100, -200, 300) um, 1.5 N",
    ),
    (
        "local_model_empty",
        HOST,
        0x08,
        local_model(7, 1000, 0, 1, 0, 0, (0.0, 0.0, 0.0), []),
        "LocalModel: sequence 7, expiry 1000 us, no flags, stiffness 1 N/m, damping 0, force limit 0 N, anchor "
        "(0, 0, 0) m, no primitives (free space)",
    ),
    (
        "local_model_wall",
        HOST,
        0x08,
        local_model(1, 5000, 0, 2000, 0, 3000, (0.0, 0.0, 0.0), [(PLANE, (0, 0, 0), (0.0, 0.0, 1.0), 20000)]),
        "LocalModel: sequence 1, expiry 5000 us, no flags, stiffness 2000 N/m, damping 0, force limit 3.0 N, anchor "
        "(0, 0, 0) m; slot 0 plane at offset (0, 0, 0) um, normal (0, 0, 1), 20 N (a floor at z = 0: by SPEC 10.5 a "
        "handle 0.5 mm below it feels 1.0 N up, one 2 mm below 4 N clamped to the 3 N limit)",
    ),
    (
        "local_model_passivity",
        HOST,
        0x08,
        local_model(
            2, 5000, passivity(PASSIVITY_CONTROL, 4), 40000, 0, 3000, (0.0, 0.0, 0.0),
            [(PLANE, (0, 0, 0), (0.0, 0.0, 1.0), 20000)],
        ),
        "LocalModel: sequence 2, expiry 5000 us, passivity control with damping code 4 (at most 1.25 * 2^4 = "
        "20 N s/m), stiffness 40000 N/m, damping 0, force limit 3.0 N, anchor (0, 0, 0) m; slot 0 plane at offset "
        "(0, 0, 0) um, normal (0, 0, 1), 20 N (a floor at z = 0 twice as stiff as the exact zero-order-hold "
        "boundary of a 0.1 kg, 1 N s/m arm at 10 kHz, 20 003 N/m)",
    ),
    (
        "local_state",
        DEVICE,
        0x86,
        struct.pack(
            "<III3f3ffffHH", 1000, 1234, 700, 0.01, -0.02, 0.0298, 0.0, 0.0, 3.5, 1e-9, 2e-9, 3.75, 0x0009, 10
        ),
        "LocalState: state sequence 1000, model sequence 1234, model age 700 us, proxy (0.01, -0.02, 0.0298) m, "
        "force (0, 0, 3.5) N, bound 1e-9 m, worst bound 2e-9 m, peak force 3.75 N, status ACTIVE|CLAMPED, 10 solves",
    ),
    (
        "local_state_dissipating",
        DEVICE,
        0x86,
        struct.pack(
            "<III3f3ffffHH", 1001, 2, 300, 0.0, 0.0, 0.0, 0.0, 0.0, 0.75, 0.0, 5e-8, 1.25, 0x0081, 10
        ),
        "LocalState: state sequence 1001, model sequence 2, model age 300 us, proxy (0, 0, 0) m, force (0, 0, 0.75) N, "
        "bound 0 m, worst bound 5e-8 m, peak force 1.25 N, status ACTIVE|DISSIPATING (the passivity controller "
        "added a force in a cycle since the previous LocalState), 10 solves",
    ),
]


def hex_bytes(data):
    return " ".join(f"{b:02x}" for b in data)


def main():
    os.makedirs(os.path.join(HERE, "local"), exist_ok=True)
    for name, report_id, msg_type, payload, description in VECTORS + [
        (os.path.join("local", v[0]),) + v[1:] for v in LOCAL_VECTORS
    ]:
        path = os.path.join(HERE, f"{name}.hex")
        with open(path, "w") as f:
            f.write(f"# {description}\n")
            f.write(f"serial: {hex_bytes(serial_frame(msg_type, payload))}\n")
            f.write(f"hid: {hex_bytes(hid_report(report_id, msg_type, payload))}\n")
    print(f"wrote {len(VECTORS) + len(LOCAL_VECTORS)} vectors to {HERE}")


if __name__ == "__main__":
    main()
