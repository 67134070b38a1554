"""voxhap.Session against the real servo loop and simulated arm: pressing the hand into a wall gives the
wall's force (k times the penetration, along its normal), leaving it gives zero, the trace holds what ran,
closing stops the servo thread, bad input is refused, and the example in docs/python.md runs."""

import gc
import math
import pathlib
import re
import threading

import numpy as np
import pytest

import voxhap

ROOT = pathlib.Path(__file__).resolve().parents[2]
# The plane z = 0 pushing along +z, strength 3 N, k = 400 N/m; the hand spring is 300 N/m.
WALL = pathlib.Path(__file__).resolve().parent / "scenes" / "wall.toml"
K_N_PER_M = 400.0
HAND_N_PER_M = 300.0
STRENGTH_N = 3.0


def servo_threads():
    """Names of this process's threads that are voxhap servo threads (Linux: /proc/self/task)."""
    names = []
    for comm in pathlib.Path("/proc/self/task").glob("*/comm"):
        try:
            names.append(comm.read_text().strip())
        except OSError:
            pass  # the thread ended while we looked
    return [name for name in names if name == "voxhap-servo"]


def settle(session, ticks=800):
    """Waits for the arm to settle and returns the state."""
    return session.wait_ticks(ticks)


def wait_engaged(session):
    for _ in range(40):
        if session.wait_ticks(50).engaged:
            return
    pytest.fail(f"the safety pipeline never engaged: {session.state()}")


def test_pressing_into_a_wall_gives_k_times_the_penetration_along_its_normal():
    with voxhap.Session(WALL) as session:
        assert session.rate_hz == 1000.0
        wait_engaged(session)
        free = session.state()
        assert free.probe_m[2] > 0.015 and np.all(free.force_n == 0.0)
        forces = []
        for target_depth_m in (0.004, 0.008):
            session.set_hand(0.0, 0.0, -target_depth_m)
            state = settle(session)
            depth_m = -state.probe_m[2]
            assert state.certified and state.error_bound_m < 1e-9, state
            # The proxy stays on the wall; the force is the coupling spring, along the wall's normal.
            assert abs(state.proxy_m[2]) < 1e-9, state.proxy_m
            assert state.rendered_force_n[2] == pytest.approx(K_N_PER_M * depth_m, rel=1e-6)
            assert abs(state.rendered_force_n[0]) < 1e-9 and abs(state.rendered_force_n[1]) < 1e-9
            # Steady and below the device's limits: the arm gets all of it.
            assert state.engaged and state.force_n == pytest.approx(state.rendered_force_n, abs=1e-9)
            # The arm settles where the hand spring balances the wall: d = h D / (h + k).
            expected_depth_m = HAND_N_PER_M * target_depth_m / (HAND_N_PER_M + K_N_PER_M)
            assert depth_m == pytest.approx(expected_depth_m, rel=0.05), (depth_m, expected_depth_m)
            assert state.force_n[2] < STRENGTH_N
            forces.append(state.force_n[2])
        assert forces[1] > 1.8 * forces[0], forces  # grows with the penetration
        # Out of the wall: no force at all.
        session.set_hand(0.0, 0.0, 0.01)
        state = settle(session)
        assert state.probe_m[2] > 0.005
        assert np.all(state.rendered_force_n == 0.0) and np.all(state.force_n == 0.0), state
        assert np.all(state.proxy_m == state.probe_m)


def test_trace_holds_every_tick_that_ran_and_close_stops_the_servo_thread():
    with voxhap.Session(WALL) as session:
        assert len(servo_threads()) == 1
        wait_engaged(session)
        session.set_hand(0.0, 0.0, -0.004)
        state = settle(session, 600)
        df = session.trace()
        assert df["tick"].is_monotonic_increasing and df["tick"].iloc[0] == 0
        assert df["tick"].iloc[-1] >= state.tick
        assert (df["solver_status"] == "certified").all()
        at = df[df["tick"] == state.tick].iloc[0]
        assert at["force_z_n"] == state.force_n[2] and at["probe_z_m"] == state.probe_m[2]
        assert df["force_z_n"].max() > 0.5
        running_rows = len(df)
    # Context exit: the thread is gone, the session says so, the finished trace is still there.
    assert not session.running
    assert servo_threads() == []
    final = session.trace()
    assert len(final) >= running_rows
    assert final.attrs["sidecar"]["complete"]
    with pytest.raises(RuntimeError, match="closed"):
        session.state()
    assert session.close() is not None  # closing twice is harmless


def test_a_session_dropped_without_close_stops_too():
    session = voxhap.Session(WALL)
    session.wait_ticks(5)
    work = pathlib.Path(session._work)
    assert servo_threads() == ["voxhap-servo"] and work.is_dir()
    del session
    gc.collect()
    assert servo_threads() == [] and not work.exists()


def test_bad_input_is_refused_with_the_problem_named():
    with voxhap.Session(WALL, record=False) as session:
        with pytest.raises(ValueError, match=r"hand position x = nan is not finite"):
            session.set_hand(math.nan, 0.0, 0.0)
        with pytest.raises(ValueError, match=r"hand position z = inf is not finite"):
            session.set_hand(0.0, 0.0, math.inf)
        with pytest.raises(ValueError, match="outside the simulated arm's workspace"):
            session.set_hand(0.0, 0.0, 0.2)
        with pytest.raises(ValueError, match="outside the simulated arm's workspace"):
            session.set_hand(1e308, 0.0, 0.0)
        with pytest.raises(TypeError, match="must be a number"):
            session.set_hand("0.01", 0.0, 0.0)
        with pytest.raises(ValueError, match="whole number"):
            session.wait_ticks(-1)
        with pytest.raises(ValueError, match="invalid: k"):
            session.control({"command": "set_stiffness", "k": -5})
        with pytest.raises(RuntimeError, match="no trace"):
            session.trace()
        # Nothing refused reached the arm: it still holds still above the wall.
        assert session.wait_ticks(10).probe_m[2] > 0.015
    with pytest.raises(ValueError, match="missing.toml"):
        voxhap.Session(ROOT / "missing.toml")
    with pytest.raises(ValueError, match="rate"):
        voxhap.Session(WALL, rate_hz=1e6)
    with pytest.raises(ValueError, match="no_such_key"):
        voxhap.Session(WALL, overrides={"no_such_key": 1})


def test_waiting_releases_the_gil():
    counted = []
    stop = threading.Event()

    def count():
        while not stop.is_set():
            counted.append(1)

    with voxhap.Session(WALL, record=False) as session:
        worker = threading.Thread(target=count)
        worker.start()
        try:
            session.wait_ticks(10)
            before = len(counted)
            session.wait_ticks(300)
            during = len(counted) - before
        finally:
            stop.set()
            worker.join()
    # A held GIL would let the counting thread run only in the interpreter's 5 ms switch slices.
    assert during > 1000, during


def test_overrides_reach_the_scene():
    with voxhap.Session(WALL, overrides={"k_n_per_m": 250.0}, record=False) as session:
        assert session.scene()["stiffness_n_per_m"] == 250.0
        assert session.state().stiffness_n_per_m == 250.0


def test_the_example_in_docs_python_md_runs(monkeypatch):
    page = (ROOT / "docs" / "python.md").read_text()
    blocks = re.findall(r"<!-- run by python/tests/test_session.py -->\n```python\n(.*?)```", page, re.S)
    assert len(blocks) == 1, "docs/python.md must hold one Session example marked for this test"
    monkeypatch.chdir(ROOT)
    namespace = {}
    exec(compile(blocks[0], "docs/python.md (Session example)", "exec"), namespace)
    assert "df" in namespace and len(namespace["df"]) > 0


def test_an_external_force_moves_the_arm_by_force_over_hand_stiffness_then_times_out():
    # Free space 2 cm above the wall: the coupling renders nothing, so the arm feels only the external force.
    # It settles where its hand spring (300 N/m) balances it: 0.6 N along x moves it 0.6 / 300 = 2 mm.
    force = (0.6, 0.0, 0.0)
    with voxhap.Session(WALL, external_force=True, external_force_timeout_s=1.0) as session:
        wait_engaged(session)
        assert np.all(session.state().external_force_n == 0.0)
        for _ in range(50):  # 1 s of ticks, the force sent every 20 ticks (well inside its 1 s timeout)
            reply = session.set_external_force(*force)
            state = session.wait_ticks(20)
        assert "external force" in reply
        assert state.external_force_n == pytest.approx(np.array(force), abs=0.0)
        # Below every limit of the arm (10 N): rendered and sent are the external force itself.
        assert state.rendered_force_n == pytest.approx(np.array(force), abs=1e-9)
        assert state.force_n == pytest.approx(np.array(force), abs=1e-9)
        assert state.probe_m[0] == pytest.approx(force[0] / HAND_N_PER_M, rel=0.05), state.probe_m
        # Nothing more sent: zero after the timeout (1 s), and the arm back on its hold point.
        state = session.wait_ticks(2500)
        assert np.all(state.external_force_n == 0.0) and np.all(state.force_n == 0.0), state
        assert abs(state.probe_m[0]) < 2e-4, state.probe_m
        df = session.trace()
    # The trace holds the same force in its own columns, and zero once it timed out.
    applied = df[df["external_force_x_n"] != 0.0]
    assert len(applied) > 900
    assert (applied["external_force_x_n"] == force[0]).all()
    assert (applied[["external_force_y_n", "external_force_z_n"]] == 0.0).all().all()
    assert (df["external_force_x_n"].iloc[-100:] == 0.0).all()


def test_an_external_force_is_refused_when_bad_or_off():
    with voxhap.Session(WALL, record=False, external_force=True) as session:
        with pytest.raises(ValueError, match=r"external force x = nan is not finite"):
            session.set_external_force(math.nan, 0.0, 0.0)
        with pytest.raises(TypeError, match="must be a number"):
            session.set_external_force("1", 0.0, 0.0)
        with pytest.raises(ValueError, match=r"above the 1000 N accepted"):
            session.set_external_force(0.0, 0.0, 1e6)
        # Nothing refused reached the arm.
        state = session.wait_ticks(50)
        assert np.all(state.external_force_n == 0.0) and np.all(state.force_n == 0.0)
    with voxhap.Session(WALL, record=False) as session:
        with pytest.raises(RuntimeError, match="external force input is off"):
            session.set_external_force(0.1, 0.0, 0.0)
    with pytest.raises(ValueError, match="external_force_timeout_s"):
        voxhap.Session(WALL, record=False, external_force=True, external_force_timeout_s=0.0)
