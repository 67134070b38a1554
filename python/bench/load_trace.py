"""Times loading a voxhap trace into pandas (issue 15: a one-hour 1 kHz trace, 3.6 M rows, in under 5 s).

Usage: python load_trace.py TRACE [--max-seconds S] [--repeat N]

Prints the rows, the file size and the median wall time of N loads (pandas.read_parquet with pyarrow for
.parquet, pandas.read_csv otherwise). With --max-seconds it exits 1 when the median exceeds S. Run by
.ci/check-python.sh on a trace written by `voxhap sim ... --duration 3600`.
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace")
    parser.add_argument("--max-seconds", type=float, default=None)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    times = []
    rows = 0
    for _ in range(args.repeat):
        start = time.perf_counter()
        frame = load(args.trace)
        times.append(time.perf_counter() - start)
        rows = len(frame)
        # Touch the columns an analysis would use, so lazy conversions are counted.
        assert frame["flag_solver_budget_hit"].dtype == bool
        assert frame["force_z_n"].dtype == "float64"
    median = statistics.median(times)
    size_mb = os.path.getsize(args.trace) / 1e6
    print(
        f"{args.trace}: {rows} rows, {size_mb:.1f} MB, pandas {pd.__version__} load median {median:.2f} s "
        f"over {args.repeat} (min {min(times):.2f} s, max {max(times):.2f} s)"
    )
    if args.max_seconds is not None and median > args.max_seconds:
        print(f"FAIL: median {median:.2f} s > {args.max_seconds} s", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
