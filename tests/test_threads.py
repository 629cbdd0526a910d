"""calib.threads: calibrate() runs with one BLAS thread, whatever the environment says once numpy
is loaded, and leaves the caller's thread count as it found it."""
from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import calib
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
from calib.threads import THREAD_VARS

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
