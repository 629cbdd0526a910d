"""calib.threads: calibrate() runs with one BLAS thread, whatever the environment says once numpy
is loaded, and leaves the caller's thread count as it found it."""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import calib
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

from conftest import BUNDLED_URDF

THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


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
    import calib.compensation.compensate as compensation
    import calib.design.poses as poses
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
