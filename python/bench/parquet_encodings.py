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

With --doc DOC (docs/traces.md) it also pins the figures DOC quotes: the text between DOC's markers
`<!-- parquet-encodings: ... -->` and `<!-- parquet-encodings: end -->` must be what this measurement renders
(render_doc), every number with a decimal point within TOLERANCE (3 %) of the measured one (the sizes of
voxhap's own file and of the CSV, and their ratio, within WRITER_TOLERANCE, 0.5 %) and every other number (rows,
columns) equal; and DOC's formats table must give voxhap's own file per hour and its ratio to the CSV within
WRITER_TOLERANCE. Otherwise it exits 1 saying which figure differs. With --bless it writes
the measured figures into DOC instead.
"""

import argparse
import json
import os
import re
import sys
import tempfile
import textwrap

import pyarrow as pa
import pyarrow.parquet as pq

ROW_GROUP_ROWS = 1 << 20
ENCODINGS = ["plain", "dictionary", "byte_stream_split", "bss+delta"]
# How far a figure DOC quotes may be from the measurement (relative): pyarrow's rewrites change a little with
# its version; the sim, voxhap's own file and the CSV are deterministic (their figures differ by rounding only).
TOLERANCE = 0.03
WRITER_TOLERANCE = 0.005
ROW_NAMES = {
    "plain": "plain",
    "dictionary": "dictionary",
    "byte_stream_split": "BYTE_STREAM_SPLIT floats",
    "bss+delta": "BYTE_STREAM_SPLIT floats, DELTA_BINARY_PACKED integers",
}
CODEC_NAMES = {"none": "none", "snappy": "Snappy", "zstd": "zstd"}
BEGIN = re.compile(r"<!-- parquet-encodings:(?! end)[^\n]*-->\n")
END = "<!-- parquet-encodings: end -->"
# A number as the docs write it: thousands grouped with spaces ("1 466.4", "600 000").
NUMBER = re.compile(r"\d{1,3}(?: \d{3})+(?:\.\d+)?|\d+(?:\.\d+)?")
# The formats table's Parquet row: voxhap's own file per hour and its ratio to the CSV.
FORMATS_ROW = re.compile(
    r"about (?P<hour>[\d ]+) MB per hour at 1 kHz of `sims/multimodal.toml`, whose hand keeps moving, "
    r"(?P<ratio>[\d.]+) times smaller than its CSV"
)


def paragraph(text, width=110):
    """`text` wrapped at `width` columns, never inside a number grouped with spaces."""
    protected = re.sub(r"(?<=\d) (?=\d{3}\b)", "\u00a0", text)
    return textwrap.fill(protected, width, break_on_hyphens=False).replace("\u00a0", " ")


def grouped(value, decimals=1):
    """A number with its thousands grouped by spaces, as docs/ writes them."""
    return f"{value:,.{decimals}f}".replace(",", " ")


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
    parser.add_argument("--doc", default=None, help="a document quoting the figures (docs/traces.md): check them")
    parser.add_argument("--bless", action="store_true", help="with --doc: write the measured figures into it")
    args = parser.parse_args()
    if args.doc and not args.csv:
        sys.exit("--doc needs --csv (the document quotes the ratio to the CSV)")
    if args.doc and args.codecs.split(",") != list(CODEC_NAMES):
        sys.exit(f"--doc needs --codecs {','.join(CODEC_NAMES)} (the document's table has those columns)")
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
    sizes = {}
    with tempfile.TemporaryDirectory() as folder:
        for encoding in ENCODINGS:
            for codec in args.codecs.split(","):
                path = os.path.join(folder, f"{encoding}-{codec}.parquet")
                pq.write_table(table, path, **options(table.schema, encoding, codec))
                size = os.path.getsize(path)
                os.remove(path)
                results.append((size, f"{encoding}/{codec}", codec))
                sizes[(encoding, codec)] = size
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
    if args.doc:
        measured = {
            "rows": table.num_rows,
            "columns": table.num_columns,
            "hours": hours,
            "trace_bytes": trace_bytes,
            "csv_bytes": csv_bytes,
            "sizes": sizes,
        }
        problems = doc_figures(args.doc, measured, args.bless)
        for problem in problems:
            print(f"{args.doc}: {problem}", file=sys.stderr)
        if problems:
            print(
                "(run with --bless, or VOXHAP_BLESS=1 .ci/check-parquet-pandas.sh, to write the measured figures)",
                file=sys.stderr,
            )
            sys.exit(1)
        agree = f"the figures quoted agree with the measurement within {TOLERANCE:.0%} ({WRITER_TOLERANCE:.1%})"
        print(f"{args.doc}: " + ("figures written" if args.bless else agree))


def render_doc(m):
    """The block of docs/traces.md between the parquet-encodings markers, from the measurement `m`."""
    words = {6: "six", 10: "ten"}
    minutes, factor = round(m["hours"] * 60), round(1 / m["hours"])
    span = f"{words.get(minutes, minutes)} minutes"
    ours = m["sizes"][("bss+delta", "snappy")]
    own_mb, csv_mb = grouped(m["trace_bytes"] / 1e6), grouped(m["csv_bytes"] / 1e6)
    smaller = f"{m['csv_bytes'] / m['trace_bytes']:.1f}"
    dictionary = f"{m['sizes'][('dictionary', 'snappy')] / ours:.1f}"
    zstd_saves = f"{100 * (1 - m['sizes'][('bss+delta', 'zstd')] / ours):.1f}"
    lines = [
        paragraph(
            f"On {span} of `sims/multimodal.toml` ({grouped(m['rows'], 0)} rows, {m['columns']} columns, the hand "
            f"circling the ball the whole time; pyarrow {pa.__version__}), in MB per hour ({span}' sizes times "
            f"{words.get(factor, factor)}; the sizes grow in proportion to the rows):"
        ),
        "",
        "| encoding | " + " | ".join(CODEC_NAMES.values()) + " |",
        "|---|" + "---|" * len(CODEC_NAMES),
    ]
    for encoding in ENCODINGS:
        cells = [grouped(m["sizes"][(encoding, codec)] / 1e6 / m["hours"]) for codec in CODEC_NAMES]
        lines.append(f"| {ROW_NAMES[encoding]} | " + " | ".join(cells) + " |")
    lines += [
        "",
        paragraph(
            f"voxhap writes the last row with Snappy (its own file: {own_mb} MB for the {span}, {smaller} times "
            f"smaller than the {csv_mb} MB CSV of the same run; dictionary pages with Snappy, what writers use by "
            f"default, take {dictionary} times as much). zstd would save another {zstd_saves} % but needs the zstd "
            "C library in every build."
        ),
    ]
    return "\n".join(lines) + "\n", {own_mb, csv_mb, smaller}


def compare_numbers(where, quoted, measured, writer_figures):
    """Problems where the text `quoted` differs from `measured` beyond its numbers, or a number beyond the
    tolerance (decimals; WRITER_TOLERANCE for the `writer_figures`) or at all (integers)."""
    skeleton = lambda text: NUMBER.sub("#", re.sub(r"pyarrow [\w.+-]+", "pyarrow", text))  # noqa: E731
    if skeleton(quoted) != skeleton(measured):
        return [f"{where}: the text differs from what the measurement renders:\n{measured}"]
    problems = []
    strip = lambda text: re.sub(r"pyarrow [\w.+-]+", "pyarrow", text)  # noqa: E731
    for q, m in zip(NUMBER.findall(strip(quoted)), NUMBER.findall(strip(measured))):
        qv, mv = float(q.replace(" ", "")), float(m.replace(" ", ""))
        if "." in q or "." in m:
            tolerance = WRITER_TOLERANCE if m in writer_figures else TOLERANCE
            if abs(qv - mv) > tolerance * abs(mv):
                problems.append(f"{where}: quotes {q}, measured {m} (more than {tolerance:.1%} apart)")
        elif qv != mv:
            problems.append(f"{where}: quotes {q}, measured {m}")
    return problems


def doc_figures(path, m, bless):
    """Checks (or with `bless` writes) the figures of the document at `path`; returns the problems found."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    begin = BEGIN.search(text)
    end = text.find(END)
    if not begin or end < begin.end():
        return [f"no block between '<!-- parquet-encodings: ... -->' and '{END}'"]
    rendered, writer_figures = render_doc(m)
    row = FORMATS_ROW.search(text)
    if not row:
        return ["the formats table's Parquet row does not give 'about N MB per hour at 1 kHz of "
                "`sims/multimodal.toml`, whose hand keeps moving, R times smaller than its CSV'"]
    hour = f"{m['trace_bytes'] / 1e6 / m['hours']:.0f}"
    ratio = f"{m['csv_bytes'] / m['trace_bytes']:.1f}"
    if bless:
        text = text[: begin.end()] + rendered + text[end:]
        row = FORMATS_ROW.search(text)
        text = (
            text[: row.start("hour")]
            + hour
            + text[row.end("hour") : row.start("ratio")]
            + ratio
            + text[row.end("ratio") :]
        )
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        return []
    problems = compare_numbers("the parquet-encodings block", text[begin.end() : end], rendered, writer_figures)
    quoted_hour = float(row.group("hour").replace(" ", ""))
    if abs(quoted_hour - float(hour)) > WRITER_TOLERANCE * float(hour):
        problems.append(f"the formats table: quotes {row.group('hour')} MB per hour, measured {hour}")
    if abs(float(row.group("ratio")) - float(ratio)) > WRITER_TOLERANCE * float(ratio):
        problems.append(f"the formats table: quotes {row.group('ratio')} times smaller, measured {ratio}")
    return problems


if __name__ == "__main__":
    main()
