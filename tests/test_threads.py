"""calib.threads: calibrate() runs with one BLAS thread, whatever the environment says once numpy
is loaded, and leaves the caller's thread count as it found it."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import calib
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
from calib.threads import OTHER_THREAD_VARS, OVERRIDE_VARS, THREAD_VARS

from conftest import BUNDLED_URDF


def _blas_threads() -> int:
    return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")


def test_calibrate_runs_with_one_blas_thread_and_restores_the_callers(monkeypatch):
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() < 2:
            pytest.skip("this BLAS runs one thread at most")
        for var in THREAD_VARS:
            monkeypatch.delenv(var, raising=False)
        robot = calib.load_robot(BUNDLED_URDF)
        meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(30, 1),
                                     rng=2)
        seen = []
        res = calib.calibrate(robot, meas, cv=0, progress=lambda f, stage: seen.append(_blas_threads()))
        assert res.status == "converged"
        assert seen and set(seen) == {1}
        assert _blas_threads() == 2
        # the environment set to one thread after numpy loaded the library (a program that sets
        # OPENBLAS_NUM_THREADS late): the library still runs 2, and calibrate limits them
        for var in THREAD_VARS:
            monkeypatch.setenv(var, "1")
        seen.clear()
        calib.calibrate(robot, meas, cv=0, progress=lambda f, stage: seen.append(_blas_threads()))
        assert set(seen) == {1} and _blas_threads() == 2


def test_pose_selection_and_compensation_run_with_one_blas_thread(monkeypatch):
    """select_poses / design_poses and compensate / compensate_poses: one BLAS thread inside
    (their batched products are small: compensate_poses of 2,000 targets took 246-328 ms of wall
    and 357-437 ms of CPU with OpenBLAS's two threads here, 210-243 ms with one), the caller's
    count after."""
    import calib.calibration.compensation as compensation
    import calib.calibration.poses as poses
    from calib.model.kinematics import ChainKinematics

    seen = []

    def recording(check):
        def wrapper(*a, **k):
            seen.append(_blas_threads())
            return check(*a, **k)
        return wrapper

    monkeypatch.setattr(poses, "check_robot", recording(poses.check_robot))
    monkeypatch.setattr(compensation, "check_robot", recording(compensation.check_robot))
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() < 2:
            pytest.skip("this BLAS runs one thread at most")
        robot = calib.load_robot(BUNDLED_URDF)
        calib.select_poses(robot, 8, candidates=200, seed=1)
        Q = robot.random_configurations(20, 3)
        R, p = ChainKinematics(robot).frame_poses(Q)
        T = np.zeros((20, 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
        calib.compensate_poses(robot, T_meas_tool=T)
        calib.compensate(robot, robot, Q)
        assert len(seen) >= 3 and set(seen) == {1}
        assert _blas_threads() == 2


def test_started_with_one_thread_reads_the_starting_environment(tmp_path):
    """Each variable once, at 1, in the environment the process started with (BLIS's absent or
    at 1); anything else (missing, another count, given twice) leaves one_blas_thread to
    threadpoolctl."""
    from calib.threads import started_with_one_thread

    def started(*entries: str) -> bool:
        f = tmp_path / "environ"
        f.write_bytes(b"\0".join(e.encode() for e in entries) + b"\0")
        return started_with_one_thread(str(f))

    ones = [f"{var}=1" for var in THREAD_VARS]
    assert started("HOME=/root", *ones, "PATH=/bin")
    assert not started(*ones[1:])
    assert not started(ones[0], ones[1], THREAD_VARS[2] + "=2")
    assert not started(*ones, THREAD_VARS[0] + "=4")
    assert not started(*ones[:2], THREAD_VARS[2] + "=10")
    assert started(*ones, "BLIS_NUM_THREADS=1")
    assert not started(*ones, "BLIS_NUM_THREADS=4")
    # a per-domain or per-loop override of the count (MKL, BLIS)
    assert not started(*ones, "MKL_DOMAIN_NUM_THREADS=MKL_BLAS=4")
    assert not started(*ones, "BLIS_JC_NT=2")
    assert not started_with_one_thread(str(tmp_path / "absent"))


_CHILD = """
import os, sys
{before}
import numpy
{after}
import calib
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
robot = calib.load_robot({urdf!r})
meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(30, 1), rng=2)
loaded = []
seen = []
def blas_threads():
    from threadpoolctl import threadpool_info
    return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
def progress(fraction, stage):
    loaded.append("threadpoolctl" in sys.modules)
    seen.append(blas_threads())
calib.calibrate(robot, meas, cv=0, progress=progress)
print(loaded[0], min(seen), max(seen), blas_threads())
"""


def _child(env_threads: str, before: str = "", after: str = "") -> list[str]:
    """(threadpoolctl loaded at the first progress report, the fewest and most BLAS threads seen
    in the reports, the count after the call) of a calibrate() in a process started with each of
    THREAD_VARS at ``env_threads``, ``before`` and ``after`` run around its import of numpy."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS + OTHER_THREAD_VARS + OVERRIDE_VARS}
    env.update({var: env_threads for var in THREAD_VARS})
    env["PYTHONPATH"] = str(BUNDLED_URDF.parents[2])
    code = _CHILD.format(before=before, after=after, urdf=str(BUNDLED_URDF))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


def test_a_process_started_with_one_thread_needs_no_controller():
    """Started with one thread in the environment: threadpoolctl not loaded at the first
    progress report (its controller not built), and the library ran one thread (it read 1)."""
    loaded, low, high, after = _child("1")
    assert (loaded, low, high, after) == ("False", "1", "1", "1")


def test_a_count_raised_at_run_time_or_before_numpy_is_limited():
    """Started with one thread but raised by threadpoolctl at run time, or by the environment
    before numpy loads (and left so): calibrate limits the library to one thread and restores
    the caller's count after; likewise a process started with two that asks for one once numpy
    is loaded (tests/test_threads.py's first test, in a process of its own)."""
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() < 2:
            pytest.skip("this BLAS runs one thread at most")
    raised = "from threadpoolctl import threadpool_limits\nthreadpool_limits(limits=2, user_api='blas')"
    assert _child("1", after=raised)[1:] == ["1", "1", "2"]
    env2 = "for v in {!r}: os.environ[v] = '2'".format(THREAD_VARS)
    assert _child("1", before=env2) == ["True", "1", "1", "2"]
    env1 = "for v in {!r}: os.environ[v] = '1'".format(THREAD_VARS)
    assert _child("2", after=env1) == ["True", "1", "1", "2"]
