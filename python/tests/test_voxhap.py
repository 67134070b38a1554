"""The voxhap Python package against real files: a sim into a DataFrame, overrides applied, traces read in
every format (and a cut-off one with a warning), bad input as clear exceptions."""

import os
import pathlib

import pytest

import voxhap

ROOT = pathlib.Path(__file__).resolve().parents[2]
SPHERE = ROOT / "sims" / "sphere_surface.toml"


def test_sim_returns_the_trace_as_a_dataframe():
    df = voxhap.sim(SPHERE)
    assert len(df) == 6000
    assert df.attrs["summary"]["certified_ticks"] == 6000
    assert df["flag_solver_budget_hit"].dtype == bool
    assert (df["solver_status"] == "certified").all()
    assert abs(df["rendered_force_z_n"].abs().max() - 2.0) < 0.02
    assert df.attrs["sidecar"]["complete"]


def test_sim_overrides_change_the_run():
    df = voxhap.sim(SPHERE, {"k_n_per_m": 250.0}, duration_s=2.0)
    assert len(df) == 2000
    assert df.attrs["sidecar"]["scenario"]["k_n_per_m"] == 250.0
    with pytest.raises(ValueError, match="no_such_key"):
        voxhap.sim(SPHERE, {"no_such_key": 1})


def test_read_trace_reads_every_format_and_a_cut_off_file(tmp_path):
    df = voxhap.sim(SPHERE, duration_s=2.0)
    for ext in ["csv", "mcap", "parquet"]:
        out = tmp_path / f"s.{ext}"
        import subprocess

        subprocess.run(
            [os.environ.get("VOXHAP_BIN", str(ROOT / "target/release/voxhap")), "sim", str(SPHERE),
             "--out", str(out), "--duration", "2"],
            check=True, capture_output=True,
        )
        back = voxhap.read_trace(out)
        assert list(back.columns) == list(df.columns)
        assert (back["force_z_n"].to_numpy() == df["force_z_n"].to_numpy()).all(), ext
    # A CSV cut mid-line, as a crash leaves it: read up to the cut, with a warning.
    text = (tmp_path / "s.csv").read_bytes()
    cut = tmp_path / "cut.csv"
    # Cut 10 bytes into the line that holds the middle of the file: never on a line end (the middle itself
    # can fall on one, and then there is no partial line to warn about).
    line_start = text.rindex(b"\n", 0, len(text) // 2) + 1
    whole_lines = text[:line_start].count(b"\n") - 1  # data lines before the cut (minus the header)
    cut.write_bytes(text[: line_start + 10])
    with pytest.warns(UserWarning, match="partial last line"):
        back = voxhap.read_trace(cut)
    assert len(back) == whole_lines
    with pytest.raises(ValueError, match="cannot read"):
        voxhap.read_trace(tmp_path / "missing.csv")


def test_solve_returns_the_certified_answer():
    answer = voxhap.solve(ROOT / "sims" / "scenes" / "plane_point.json")
    assert answer["status"] == "certified"
    assert len(answer["proxy"]) == 3 and len(answer["force"]) == 3
    assert answer["error_bound"] < 1e-9
    with pytest.raises(ValueError, match="expected exact, euler or constraint"):
        voxhap.solve(ROOT / "sims" / "scenes" / "plane_point.json", solver="newton")
    with pytest.raises(ValueError):
        voxhap.solve(ROOT / "sims" / "scenes" / "missing.json")
