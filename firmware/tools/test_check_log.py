#!/usr/bin/env python3
"""check_log.py must catch what it claims to: each case is a short hand-written log (times in us, forces as f32
bits) built from SPEC rules, run through the checker; the clean session must pass, each broken one must fail
naming its rule. Run: python3 firmware/tools/test_check_log.py (check-firmware.sh runs it)."""
import os
import struct
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def bits(x):
    return struct.unpack("<I", struct.pack("<f", x))[0]


def f3(x, y=0.0, z=0.0):
    return f"{bits(x):08x} {bits(y):08x} {bits(z):08x}"


ZERO = f3(0.0)

# A clean session: reset, Hello, SetForce 1 (zero), Enable(50 ms), forces ramping 0.4 N per ms, zero, Disable.
CLEAN = [
    "X 0 reset 5",
    "M 1000 01 256",
    "T 1000 81 0 0",
    f"S 2000 1 {ZERO} 0",
    f"A 2000 {ZERO}",
    "M 3000 02 50000",
    f"A 3000 {ZERO}",
    f"S 4000 2 {f3(0.4)} 0",
    f"A 4000 {f3(0.4)}",
    f"S 5000 3 {f3(0.8)} 0",
    f"A 5000 {f3(0.8)}",
    f"S 6000 4 {f3(0.0)} 0",
    f"A 6000 {ZERO}",
    "M 6100 03 0",
    f"A 7000 {ZERO}",
]


def with_lines(replace=None, append=()):
    lines = list(CLEAN)
    for index, line in (replace or {}).items():
        lines[index] = line
    return lines + list(append)


CASES = [
    ("clean session", CLEAN, True, None),
    ("force written above max_force_n", with_lines({8: f"A 4000 {f3(6.0)}"}), False, "above max_force_n"),
    ("force longer than commanded", with_lines({8: f"A 4000 {f3(0.5)}"}), False, "longer than the commanded"),
    ("non-zero force while Idle", with_lines(append=[f"A 8000 {f3(0.1)}"]), False, "written while the device is"),
    ("NaN force written", with_lines({8: "A 4000 7fc00000 00000000 00000000"}), False, "non-finite"),
    ("firmware slew exceeded", with_lines({10: f"A 5000 {f3(1.5)}", 9: f"S 5000 3 {f3(1.5)} 0"}), False,
     "N/s allows"),
    # Enabled at 3000 with 0.8 N applied at 5000; nothing fed it since: at 55 001 us the watchdog is overdue.
    ("watchdog not honoured", CLEAN[:11] + [f"A 55001 {f3(0.8)}"], False, "no Fault(WATCHDOG_EXPIRED)"),
    ("watchdog fired early", CLEAN[:11] + ["T 20000 84 0 0"], False, "watchdog Fault at"),
    ("watchdog fired on time", CLEAN[:11] + ["T 55001 84 0 0", f"A 55001 {ZERO}", f"S 56000 4 {ZERO} 0",
                                             "M 56100 03 0"], True, None),
    ("host ClearFault by itself", with_lines(append=["M 8000 06 0"]), False, "ClearFault"),
    ("Enable before any SetForce", CLEAN[:3] + ["M 1500 02 50000"], False, "Enable before any SetForce"),
    ("stop without a zero SetForce first", with_lines({11: f"S 6000 4 {f3(0.9)} 0", 12: f"A 6000 {f3(0.9)}"}),
     False, "the last Disable does not follow a zero SetForce"),
]


def main():
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name, lines, should_pass, needle in CASES:
            path = os.path.join(tmp, "case.log")
            with open(path, "w") as f:
                f.write("\n".join(lines) + "\n")
            run = subprocess.run(
                [sys.executable, os.path.join(HERE, "check_log.py"), path, "--max-force", "5", "--max-rise", "500",
                 "--expect", "engaged,stopped"],
                capture_output=True, text=True)
            passed = run.returncode == 0
            ok = passed == should_pass and (needle is None or needle in run.stdout)
            if not ok:
                failures += 1
                print(f"test_check_log: FAILED: {name}: expected {'pass' if should_pass else 'a failure naming ' + repr(needle)}, got:\n{run.stdout}")
    if failures:
        print(f"test_check_log: {failures} of {len(CASES)} cases wrong")
        return 1
    print(f"test_check_log: all {len(CASES)} cases judged as expected")
    return 0


if __name__ == "__main__":
    sys.exit(main())
