"""voxhap from Python: read force traces, run sims into pandas DataFrames, and drive a live session.

`read_trace(path)` reads a CSV, MCAP or Parquet trace (also one cut off by a crash, with a warning): Parquet
and CSV with pyarrow's and pandas' own readers, MCAP with voxhap's (voxhap/trace.py); `sim(scenario,
overrides)` runs a sim scenario and returns its trace. Both return a pandas DataFrame with the trace's
columns (docs/traces.md): integer columns as integers, flags as boolean `flag_<name>` columns, missing
device values as `<NA>`. `df.attrs["sidecar"]` holds the trace's metadata and `df.attrs["warnings"]` what the
reader skipped. `Session(scene)` runs a live servo session with the simulated arm in this process, for
integration tests: move the hand, wait for ticks, read the forces (voxhap/session.py).
"""

import json
import os
import tempfile

from . import _voxhap
from .trace import read_trace

__all__ = ["Session", "State", "read_trace", "sim", "solve"]


def solve(scene, solver="exact"):
    """Solves the proxy problem of a JSON scene file (as `voxhap solve SCENE --json`).

    Returns a dict: `proxy` and `force` ([x, y, z], m and N), `status` and `error_bound` (exact solver), the
    iteration counts and the median solve time in ns."""
    return json.loads(_voxhap.solve(os.fspath(scene), solver))


def sim(scenario, overrides=None, duration_s=None, rate_hz=None):
    """Runs the sim `scenario` (a TOML file) and returns its trace as a DataFrame.

    `overrides` maps scenario keys (dotted paths, array indices, as `voxhap sim --set`) to values, e.g.
    `{"k_n_per_m": 200, "arm.mass_kg": 0.2}`. `df.attrs["summary"]` holds the tick counts and the
    largest force.
    """
    sets = [f"{key}={_toml_value(value)}" for key, value in (overrides or {}).items()]
    with tempfile.TemporaryDirectory(prefix="voxhap-") as work:
        out = os.path.join(work, "sim.parquet")
        ticks, certified, max_force_n = _voxhap.sim(
            os.fspath(scenario), out, sets, duration_s, rate_hz
        )
        frame = read_trace(out)
    frame.attrs["summary"] = {
        "ticks": ticks,
        "certified_ticks": certified,
        "max_force_n": max_force_n,
    }
    return frame


def _toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


from .session import Session, State  # noqa: E402  (session.py uses read_trace and _toml_value above)
