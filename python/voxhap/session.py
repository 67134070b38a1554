"""`voxhap.Session`: a live servo session with the simulated arm, for integration tests in Python.

The servo loop runs in this process on its own thread, as `voxhap serve --device sim --no-http` runs it
(real time, 1 kHz by default); Python moves the arm's virtual hand, waits for ticks and reads what the
loop rendered. Hand positions are checked as the HTTP API checks them (finite, inside the arm's
workspace) and refused with `ValueError`. Waiting releases the GIL. Every tick is recorded (a CSV file in
a private temporary folder, removed when the session is done) so `trace()` gives what ran as a DataFrame.

    with voxhap.Session("scene.toml") as session:
        session.set_hand(0.0, 0.0, -0.002)
        state = session.wait_ticks(500)
        state.force_n, state.proxy_m, state.error_bound_m
        df = session.trace()
"""

import json
import math
import numbers
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from typing import FrozenSet, Optional

import numpy as np

from . import _voxhap

__all__ = ["Session", "State"]

_FLAG_NAMES = _voxhap.NativeSession.flag_names()


@dataclass(frozen=True)
class State:
    """One servo tick as the session saw it (the HTTP API's snapshot). Vectors are numpy arrays in the
    scene frame: positions in m, velocities in m/s, forces in N."""

    tick: int
    """Ticks since the session started."""
    t_s: float
    """Time of this tick since the session started (s)."""
    probe_m: np.ndarray
    """Probe (arm) position."""
    probe_velocity_m_per_s: np.ndarray
    proxy_m: np.ndarray
    """Proxy position after the solve."""
    rendered_force_n: np.ndarray
    """Force the tick rendered, k (proxy - probe) plus damping, before the safety pipeline."""
    force_n: np.ndarray
    """Force sent to the arm after the safety pipeline (the trace's force_*_n)."""
    error_bound_m: float
    """Certificate: bound on the proxy's distance from the exact equilibrium; inf without one."""
    status: str
    """How the solve ended: certified, budget_exhausted, stalled, uncertified, input_rejected."""
    sweeps: int
    """Solver sweeps this tick (block sweeps plus primal Newton passes)."""
    stiffness_n_per_m: float
    damping_n_s_per_m: float
    connected: bool
    engaged: bool
    """True once the safety pipeline passes forces at full strength."""
    output_state: str
    flag_bits: int
    flags: FrozenSet[str]
    """Names of the flags set this tick (docs/reference/trace.md)."""
    hand_target_m: Optional[np.ndarray]
    """Where the virtual hand is pulled to, when `set_hand` set it."""
    external_force_n: np.ndarray
    """The external force added to the rendered force this tick (`set_external_force`); zero when none is
    in effect (off, none sent, older than the staleness timeout)."""

    @property
    def certified(self):
        """True when the exact solver certified this tick within its tolerance."""
        return self.status == "certified"

    @classmethod
    def _from_json(cls, text):
        raw = json.loads(text)
        vector = lambda key: np.array(raw[key], dtype=float)  # noqa: E731
        bits = int(raw["flags"])
        bound = raw["error_bound_m"]
        target = raw.get("hand_target_m")
        return cls(
            tick=int(raw["tick"]),
            t_s=float(raw["t_s"]),
            probe_m=vector("probe_m"),
            probe_velocity_m_per_s=vector("probe_velocity_m_per_s"),
            proxy_m=vector("proxy_m"),
            rendered_force_n=vector("rendered_force_n"),
            force_n=vector("sent_force_n"),
            error_bound_m=math.inf if bound is None else float(bound),
            status=raw["status"],
            sweeps=int(raw["sweeps"]),
            stiffness_n_per_m=float(raw["stiffness_n_per_m"]),
            damping_n_s_per_m=float(raw["damping_n_s_per_m"]),
            connected=bool(raw["connected"]),
            engaged=bool(raw["engaged"]),
            output_state=raw["output_state"],
            flag_bits=bits,
            flags=frozenset(name for bit, name in enumerate(_FLAG_NAMES) if bits >> bit & 1),
            hand_target_m=None if target is None else np.array(target, dtype=float),
            external_force_n=np.array(raw["truth"]["external_force_n"], dtype=float),
        )


def _coordinate(name, value, what="hand position"):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{what} {name} must be a number, not {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{what} {name} = {value} is not finite")
    return value


class Session:
    """A live session with the simulated arm (see the module docstring).

    `scene`: a scene or sim scenario TOML file (docs/scenarios.md); None for the built-in scene of
    `voxhap serve`. `overrides`: scene keys to change, as `voxhap sim --set` (`{"k_n_per_m": 250}`).
    `rate_hz`: servo rate, 100 to 10 000 (default the scene's `rate_hz`, else 1000). `record`: keep every
    tick for `trace()` (a CSV file in a temporary folder, 0.25 to 0.7 kB per tick depending on the modes; False for none).
    `external_force`: accept `set_external_force` (off by default, as `voxhap serve` without
    `--external-force`); `external_force_timeout_s`: how long a force is applied after it was sent (0.001 to
    5 s, default 0.1 s, as `--external-force-timeout`).
    """

    def __init__(self, scene=None, overrides=None, rate_hz=None, record=True, external_force=False,
                 external_force_timeout_s=0.1):
        from . import _toml_value

        sets = [f"{key}={_toml_value(value)}" for key, value in (overrides or {}).items()]
        self._work = tempfile.mkdtemp(prefix="voxhap-session-") if record else None
        self._trace_csv = os.path.join(self._work, "session.csv") if record else None
        self._final_trace = None
        self._summary = None
        try:
            self._native = _voxhap.NativeSession(
                None if scene is None else os.fspath(scene), sets, rate_hz, self._trace_csv,
                float(external_force_timeout_s) if external_force else None,
            )
        except BaseException:
            self._remove_work()
            raise
        self.rate_hz = json.loads(self._native.stats())["rate_hz"]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        # A session dropped without close(): stop it all the same (zero force, arm disabled).
        native = getattr(self, "_native", None)
        try:
            if native is not None:
                native.close()
        finally:
            self._remove_work()

    @property
    def running(self):
        """True while the servo thread runs (False after `close`)."""
        return self._native.running()

    def set_hand(self, x, y, z):
        """Pulls the simulated arm's virtual hand towards (x, y, z) m; the arm follows through its hand
        spring and meets the scene's forces. Raises ValueError for a coordinate that is not finite or a
        point outside the arm's workspace, TypeError for a non-number. Returns voxhap's confirmation."""
        target = [_coordinate(name, value) for name, value in zip("xyz", (x, y, z))]
        return self._native.set_hand_target(target)

    def release_hand(self):
        """Lets the virtual hand follow the scene's scripted path again."""
        return self._native.set_hand_target(None)

    def set_external_force(self, fx, fy, fz):
        """Sends an external force (N, scene frame), added to the rendered force before the safety pipeline
        (force limit, slew limit, engage ramp, passivity) for the staleness timeout; send it again before the
        timeout ends to keep it, or (0, 0, 0) to remove it at once. Raises ValueError for a component that is
        not finite or a magnitude above 1000 N, TypeError for a non-number, RuntimeError when the session was
        started without `external_force=True`. Returns voxhap's confirmation."""
        force = [_coordinate(name, value, "external force") for name, value in zip("xyz", (fx, fy, fz))]
        return self._native.set_external_force(force)

    def wait_ticks(self, ticks, timeout_s=None):
        """Waits until `ticks` more servo ticks have run (GIL released) and returns that tick's State.
        `timeout_s` (default: ten times the ticks' duration, at least 5 s) raises TimeoutError."""
        if isinstance(ticks, bool) or not isinstance(ticks, numbers.Integral) or ticks < 0:
            raise ValueError(f"ticks must be a whole number >= 0, got {ticks!r}")
        if timeout_s is None:
            timeout_s = max(5.0, 10.0 * int(ticks) / self.rate_hz)
        return State._from_json(self._native.wait_ticks(int(ticks), float(timeout_s)))

    def wait_s(self, seconds, timeout_s=None):
        """Waits `seconds` of servo time (that many ticks at the session's rate); returns the State."""
        seconds = float(seconds)
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"seconds must be a finite number >= 0, got {seconds}")
        return self.wait_ticks(round(seconds * self.rate_hz), timeout_s)

    def state(self):
        """The newest tick's State (waits for the first tick after start)."""
        text = self._native.snapshot()
        if text is None:
            return self.wait_ticks(1)
        return State._from_json(text)

    def control(self, command):
        """Applies a control command of the HTTP API, as a dict (`{"command": "set_stiffness", "k": 400}`,
        docs/serve.md); bad values raise ValueError, commands not possible now RuntimeError."""
        return self._native.control(json.dumps(command))

    def stats(self):
        """The servo statistics so far (ticks, overruns, lateness, safety counters) as a dict."""
        return json.loads(self._native.stats())

    def scene(self):
        """The scene as configured now (k, damping, modes, volumes) as a dict."""
        return json.loads(self._native.scene())

    def trace(self, timeout_s=5.0):
        """Every tick that ran up to now (or up to `close`) as a DataFrame with the trace's columns
        (docs/reference/trace.md), as `voxhap.read_trace` gives them."""
        from . import read_trace

        if self._trace_csv is None:
            raise RuntimeError("this session records no trace (Session(..., record=False))")
        if self._final_trace is not None:
            return self._final_trace.copy()
        if self._summary is not None:
            self._final_trace = read_trace(self._trace_csv)
            self._remove_work()
            return self._final_trace.copy()
        # Running: the recorder writes whole lines at least every 250 ms; read until the tick current now
        # has reached the file.
        last_tick = self.state().tick
        deadline = time.monotonic() + timeout_s
        while True:
            frame = read_trace(self._trace_csv)
            if len(frame) and frame["tick"].iloc[-1] >= last_tick:
                return frame[frame["tick"] <= last_tick].reset_index(drop=True)
            if time.monotonic() > deadline:
                raise TimeoutError(f"tick {last_tick} did not reach the trace within {timeout_s} s")
            time.sleep(0.1)

    def close(self):
        """Stops the session: the servo thread stops, zero force goes to the arm, the arm is disabled and
        closed, the trace is finished. Returns the final statistics (dict); closing twice is harmless."""
        text = self._native.close()
        if text is not None:
            self._summary = json.loads(text)
            if self._summary.get("recorder_error"):
                raise RuntimeError(f"recording failed: {self._summary['recorder_error']}")
        return self._summary

    def _remove_work(self):
        work, self._work = getattr(self, "_work", None), None
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
