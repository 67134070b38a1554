"""voxhap.read_trace against traces written by the voxhap binary: every column has the type the trace format
gives it (docs/traces.md, and the sidecar's column list written by the binary), the three formats give
equal frames and the values pandas' own readers give, nothing is written while reading (no temporary copy),
and what voxhap's readers warn about or refuse is still warned about or refused."""

import os
import pathlib
import subprocess
import tempfile

import numpy as np
import pandas as pd
import pytest

import voxhap

ROOT = pathlib.Path(__file__).resolve().parents[2]
BIN = os.environ.get("VOXHAP_BIN", str(ROOT / "target/release/voxhap"))
# Three modes at once (surface, friction, viscosity), so the per-mode columns are there three times.
SCENARIO = ROOT / "sims" / "multimodal.toml"
START_UTC_NS = 1_795_514_834_000_000_000
FORMATS = ["parquet", "csv", "mcap"]

# docs/traces.md, "Columns" and "Parquet": the value type of each column type, as pandas holds it.
DTYPE_OF_TYPE = {
    "u64": "uint64",
    "i64": "int64",
    "f64": "float64",
    "bool": "bool",
    "optionalu64": "UInt64",
}


@pytest.fixture(scope="module")
def traces(tmp_path_factory):
    """The same 1.5 s of the multimodal sim in each format (fixed start time: equal utc_ns)."""
    folder = tmp_path_factory.mktemp("traces")
    paths = {}
    for ext in FORMATS:
        out = folder / f"run.{ext}"
        subprocess.run(
            [BIN, "sim", str(SCENARIO), "--out", str(out), "--duration", "1.5",
             "--start-utc-ns", str(START_UTC_NS)],
            check=True, capture_output=True,
        )
        paths[ext] = out
    return paths


def sidecar_types(path):
    import json

    sidecar = json.loads(pathlib.Path(f"{path}.json").read_text())
    return {c["name"]: c["type"] for c in sidecar["columns"]}


@pytest.mark.parametrize("ext", FORMATS)
def test_every_column_has_the_type_of_the_trace_format(traces, ext):
    df = voxhap.read_trace(traces[ext])
    types = sidecar_types(traces[ext])
    assert list(df.columns) == list(types)
    for name, column_type in types.items():
        if column_type == "text":
            assert pd.api.types.is_string_dtype(df[name].dtype), (name, df[name].dtype)
        else:
            assert str(df[name].dtype) == DTYPE_OF_TYPE[column_type], (name, df[name].dtype)
    # The integer columns the issue found as float64.
    assert str(df["device_sequence"].dtype) == "UInt64"
    assert str(df["tick"].dtype) == "uint64" and str(df["sweeps"].dtype) == "uint64"
    assert str(df["utc_ns"].dtype) == "int64"


def test_a_device_sequence_beyond_float_precision_comes_back_exactly(traces, tmp_path):
    # 2**53 + 1 is the first integer a float64 cannot hold: a reader that goes through float64 changes it.
    text = traces["csv"].read_text().splitlines(keepends=True)
    header = text[0].rstrip("\n").split(",")
    column = header.index("device_sequence")
    big = 2**53 + 1
    fields = text[1].rstrip("\n").split(",")
    fields[column] = str(big)
    out = tmp_path / "big.csv"
    out.write_text(text[0] + ",".join(fields) + "\n" + "".join(text[2:]))
    df = voxhap.read_trace(out)
    assert int(df["device_sequence"].iloc[0]) == big  # int(): no float comparison that rounds both sides
    assert df["device_sequence"].iloc[1:].isna().all()


def test_the_three_formats_give_equal_frames(traces):
    frames = {ext: voxhap.read_trace(traces[ext]) for ext in FORMATS}
    for ext in ["csv", "mcap"]:
        pd.testing.assert_frame_equal(frames[ext], frames["parquet"], check_exact=True, obj=ext)
    assert len(frames["parquet"]) == 1500


def test_values_are_those_pandas_own_readers_give(traces):
    df = voxhap.read_trace(traces["parquet"])
    plain = pd.read_parquet(traces["parquet"])
    for name in plain.columns:
        ours, theirs = df[name], plain[name]
        if name in ("device_sequence", "device_time_us"):
            assert ours.isna().equals(theirs.isna()), name
            continue
        assert (ours.to_numpy() == theirs.to_numpy()).all() or (
            ours.dtype.kind == "f" and np.array_equal(ours.to_numpy(), theirs.to_numpy(), equal_nan=True)
        ), name
    # CSV: the floats as Python parses the text (exact round trip), independent of pandas.
    lines = traces["csv"].read_text().splitlines()
    header = lines[0].split(",")
    for row in (0, 700, len(lines) - 2):
        fields = lines[row + 1].split(",")
        for name in ("t_s", "probe_x_m", "force_z_n", "error_bound_m"):
            assert df[name].iloc[row] == float(fields[header.index(name)]), (row, name)
        assert df["tick"].iloc[row] == int(fields[header.index("tick")])
        assert df["utc_ns"].iloc[row] == int(fields[header.index("utc_ns")])


def test_reading_writes_nothing_no_temporary_copy(traces, tmp_path, monkeypatch):
    """No file is created while reading: the temporary-file functions fail if called, TMPDIR points to an
    empty folder that stays empty, and the traces' folder holds the same files afterwards."""

    def refuse(*args, **kwargs):
        raise AssertionError("read_trace made a temporary file")

    for name in ("mkstemp", "mkdtemp", "TemporaryDirectory", "NamedTemporaryFile", "TemporaryFile"):
        monkeypatch.setattr(tempfile, name, refuse)
    empty = tmp_path / "tmp"
    empty.mkdir()
    monkeypatch.setenv("TMPDIR", str(empty))
    folder = traces["csv"].parent
    before = sorted(p.name for p in folder.iterdir())
    for ext in FORMATS:
        assert len(voxhap.read_trace(traces[ext])) == 1500
    assert list(empty.iterdir()) == []
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.mark.parametrize("ext", FORMATS)
def test_a_sidecar_that_lies_is_a_warning(traces, tmp_path, ext):
    import json

    out = tmp_path / f"lie.{ext}"
    out.write_bytes(traces[ext].read_bytes())
    sidecar = json.loads(pathlib.Path(f"{traces[ext]}.json").read_text())
    sidecar["sample_count"] = 7921
    pathlib.Path(f"{out}.json").write_text(json.dumps(sidecar))
    with pytest.warns(UserWarning, match="it says 7921 samples, the trace holds 1500"):
        df = voxhap.read_trace(out)
    assert any("does not match the trace" in w for w in df.attrs["warnings"])
    assert df.attrs["sidecar"]["sample_count"] == 7921


@pytest.mark.parametrize("ext", FORMATS)
def test_a_sidecar_lying_about_modes_format_and_version_warns_of_each(traces, tmp_path, ext):
    """Every contradiction between the sidecar and the data is its own warning (docs/traces.md, "Sidecar"):
    the modes it names, the format it claims and the trace format version; the trace's data are used."""
    import json

    out = tmp_path / f"lie.{ext}"
    out.write_bytes(traces[ext].read_bytes())
    sidecar = json.loads(pathlib.Path(f"{traces[ext]}.json").read_text())
    honest_modes = sidecar["mode_names"]
    sidecar["mode_names"] = ["surface"]
    sidecar["trace_format"] = "csv" if ext != "csv" else "mcap"
    sidecar["format_version"] = 99
    pathlib.Path(f"{out}.json").write_text(json.dumps(sidecar))
    with pytest.warns(UserWarning) as caught:
        df = voxhap.read_trace(out)
    texts = [str(w.message) for w in caught]
    expected = [
        f"it names the modes [\"surface\"], the trace has {json.dumps(honest_modes)}",
        f"it says trace_format {sidecar['trace_format']}, the file is {ext}",
        "it says format_version 99, this reader reads",
    ]
    for text in expected:
        assert any(text in t for t in texts), (text, texts)
    assert len(df) == 1500
    assert [c for c in df.columns if c.startswith("primitives_")] == [f"primitives_{m}" for m in honest_modes]


def test_a_cut_off_parquet_trace_is_read_with_a_warning(traces, tmp_path):
    data = traces["parquet"].read_bytes()
    out = tmp_path / "cut.parquet"
    out.write_bytes(data[: len(data) - 100])
    pathlib.Path(f"{out}.json").write_bytes(pathlib.Path(f"{traces['parquet']}.json").read_bytes())
    with pytest.warns(UserWarning, match="no final footer"):
        df = voxhap.read_trace(out)
    assert list(df.columns) == list(sidecar_types(traces["parquet"]))


def test_a_whole_last_line_without_newline_is_kept(traces, tmp_path):
    out = tmp_path / "nonl.csv"
    out.write_bytes(traces["csv"].read_bytes().rstrip(b"\n"))
    pathlib.Path(f"{out}.json").write_bytes(pathlib.Path(f"{traces['csv']}.json").read_bytes())
    df = voxhap.read_trace(out)
    assert len(df) == 1500 and df.attrs["warnings"] == []


def edited_csv(traces, tmp_path, row, column, value):
    lines = traces["csv"].read_text().splitlines(keepends=True)
    header = lines[0].rstrip("\n").split(",")
    fields = lines[row + 1].rstrip("\n").split(",")
    fields[header.index(column)] = value
    lines[row + 1] = ",".join(fields) + "\n"
    out = tmp_path / "edited.csv"
    out.write_text("".join(lines))
    pathlib.Path(f"{out}.json").write_bytes(pathlib.Path(f"{traces['csv']}.json").read_bytes())
    return out


@pytest.mark.parametrize(
    "column, value, message",
    [
        ("force_x_n", "inf", "force_x_n = inf is not finite"),
        ("probe_z_m", "NaN", "probe_z_m = nan is not finite"),
        ("error_bound_m", "-1.0", "error_bound_m = -1.0 must be >= 0"),
        ("tick", "3", "ticks must strictly increase"),
        ("flag_bits", "1", "disagrees with flag_bits"),
        ("flag_device_faulted", "true", "flag_device_faulted disagrees with flag_bits"),
        ("utc_ns", "5", "utc_ns disagrees"),
        ("sweeps", "x", "CSV trace"),
    ],
)
def test_a_broken_row_is_an_error_naming_it(traces, tmp_path, column, value, message):
    # docs/traces.md: readers accept non-finite values only in samples flagged invalid_values, ticks
    # strictly increase, flags agree with flag_bits; an edited row breaks one rule at a time.
    out = edited_csv(traces, tmp_path, 9, column, value)
    with pytest.raises(ValueError, match=message):
        voxhap.read_trace(out)


def test_old_format_and_foreign_files_are_refused(tmp_path):
    old = tmp_path / "old.csv"
    old.write_text("tick,t_s,flags\n0,0.0,0\n")
    with pytest.raises(ValueError, match="written by an older voxhap"):
        voxhap.read_trace(old)
    other = tmp_path / "other.parquet"
    pd.DataFrame({"tick": np.arange(3, dtype="uint64"), "x": [1.0, 2.0, 3.0]}).to_parquet(other)
    with pytest.raises(ValueError, match="column 2 is x"):
        voxhap.read_trace(other)
    with pytest.raises(ValueError, match="cannot read"):
        voxhap.read_trace(tmp_path / "missing.parquet")


def test_an_empty_csv_file_is_refused(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="CSV trace is empty"):
        voxhap.read_trace(empty)


def test_a_line_with_a_field_too_many_is_refused(traces, tmp_path):
    lines = traces["csv"].read_text().splitlines(keepends=True)
    for row in (0, 700):
        edited = list(lines)
        edited[row + 1] = edited[row + 1].rstrip("\n") + ",1\n"
        out = tmp_path / f"extra{row}.csv"
        out.write_text("".join(edited))
        with pytest.raises(ValueError, match="fields"):
            voxhap.read_trace(out)
