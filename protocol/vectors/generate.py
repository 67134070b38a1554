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
    ("hello", HOST, 0x01, struct.pack("<BB", 1, 0), "Hello: protocol version 1.0"),
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
        struct.pack("<BB", 1, 0)
        + label("voxhap-sim")
        + label("SN0001")
        + struct.pack("<BBBB", 3, 3, 2, 0b0001_1100)
        + struct.pack("<3f3fff", -0.08, -0.06, -0.05, 0.08, 0.06, 0.05, 8.5, 2000.0),
        "DeviceInfo: v1.0, model voxhap-sim, serial SN0001, 3 position DOF, 3 force DOF, 2 buttons, "
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


def hex_bytes(data):
    return " ".join(f"{b:02x}" for b in data)


def main():
    for name, report_id, msg_type, payload, description in VECTORS:
        path = os.path.join(HERE, f"{name}.hex")
        with open(path, "w") as f:
            f.write(f"# {description}\n")
            f.write(f"serial: {hex_bytes(serial_frame(msg_type, payload))}\n")
            f.write(f"hid: {hex_bytes(hid_report(report_id, msg_type, payload))}\n")
    print(f"wrote {len(VECTORS)} vectors to {HERE}")


if __name__ == "__main__":
    main()
