"""Closed-form frame estimate: exact recovery, also when accumulated over chunks of poses."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calib.calibration.frames import estimate_frames
from calib.model.simulate import simulate_measurements
from calib.model.spatial import zyx_transform


@pytest.mark.parametrize("chunk", [4096, 7])
def test_frames_recovered_from_exact_data(bundled_robot, monkeypatch, chunk):
    import calib.calibration.frames as frames

    monkeypatch.setattr(frames, "CHUNK", chunk)
    robot = bundled_robot
    X = zyx_transform(0.8, -0.3, 0.2, 0.9, -0.4, 2.5)        # measurement device far away
    Y = zyx_transform(0.01, 0.02, 0.15, 0.1, 0.2, -0.3)
    true = replace(robot, T_meas_base_ref=X @ robot.T_meas_base_ref,
                   T_flange_tool_ref=robot.T_flange_tool_ref @ Y)
    meas = simulate_measurements(true, robot.random_configurations(30, 5), sigma_pos=0, sigma_rot=0)
    X_est, Y_est = estimate_frames(robot, meas.q, meas.position, meas.rotation)
    # noise-free data: the frames come back to rounding (1e-9 m, 1e-9 rad)
    np.testing.assert_allclose(X_est, true.T_meas_base(), atol=1e-9)
    np.testing.assert_allclose(Y_est, true.T_flange_tool(), atol=1e-9)


def test_median_equals_numpy_median():
    from calib.calibration.frames import median

    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 10):
        x = rng.normal(size=(n, 3)) * 1e-4
        assert median(x) == float(np.median(x))
    assert median(np.array([3.0, 1.0])) == 2.0
    assert np.isnan(median(np.array([1.0, np.nan, 2.0])))
