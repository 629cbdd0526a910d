"""The closed-form angle search on a well-spread subset of the poses."""
from __future__ import annotations

import math

import numpy as np

from calib import analyze_identifiability
from calib.solvers.angles import RotationChain, spread_subset
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements


def _chordal(X, Y):
    return np.sum((X[:, None] - Y[None]) ** 2, axis=(2, 3))


def test_spread_subset_is_a_farthest_point_cover(bundled_robot):
    meas = simulate_measurements(bundled_robot, bundled_robot.random_configurations(600, 3), rng=1)
    R = meas.rotation
    np.testing.assert_array_equal(spread_subset(R[:150], 200), np.arange(150))
    idx = spread_subset(R, 40)
    assert len(idx) == 40 and np.all(np.diff(idx) > 0)
    np.testing.assert_array_equal(spread_subset(R, 40), idx)
    # farthest-point property: every pose lies closer to the subset than any two chosen poses
    # lie to each other (so no region of the data is left without a chosen pose)
    cover = _chordal(R, R[idx]).min(axis=1).max()
    D = _chordal(R[idx], R[idx])
    np.fill_diagonal(D, np.inf)
    assert cover <= D.min() + 1e-12
    # and it covers better than every 15th pose
    every = np.arange(0, 600, 15)
    assert cover < _chordal(R, R[every]).min(axis=1).max()


def test_search_on_a_subset_finds_the_angles(bundled_robot):
    """From theta1 and alpha2 off by 2.5 rad, the search on 60 spread poses of 1000 exact ones
    lands at the true angles (or their mirrored twin), as on all poses."""
    robot = bundled_robot
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, robot.random_configurations(1000, 4), sigma_pos=0, sigma_rot=0)
    free = analyze_identifiability(robot).identifiable
    angular = [k for k in robot.indices(free) if robot.parameters[k].is_angular]
    start = robot.with_changes(theta1=2.5, alpha2=-2.5)
    chain = RotationChain(start)
    idx = robot.indices(("theta1", "alpha1", "alpha2", "beta2"))
    for max_poses in (60, None):
        found, cost = chain.search(start.values, meas.q, meas.rotation, angular, 1e-4, max_poses=max_poses)
        err = (found[idx] - true.values[idx] + math.pi) % (2 * math.pi) - math.pi
        mirrored = (found[idx] - true.values[idx]) % (2 * math.pi) - math.pi
        assert np.all(np.abs(err) < 0.05) or np.all(np.abs(mirrored) < 0.05), (max_poses, err)
        n = 60 if max_poses else 1000
        assert cost < 2 * n * 0.02 ** 2                       # RMS rotation residual below 0.02 rad
        # the returned cost is that of the poses searched
        if max_poses is None:
            # both are 6 N - 2 sum tr(R R_meas^T): rounding of 6000 at 1e-16 relative
            np.testing.assert_allclose(cost, chain.cost(found, meas.q, meas.rotation), rtol=0, atol=1e-10)
