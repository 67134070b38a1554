"""Times loading a voxhap trace into pandas: pandas' own reader, and `voxhap.read_trace` beside it.

Usage: python load_trace.py TRACE [--max-seconds S] [--repeat N] [--read-trace] [--max-ratio R]

Prints the rows, the file size and the median wall time of N loads with pandas' own reader
(`pandas.read_parquet` with pyarrow for .parquet, `pandas.read_csv` otherwise). With --max-seconds it exits 1
when that median exceeds S. With --read-trace it also times `voxhap.read_trace` on the same file, the two
loads taking turns (so both see the same machine load), prints both medians and their ratio, and with
--max-ratio exits 1 when read_trace's median is more than R times pandas'. Run by .ci/check-python.sh on a
trace written by `voxhap sim`, and by .ci/check-parquet-pandas.sh on an hour-long one.
"""

import argparse
import os
import statistics
import sys
import time

import pandas as pd


def load(path):
    if path.endswith(".parquet"):
        return pd.read_parquet(path, engine="pyarrow")
    return pd.read_csv(path)


def timed(function, path):
    start = time.perf_counter()
    frame = function(path)
    elapsed = time.perf_counter() - start
    # Touch the columns an analysis would use, so lazy conversions are counted.
    assert frame["flag_solver_budget_hit"].dtype == bool
    assert frame["force_z_n"].dtype == "float64"
    return elapsed, len(frame)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace")
    parser.add_argument("--max-seconds", type=float, default=None)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--read-trace", action="store_true")
    parser.add_argument("--max-ratio", type=float, default=None)
    args = parser.parse_args()
    readers = [("pandas", load)]
    if args.read_trace:
        import voxhap

        readers.append(("voxhap.read_trace", voxhap.read_trace))
    times = {name: [] for name, _ in readers}
    rows = 0
    for _ in range(args.repeat):
        for name, function in readers:
            elapsed, rows = timed(function, args.trace)
            times[name].append(elapsed)
    size_mb = os.path.getsize(args.trace) / 1e6
    medians = {name: statistics.median(values) for name, values in times.items()}
    for name, values in times.items():
        print(
            f"{args.trace}: {rows} rows, {size_mb:.1f} MB, {name} (pandas {pd.__version__}) load median "
            f"{medians[name]:.2f} s over {args.repeat} (min {min(values):.2f} s, max {max(values):.2f} s)"
        )
    status = 0
    if args.max_seconds is not None and medians["pandas"] > args.max_seconds:
        print(f"FAIL: median {medians['pandas']:.2f} s > {args.max_seconds} s", file=sys.stderr)
        status = 1
    if args.read_trace:
        ratio = medians["voxhap.read_trace"] / medians["pandas"]
        print(f"{args.trace}: voxhap.read_trace / pandas = {ratio:.2f} (medians; load average {os.getloadavg()[0]:.1f})")
        if args.max_ratio is not None and ratio > args.max_ratio:
            print(f"FAIL: read_trace takes {ratio:.2f} times pandas' time > {args.max_ratio}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
