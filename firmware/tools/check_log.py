#!/usr/bin/env python3
"""Checks a firmware's event log (firmware/ports/common/fwlog.h format) against protocol/SPEC.md.

The log is what the firmware received (S, M lines), the replies it sent other than State (T), the force it wrote
to its motors every control cycle (A) and port events (X). This script re-derives, from the messages alone and
the SPEC's rules, when the device may apply force (its own model of section 6: session, drive, watchdog, faults),
and checks the firmware against that model and the host against its promises (section 7.1):

firmware (device side)
  - every force written is finite, at most max_force_n (1e-6 relative, section 6.2), and no longer than the
    force the host last commanded (clamped);
  - non-zero only while Enabled; zero from the control cycle in which the watchdog timeout has passed (the Fault
    with code 0 comes in that same cycle), after any Fault, Disable or Hello;
  - the rise of |force| between control cycles is at most --max-rise N/s (the firmware's slew limit);
host (as seen by the device)
  - every SetForce is finite and at most max_force_n; |force| rises at most 0.5 N/ms, i.e. 0.5 N per SetForce at
    --host-rate 1000 Hz (a gap in the sequence allows as much again per missing SetForce);
  - Enable only after a SetForce in each session; never ClearFault unless --operator-clears;
  - at most 4 non-zero SetForce in a row to a device that is not Enabled (the one in flight, plus a State used for
    at most 3 periods: section 7.1);
  - on a stop: a zero SetForce, then Disable.
--expect adds scenario checks: engaged, watchdog, reconnect, fault, garbage, stopped.

Usage: check_log.py LOG --max-force N [--max-rise N_PER_S] [--host-rate HZ] [--expect a,b,c] [--operator-clears]
Exit status 0 when every check holds; 1 with one line per failure (the first 20) otherwise.
"""
import argparse
import math
import struct
import sys

HELLO, ENABLE, DISABLE, HEARTBEAT, CLEAR_FAULT, SET_STATE_RATE = 0x01, 0x02, 0x03, 0x05, 0x06, 0x07
DEVICE_INFO, HEARTBEAT_REPLY, FAULT, REJECTED = 0x81, 0x83, 0x84, 0x85
HOST_SLEW_N_PER_MS = 0.5
SLEW_MARGIN_N = 0.01
NOT_ENABLED_RUN_LIMIT = 4


def f32(hex_bits):
    return struct.unpack("<f", struct.pack("<I", int(hex_bits, 16)))[0]


def norm(v):
    return math.sqrt(sum(float(x) * float(x) for x in v))


class Checker:
    def __init__(self, max_force, max_rise, operator_clears, host_rate_hz=1000.0):
        self.slew_per_setforce = HOST_SLEW_N_PER_MS * 1000.0 / host_rate_hz
        self.max_force = max_force
        self.max_rise = max_rise
        self.operator_clears = operator_clears
        self.failures = []
        self.counts = dict(setforce=0, applied=0, nonzero_applied=0, hellos=0, enables=0, disables=0,
                           watchdog_trips=0, latching_faults=0, rejected=0, resets=0, garbage=0, device_infos=0,
                           heartbeats=0, clear_faults=0)
        self.max_applied = 0.0
        self.max_commanded = 0.0
        self.events = []  # (line number, kind) in order, for the scenario checks
        self.reset(0)

    def fail(self, line_no, text):
        self.failures.append(f"line {line_no}: {text}")

    def reset(self, t):
        self.session_open = False
        self.drive = "idle"
        self.faults = 0
        self.timeout = 50_000
        self.last_feed = t
        self.commanded = 0.0  # |clamped force| of the last applied SetForce
        self.prev_applied = 0.0
        self.prev_applied_t = None
        self.prev_s = None  # (seq, |f|) of the previous SetForce in this session
        self.setforce_since_hello = 0
        self.not_enabled_run = 0

    def expired(self, t):
        return self.drive == "enabled" and t > self.last_feed and t - self.last_feed > self.timeout

    def line(self, n, parts):
        kind, t = parts[0], int(parts[1])
        if kind == "X":
            event = parts[2]
            if event == "reset":
                self.reset(t)
                self.counts["resets"] += 1
            elif event.startswith("garbage"):
                self.counts["garbage"] += 1
            self.events.append((n, "X " + event))
        elif kind == "M":
            self.message(n, t, int(parts[2], 16), int(parts[3]))
        elif kind == "S":
            self.set_force(n, t, int(parts[2]), [f32(x) for x in parts[3:6]], parts[3:6])
        elif kind == "T":
            self.reply(n, t, int(parts[2], 16), int(parts[3]), int(parts[4]))
        elif kind == "A":
            self.applied(n, t, [f32(x) for x in parts[2:5]])
        else:
            self.fail(n, f"unknown line kind {kind!r}")

    def message(self, n, t, mtype, arg):
        if mtype == HELLO:
            self.counts["hellos"] += 1
            if self.drive == "enabled":
                self.drive = "idle"
            self.session_open = (arg >> 8) == 1
            self.timeout = 50_000
            self.prev_s = None
            self.setforce_since_hello = 0
            self.events.append((n, "hello"))
        elif mtype == ENABLE:
            self.counts["enables"] += 1
            if self.setforce_since_hello == 0:
                self.fail(n, "Enable before any SetForce of this session (SPEC 7.1 step 4: never before SetForce 1)")
            valid = arg == 0 or 1_000 <= arg <= 1_000_000
            if self.session_open and self.drive != "faulted" and valid:
                self.drive = "enabled"
                self.timeout = arg or 50_000
                self.last_feed = t
                self.commanded = 0.0
                self.events.append((n, "enable"))
        elif mtype == DISABLE:
            self.counts["disables"] += 1
            if self.session_open and self.drive == "enabled":
                self.drive = "idle"
            self.events.append((n, "disable"))
        elif mtype == CLEAR_FAULT:
            self.counts["clear_faults"] += 1
            if not self.operator_clears:
                self.fail(n, "the host sent ClearFault by itself (SPEC 7.1: only on the operator's command)")
            if self.session_open and self.drive == "faulted":
                self.drive = "idle"
                self.faults = 0
        elif mtype == HEARTBEAT:
            self.counts["heartbeats"] += 1

    def set_force(self, n, t, seq, force, raw):
        self.counts["setforce"] += 1
        if not all(math.isfinite(x) for x in force):
            self.fail(n, f"non-finite SetForce {raw}")
            return
        mag = norm(force)
        self.max_commanded = max(self.max_commanded, mag)
        if mag > self.max_force * (1 + 1e-6):
            self.fail(n, f"SetForce |f| = {mag:.6g} N above max_force_n {self.max_force} N")
        if self.session_open and self.prev_s is not None:
            prev_seq, prev_mag = self.prev_s
            gap = max(1, (seq - prev_seq) % (1 << 32))
            if gap < (1 << 31) and mag - prev_mag > self.slew_per_setforce * gap + SLEW_MARGIN_N:
                self.fail(n, f"|SetForce| rose {mag - prev_mag:.4g} N over {gap} SetForce (host slew limit 0.5 N/ms: "
                             f"{self.slew_per_setforce:g} N per SetForce)")
        if self.session_open:
            self.prev_s = (seq, mag)
            self.setforce_since_hello += 1
        enabled = self.session_open and self.drive == "enabled"
        if mag > 0 and not enabled:
            self.not_enabled_run += 1
            if self.not_enabled_run > NOT_ENABLED_RUN_LIMIT:
                self.fail(n, f"{self.not_enabled_run} non-zero SetForce in a row to a device that is not Enabled")
        else:
            self.not_enabled_run = 0
        if enabled:
            self.commanded = min(mag, self.max_force)
            self.last_feed = t

    def reply(self, n, t, rtype, a, b):
        if rtype == FAULT:
            if a == 0:
                self.counts["watchdog_trips"] += 1
                if not self.expired(t):
                    self.fail(n, f"watchdog Fault at {t} us, but {t - self.last_feed} us since the last feed "
                                 f"(timeout {self.timeout} us, drive {self.drive})")
                if self.drive == "enabled":
                    self.drive = "idle"
                self.events.append((n, "watchdog"))
            else:
                self.counts["latching_faults"] += 1
                self.drive = "faulted"
                self.faults |= 1 << a
                if b != self.faults:
                    self.fail(n, f"Fault({a}) reports active faults {b:#06x}, expected {self.faults:#06x}")
                self.events.append((n, f"fault {a}"))
        elif rtype == REJECTED:
            self.counts["rejected"] += 1
            self.events.append((n, f"rejected {a:#04x} {b}"))
        elif rtype == DEVICE_INFO:
            self.counts["device_infos"] += 1

    def applied(self, n, t, force):
        self.counts["applied"] += 1
        if not all(math.isfinite(x) for x in force):
            self.fail(n, f"non-finite force written to the motors {force}")
            return
        mag = norm(force)
        self.max_applied = max(self.max_applied, mag)
        if self.expired(t):
            self.fail(n, f"watchdog: {t - self.last_feed} us since the last SetForce (timeout {self.timeout} us) "
                         "and no Fault(WATCHDOG_EXPIRED) in this control cycle")
            self.drive = "idle"
        if mag > 0:
            self.counts["nonzero_applied"] += 1
            if not (self.session_open and self.drive == "enabled"):
                self.fail(n, f"force {mag:.4g} N written while the device is {self.drive} "
                             f"(session {'open' if self.session_open else 'closed'})")
            if mag > self.max_force * (1 + 1e-6):
                self.fail(n, f"force {mag:.6g} N written above max_force_n {self.max_force} N")
            if mag > self.commanded * (1 + 1e-6) + 1e-9:
                self.fail(n, f"force {mag:.6g} N written, longer than the commanded {self.commanded:.6g} N")
        if self.max_rise > 0 and self.prev_applied_t is not None:
            dt = min(t - self.prev_applied_t, 10_000) * 1e-6
            allowed = self.max_rise * dt * (1 + 1e-5) + 1e-6
            if mag - self.prev_applied > allowed:
                self.fail(n, f"|force| rose {mag - self.prev_applied:.4g} N in {dt * 1e6:.0f} us "
                             f"(slew limit {self.max_rise} N/s allows {allowed:.4g} N)")
        self.prev_applied = mag
        self.prev_applied_t = t
        if mag > 0:
            self.events.append((n, "force"))

    def expect(self, what):
        ev = self.events

        def after(index, kind):
            return next((i for i in range(index + 1, len(ev)) if ev[i][1] == kind), None)

        def last(kind):
            return max((i for i in range(len(ev)) if ev[i][1] == kind), default=None)

        if what == "engaged":
            if self.counts["nonzero_applied"] == 0:
                self.failures.append("expected engaged: no non-zero force was ever written")
        elif what == "watchdog":
            i = last("watchdog")
            if i is None:
                self.failures.append("expected a watchdog trip: none logged")
            elif after(i, "enable") is None or after(after(i, "enable"), "force") is None:
                self.failures.append("expected Enable and force again after the last watchdog trip")
        elif what == "reconnect":
            i = last("X reset")
            if i is None or self.counts["resets"] < 2:
                self.failures.append("expected a reset: fewer than 2 resets logged")
            else:
                h = after(i, "hello")
                e = after(h, "enable") if h is not None else None
                if e is None or after(e, "force") is None:
                    self.failures.append("expected Hello, Enable and force after the last reset")
        elif what == "fault":
            faults = [i for i in range(len(ev)) if ev[i][1].startswith("fault ")]
            injected = last("X fault")
            if injected is None or not faults or faults[-1] < injected:
                self.failures.append("expected a latching Fault after the injected fault")
            elif after(faults[-1], "force") is not None:
                self.failures.append("force written after the latching fault")
        elif what == "garbage":
            if self.counts["garbage"] == 0:
                self.failures.append("expected garbage bursts: none logged")
            else:
                first = next(i for i in range(len(ev)) if ev[i][1].startswith("X garbage"))
                if after(first, "force") is None:
                    self.failures.append("no force after the first garbage burst")
        elif what == "stopped":
            pass  # checked in main (needs the raw S lines)
        else:
            self.failures.append(f"unknown --expect {what!r}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--max-force", type=float, required=True, help="the device's max_force_n, N")
    ap.add_argument("--max-rise", type=float, default=0.0, help="the firmware's slew limit, N/s (0: not checked)")
    ap.add_argument("--host-rate", type=float, default=1000.0, help="the host's servo rate, Hz (default 1000)")
    ap.add_argument("--expect", default="", help="comma-separated: engaged,watchdog,reconnect,fault,garbage,stopped")
    ap.add_argument("--operator-clears", action="store_true", help="an operator may have sent clear_fault")
    args = ap.parse_args()
    c = Checker(args.max_force, args.max_rise, args.operator_clears, args.host_rate)
    last_s = None  # (line, |f|) of the last SetForce
    stop_ok = None
    with open(args.log, encoding="ascii", errors="replace") as f:
        for n, text in enumerate(f, 1):
            if not text.endswith("\n"):
                break  # a last line cut off when the device was stopped mid-write
            parts = text.split()
            if not parts:
                continue
            try:
                c.line(n, parts)
            except (IndexError, ValueError) as e:
                c.fail(n, f"unreadable line {text.strip()!r}: {e}")
                continue
            if parts[0] == "S":
                last_s = (n, norm(f32(x) for x in parts[3:6]))
            elif parts[0] == "M" and int(parts[2], 16) == DISABLE:
                stop_ok = last_s is not None and last_s[1] == 0.0
    expects = [e for e in args.expect.split(",") if e]
    for e in expects:
        c.expect(e)
    if "stopped" in expects and not stop_ok:
        c.failures.append("expected a stop: the last Disable does not follow a zero SetForce")
    counts = ", ".join(f"{k} {v}" for k, v in c.counts.items())
    print(f"check_log: {args.log}: {counts}; max |SetForce| {c.max_commanded:.4f} N, max |applied| "
          f"{c.max_applied:.4f} N")
    if c.failures:
        for line in c.failures[:20]:
            print(f"check_log: FAILED: {line}")
        if len(c.failures) > 20:
            print(f"check_log: ... and {len(c.failures) - 20} more")
        return 1
    print(f"check_log: every check passed{' (expected: ' + ', '.join(expects) + ')' if expects else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
