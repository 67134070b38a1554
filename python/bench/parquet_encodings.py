"""Measures Parquet column encodings and codecs on a voxhap trace: the size of the same rows written each way.

Usage: python parquet_encodings.py TRACE.parquet [--csv TRACE.csv] [--codecs none,snappy,zstd]
       [--expect-best ENCODING/CODEC]

Reads TRACE (a voxhap Parquet trace; use a moving one, where the values change every tick) with pyarrow and
rewrites its rows with pyarrow into a temporary folder (TMPDIR) once per encoding and codec, with voxhap's row groups
(1 048 576 rows), and prints a table: the file size, the size per hour of trace (from the rows and the
sidecar's rate), the ratio to the CSV trace of the same run (--csv) and the ratio to TRACE itself. Encodings:

  plain              every column PLAIN (no dictionary)
  dictionary         dictionary pages for every column (falling back to PLAIN where a dictionary outgrows
                     its page, as every writer does)
  byte_stream_split  the float columns BYTE_STREAM_SPLIT, the others PLAIN
  bss+delta          the float columns BYTE_STREAM_SPLIT, the integer columns DELTA_BINARY_PACKED, text with
                     a dictionary

The last lines name the smallest overall and the smallest among the codecs voxhap's writer is built with
(--writer-codecs, default none,snappy). With --expect-best it exits 1 when the latter is not that one (what
the writer uses). Run by .ci/check-parquet-pandas.sh on a ten-minute
trace of sims/multimodal.toml (the hand circles the ball for the whole hour).
"""

import argparse
import json
import os
import sys
import tempfile

import pyarrow as pa
import pyarrow.parquet as pq

ROW_GROUP_ROWS = 1 << 20
ENCODINGS = ["plain", "dictionary", "byte_stream_split", "bss+delta"]


def options(schema, encoding, codec):
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    integers = [f.name for f in schema if pa.types.is_integer(f.type)]
    texts = [f.name for f in schema if pa.types.is_string(f.type)]
    kw = {"compression": codec, "row_group_size": ROW_GROUP_ROWS}
    if encoding == "plain":
        kw["use_dictionary"] = False
    elif encoding == "dictionary":
        kw["use_dictionary"] = True
    elif encoding == "byte_stream_split":
        kw["use_dictionary"] = False
        kw["column_encoding"] = {name: "BYTE_STREAM_SPLIT" for name in floats}
    elif encoding == "bss+delta":
        kw["use_dictionary"] = texts
        kw["column_encoding"] = {name: "BYTE_STREAM_SPLIT" for name in floats}
        kw["column_encoding"].update({name: "DELTA_BINARY_PACKED" for name in integers})
    return kw


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace")
    parser.add_argument("--csv", default=None)
    parser.add_argument("--codecs", default="none,snappy,zstd")
    parser.add_argument("--writer-codecs", default="none,snappy")
    parser.add_argument("--expect-best", default=None)
    args = parser.parse_args()
    table = pq.read_table(args.trace)
    sidecar = json.loads(pq.ParquetFile(args.trace).metadata.metadata[b"voxhap.sidecar"])
    hours = table.num_rows / sidecar["rate_hz"] / 3600.0
    csv_bytes = os.path.getsize(args.csv) if args.csv else None
    trace_bytes = os.path.getsize(args.trace)
    print(
        f"{args.trace}: {table.num_rows} rows ({hours:.3f} h at {sidecar['rate_hz']:g} Hz), "
        f"{table.num_columns} columns, {trace_bytes / 1e6:.1f} MB"
        + (f"; CSV {csv_bytes / 1e6:.1f} MB" if csv_bytes else "")
        + f" (pyarrow {pa.__version__})"
    )
    print(f"{'encoding':<18} {'codec':<7} {'MB':>9} {'MB/hour':>9} {'CSV/this':>9} {'this/trace':>10}")
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for encoding in ENCODINGS:
            for codec in args.codecs.split(","):
                path = os.path.join(folder, f"{encoding}-{codec}.parquet")
                pq.write_table(table, path, **options(table.schema, encoding, codec))
                size = os.path.getsize(path)
                os.remove(path)
                results.append((size, f"{encoding}/{codec}", codec))
                ratio = f"{csv_bytes / size:9.2f}" if csv_bytes else f"{'-':>9}"
                print(
                    f"{encoding:<18} {codec:<7} {size / 1e6:9.1f} {size / 1e6 / hours:9.1f} {ratio} "
                    f"{size / trace_bytes:10.3f}",
                    flush=True,
                )
    size, best, _ = min(results)
    print(f"smallest: {best} ({size / 1e6:.1f} MB)")
    ours = [r for r in results if r[2] in args.writer_codecs.split(",")]
    if not ours:
        sys.exit(f"none of --writer-codecs {args.writer_codecs} was measured")
    size, best, _ = min(ours)
    print(f"smallest with the writer's codecs ({args.writer_codecs}): {best} ({size / 1e6:.1f} MB)")
    if args.expect_best and best != args.expect_best:
        print(f"expected {args.expect_best} to be the smallest, got {best}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
