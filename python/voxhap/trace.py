"""`voxhap.read_trace`: a trace file as a pandas DataFrame, read at the speed of pandas' own readers.

A Parquet trace goes straight to pyarrow (`pyarrow.parquet.read_table`, what `pd.read_parquet` uses), a CSV
trace to `pd.read_csv` with each column's type given, an MCAP trace (and a Parquet trace cut off by a crash,
which pyarrow refuses) through voxhap's own reader in the native module, which hands the columns over in
memory. Nothing is written anywhere: no temporary copy of the input.

What voxhap's own readers check is checked here too: the columns against the trace format (an older
format or a foreign file is a `ValueError`), the sidecar against the file (each disagreement a warning), and
the sample rules (ticks strictly increase; unless a sample is flagged `invalid_values`, times, positions,
velocities and forces are finite, `t_s >= 0` and `error_bound_m >= 0` or `inf`; the `flag_<name>` columns
agree with `flag_bits`; `utc_ns` is the sidecar's `start_utc_ns` plus `t_s`). A CSV trace cut off mid-line
(by a crash) is read up to its last whole line, with a warning.

Column types (docs/traces.md): `u64` columns are `uint64`, `utc_ns` is `int64` (pandas' nullable `Int64`
only in a trace where a flagged sample has no finite time, or an MCAP trace without its sidecar, which
alone dates the samples), `f64` columns `float64`, flags `bool`,
`solver_status` pandas' default string type, `device_sequence` and `device_time_us` pandas' nullable
`UInt64` (`<NA>` where the device sent none). The three formats give equal frames.
"""

import io
import json
import os
import sys
import warnings

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from . import _voxhap

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_ARROW_TYPES = {
    "u64": pa.uint64(),
    "i64": pa.int64(),
    "f64": pa.float64(),
    "bool": pa.bool_(),
    "text": pa.string(),
    "optionalu64": pa.uint64(),
}
_CSV_DTYPES = {
    "u64": "uint64",
    "i64": "Int64",
    "f64": "float64",
    "bool": "bool",
    "text": None,  # pandas' default string type, as pd.read_parquet gives it
    "optionalu64": "UInt64",
}
# pandas before 3.0 parses floats exactly only with this (docs/python.md).
_FLOAT_PRECISION = "round_trip" if int(pd.__version__.split(".")[0]) < 3 else None
# Sample rules: the columns that must be finite unless the sample is flagged invalid_values.
_FINITE_PREFIXES = ("t_s", "probe_", "proxy_", "rendered_force_", "force_", "mode_force_")


def read_trace(path):
    """The trace at `path` (CSV, MCAP or Parquet) as a pandas DataFrame (see the module header)."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as handle:
            magic = handle.read(8)
    except OSError as error:
        raise ValueError(f"cannot read {path}: {error.strerror or error}") from error
    if magic == _MCAP_MAGIC:
        return _read_native(path)
    if magic.startswith(b"PAR1"):
        return _read_parquet(path)
    return _read_csv(path)


def _finish(frame, sidecar_json, reader_warnings):
    frame.attrs["sidecar"] = json.loads(sidecar_json) if sidecar_json else None
    frame.attrs["warnings"] = list(reader_warnings)
    # Each warning points at the first caller outside this package (read_trace's or sim's caller).
    level, caller = 1, sys._getframe(0)
    while caller is not None and caller.f_globals.get("__name__", "").startswith("voxhap"):
        caller, level = caller.f_back, level + 1
    for text in reader_warnings:
        warnings.warn(text, stacklevel=level)
    return frame


def _mode_names(names):
    return [name[len("primitives_"):] for name in names if name.startswith("primitives_")]


def _to_frame(table, kinds):
    """The Arrow table as a DataFrame: pyarrow's own conversion, except that the columns that can be
    missing stay integers (pandas' nullable types) instead of becoming float64."""
    nullable = [
        (index, name)
        for index, (name, kind) in enumerate(kinds)
        if kind == "optionalu64" or (kind == "i64" and table.column(name).null_count)
    ]
    frame = table.drop_columns([name for _, name in nullable]).to_pandas()
    for index, name in nullable:
        frame.insert(index, name, _nullable_integers(table.column(name)))
    return frame


def _nullable_integers(column):
    """An integer Arrow column with nulls as pandas' nullable integer array (`UInt64`/`Int64`), built from
    its values and validity directly (pandas' own Arrow conversion is several times slower; a column of
    nothing but nulls, a sim's device columns, costs two allocations)."""
    dtype = np.uint64 if column.type == pa.uint64() else np.int64
    rows = len(column)
    if column.null_count == rows:
        values, mask = np.zeros(rows, dtype=dtype), np.ones(rows, dtype=bool)
    else:
        values = np.asarray(column.fill_null(0), dtype=dtype)
        mask = np.asarray(column.is_null(), dtype=bool)
    return pd.arrays.IntegerArray(values, mask)


def _read_parquet(path):
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError):
        # No final footer (a crash) or damage: voxhap's reader recovers what it can, or says what is wrong.
        return _read_native(path)
    names = table.column_names
    kinds = _voxhap.trace_columns(_mode_names(names))
    expected = [(name, _ARROW_TYPES[kind]) for name, kind in kinds]
    found = [(field.name, field.type) for field in table.schema]
    if found != expected:
        column = next(
            (i for i, (want, got) in enumerate(zip(expected, found)) if want != got),
            min(len(found), len(expected)),
        )
        want = "the end of the columns" if column >= len(expected) else "{} ({})".format(*expected[column])
        got = "the end of the columns" if column >= len(found) else "{} ({})".format(*found[column])
        raise ValueError(f"Parquet trace {path}: column {column + 1} is {got}, expected {want}")
    embedded = (table.schema.metadata or {}).get(b"voxhap.sidecar")
    sidecar_json, reader_warnings = _voxhap.sidecar_check(
        path, "parquet", _mode_names(names), table.num_rows,
        embedded.decode("utf-8", "replace") if embedded else None,
    )
    _check_samples(table, path, kinds, _start_utc_ns(sidecar_json))
    frame = _to_frame(table, kinds)
    return _finish(frame, sidecar_json, reader_warnings)


class _Prefix(io.RawIOBase):
    """The first `size` bytes of an open file, read as a stream (so pandas reads a file that is still
    being written, or ends in a partial line, only up to a given offset, without a copy)."""

    def __init__(self, handle, size):
        self._handle = handle
        self._left = size

    def readable(self):
        return True

    def readinto(self, buffer):
        view = memoryview(buffer)[: self._left]
        count = self._handle.readinto(view)
        self._left -= count or 0
        return count


def _read_csv(path):
    with open(path, "rb") as handle:
        size = os.fstat(handle.fileno()).st_size
        header = handle.readline(1 << 20)
        if not header:
            raise ValueError(f"{path}: CSV trace is empty: no header line")
        modes = _voxhap.csv_mode_names(path, header)
        kinds = _voxhap.trace_columns(modes)
        # pandas would take a first data line with a field too many for an index column: say what it is.
        first = handle.readline(1 << 20)
        if first.endswith(b"\n") and first.count(b",") + 1 != len(kinds):
            raise ValueError(
                f"CSV trace {path}: line 2: {first.count(b',') + 1} fields, expected {len(kinds)}"
            )
        # A crash leaves at most one partial line, at the end and without a newline: find where the whole
        # lines end (the size is taken once, so a trace still being written is read up to that point).
        tail = b""
        end = size
        if size > len(header):
            back = min(size - len(header), 1 << 20)
            handle.seek(size - back)
            last = handle.read(back)
            cut = last.rfind(b"\n")
            if cut < len(last) - 1:
                end = size - back + cut + 1
                tail = last[cut + 1:]
        handle.seek(0)
        dtypes = {name: _CSV_DTYPES[kind] for name, kind in kinds if _CSV_DTYPES[kind]}
        options = dict(dtype=dtypes, float_precision=_FLOAT_PRECISION)
        source = io.BufferedReader(_Prefix(handle, end), buffer_size=1 << 20)
        try:
            frame = pd.read_csv(source, **options)
        except (ValueError, TypeError) as error:
            raise ValueError(f"CSV trace {path}: {error}") from error
    reader_warnings = []
    if list(frame.columns) != [name for name, _ in kinds] or not isinstance(frame.index, pd.RangeIndex):
        raise ValueError(f"CSV trace {path}: line 2 has more fields than the header")
    if tail:
        line = int(len(frame)) + 2
        try:
            last_row = pd.read_csv(io.BytesIO(header + tail), **options)
            # A line cut short has too few fields (a missing value where none may be) or a cut-off last
            # value (a flag that is neither true nor false): pandas refuses both.
            if len(last_row) != 1 or not isinstance(last_row.index, pd.RangeIndex):
                raise ValueError("not one line")
            frame = pd.concat([frame, last_row], ignore_index=True)
        except (ValueError, TypeError) as error:
            reader_warnings.append(
                f"{path}: skipped the partial last line {line} (the recording was cut off): {error}"
            )
    sidecar_json, found = _voxhap.sidecar_check(path, "csv", modes, len(frame))
    reader_warnings.extend(found)
    utc = frame["utc_ns"]
    if not utc.hasnans:
        frame["utc_ns"] = utc.to_numpy(dtype="int64")
    # As Arrow arrays for the checks; NaN stays NaN (pyarrow's pandas conversion would make it null).
    table = pa.table({name: pa.array(frame[name], from_pandas=kind != "f64") for name, kind in kinds})
    _check_samples(table, path, kinds, _start_utc_ns(sidecar_json))
    return _finish(frame, sidecar_json, reader_warnings)


def _read_native(path):
    read = _voxhap.read_trace_columns(path)
    names, arrays, kinds = [], [], []
    for name, kind, data, valid in read["columns"]:
        if kind in ("u64", "optionalu64"):
            values = np.frombuffer(data, dtype="<u8")
        elif kind == "i64":
            values = np.frombuffer(data, dtype="<i8")
        elif kind == "f64":
            values = np.frombuffer(data, dtype="<f8")
        elif kind == "bool":
            values = np.frombuffer(data, dtype=np.uint8).astype(bool)
        else:
            codes = pa.array(np.frombuffer(data, dtype=np.uint8).astype(np.int8))
            arrays.append(pa.DictionaryArray.from_arrays(codes, pa.array(read["statuses"])).dictionary_decode())
            names.append(name)
            kinds.append((name, kind))
            continue
        mask = None if valid is None else np.frombuffer(valid, dtype=np.uint8) == 0
        arrays.append(pa.array(values, type=_ARROW_TYPES[kind], mask=mask))
        names.append(name)
        kinds.append((name, kind))
    frame = _to_frame(pa.table(arrays, names=names), kinds)
    return _finish(frame, read["sidecar"], read["warnings"])


def _start_utc_ns(sidecar_json):
    if not sidecar_json:
        return None
    return json.loads(sidecar_json).get("start_utc_ns")


def _fail(path, table, mask, what):
    """Raises the error for the first row where `mask` (a boolean Arrow array) is true."""
    row = pc.index(mask, True).as_py()
    tick = table.column("tick")[row].as_py()
    value = what(row) if callable(what) else what
    raise ValueError(f"{path}: row {row + 1} (tick {tick}): {value}")


def _check_samples(table, path, kinds, start_utc_ns):
    """The sample rules of voxhap's readers (see the module header) on the Arrow table, with Arrow's
    compute kernels (no copy of a column); the first broken rule is a `ValueError` naming the row, its tick
    and the column."""
    if not table.num_rows:
        return
    column = table.column
    tick = column("tick")
    ticks = _chunks(tick)
    in_order = all(bool((a[1:] > a[:-1]).all()) for a in ticks) and all(
        later[0] > earlier[-1] for earlier, later in zip(ticks, ticks[1:]) if len(earlier) and len(later)
    )
    if not in_order:
        later = pc.greater(tick.slice(1), tick.slice(0, table.num_rows - 1))
        row = pc.index(pc.invert(later), True).as_py() + 1
        raise ValueError(
            f"{path}: row {row + 1} (tick {tick[row].as_py()}): follows tick {tick[row - 1].as_py()}: "
            "ticks must strictly increase"
        )
    valid = pc.invert(column("flag_invalid_values"))
    for name, kind in kinds:
        if kind != "f64" or not name.startswith(_FINITE_PREFIXES):
            continue
        values = column(name)
        # A finite sum means every value is finite (NaN and infinities propagate): one pass, no copy.
        with np.errstate(over="ignore", invalid="ignore"):
            if all(np.isfinite(a.sum()) for a in _chunks(values)):
                continue
        bad = pc.and_(pc.invert(pc.is_finite(values)), valid)
        if pc.any(bad).as_py():
            _fail(path, table, bad, lambda row: f"{name} = {values[row].as_py()} is not finite")
    t_s = column("t_s")
    bad = pc.and_(pc.less(t_s, 0.0), valid)
    if pc.any(bad).as_py():
        _fail(path, table, bad, lambda row: f"t_s = {t_s[row].as_py()} is negative")
    bound = column("error_bound_m")
    bad = pc.and_(pc.invert(pc.greater_equal(bound, 0.0)), valid)  # NaN compares false
    if pc.any(bad).as_py():
        _fail(path, table, bad, lambda row: f"error_bound_m = {bound[row].as_py()} must be >= 0 (or +inf)")
    for name, kind in kinds:
        if kind == "u64" and (name.startswith("primitives_") or name in ("sweeps", "flag_bits")):
            limit = 0xFFFF if name.startswith("primitives_") else 0xFFFF_FFFF
            if max((int(a.max()) for a in _chunks(column(name)) if len(a)), default=0) > limit:
                _fail(path, table, pc.greater(column(name), limit), f"{name} is above {limit}")
    bits = column("flag_bits")
    # The bits set anywhere: a flag whose bit is never set only needs its column to be all false.
    seen = 0
    for a in _chunks(bits):
        seen |= int(np.bitwise_or.reduce(a)) if len(a) else 0
    for bit, name in enumerate(_flag_names(kinds)):
        if name is None:
            continue
        if not seen >> bit & 1:
            if pc.any(column(name)).as_py():
                _fail(path, table, column(name), f"{name} disagrees with flag_bits")
            continue
        wrong = pc.xor(pc.not_equal(pc.bit_wise_and(bits, pa.scalar(1 << bit, pa.uint64())), 0), column(name))
        if pc.any(wrong).as_py():
            _fail(path, table, wrong, f"{name} disagrees with flag_bits")
    if start_utc_ns is not None:
        # start + round(t_s * 1e9), halves away from zero (Rust's f64::round), where t_s is finite.
        nanos = pc.round(pc.multiply(t_s, 1e9), round_mode="half_towards_infinity")
        finite = pc.is_finite(t_s)
        want = pc.add(pc.cast(pc.if_else(finite, nanos, 0.0), pa.int64()), pa.scalar(start_utc_ns, pa.int64()))
        wrong = pc.and_(finite, pc.fill_null(pc.not_equal(column("utc_ns"), want), True))
        if pc.any(wrong).as_py():
            _fail(path, table, wrong, "utc_ns disagrees with the sidecar's start_utc_ns + t_s")


def _chunks(values):
    """The chunks of an Arrow column without nulls as numpy arrays (no copy)."""
    return [chunk.to_numpy(zero_copy_only=False) for chunk in values.chunks]


def _flag_names(kinds):
    """The flag columns by bit (None for a bit without a column)."""
    names = {}
    for bit, name in _voxhap.flag_bits():
        names[bit] = name
    return [names.get(bit) and f"flag_{names[bit]}" for bit in range(max(names) + 1)] if names else []
