"""calib.model.draws: the stored table is numpy's seed-0 stream, and the draws are numpy's
uniform draws bit for bit (the default calibration's random configurations unchanged)."""
from __future__ import annotations

import math
import platform

import numpy as np
import pytest

from calib.model import draws
from conftest import bundled_or_ur5


def test_table_is_the_seed0_stream():
    table = np.load(draws.TABLE_FILE)
    assert table.shape == (draws.TABLE_SIZE,)
    assert np.array_equal(table, np.random.default_rng(0).random(draws.TABLE_SIZE))


@pytest.mark.parametrize("n, k", [(256, 6), (50, 7), (100, 6), (1, 1), (585, 7), (0, 6), (256, 16)])
def test_uniform_equals_numpy_bit_for_bit(n, k):
    g = np.random.default_rng(7)
    lo = g.uniform(-4, 1, k)
    hi = lo + g.uniform(0, 6, k)
    hi[0] = lo[0]                                   # an empty range
    got = draws.uniform(0, lo, hi, n)
    want = np.random.default_rng(0).uniform(lo, hi, size=(n, k))
    assert got.shape == (n, k)
    if platform.machine() in ("x86_64", "AMD64"):
        assert np.array_equal(got.view(np.int64), want.view(np.int64))
    else:       # (numpy's lo + range * u may be one fused multiply-add there: 1 ulp apart)
        np.testing.assert_array_max_ulp(got, want, maxulp=1)


@pytest.mark.filterwarnings("ignore:overflow encountered in subtract")
def test_beyond_the_table_and_other_seeds_ask_numpy():
    lo, hi = -np.ones(20), np.ones(20)
    assert np.array_equal(draws.uniform(0, lo, hi, 300), np.random.default_rng(0).uniform(lo, hi, size=(300, 20)))
    assert np.array_equal(draws.uniform(3, lo, hi, 5), np.random.default_rng(3).uniform(lo, hi, size=(5, 20)))
    with pytest.raises(OverflowError):              # numpy's refusal of a range beyond the floats
        draws.uniform(0, np.array([-1e308]), np.array([1e308]), 2)


@pytest.mark.parametrize("robot_name", ["bundled", "ur5"])
def test_random_configurations_seed0_unchanged(robot_name):
    robot = bundled_or_ur5(robot_name)
    for n in (256, 50, 1):
        lo = np.where(np.isfinite(robot.lower), robot.lower, -math.pi)
        hi = np.where(np.isfinite(robot.upper), robot.upper, math.pi)
        want = np.random.default_rng(0).uniform(lo, hi, size=(n, robot.n_joints))
        assert np.array_equal(robot.random_configurations(n, 0), want)


def test_permutations_are_the_seed0_generators():
    table = np.load(draws.PERMUTATION_FILE)
    assert table.dtype == np.uint8 and table.shape == (draws.PERMUTATION_MAX * (draws.PERMUTATION_MAX + 1) // 2,)
    for n in range(1, draws.PERMUTATION_MAX + 1):
        got = draws.permutation(0, n)
        assert got.dtype == np.int64
        assert np.array_equal(got, np.random.default_rng(0).permutation(n)), n
    for seed, n in ((0, 0), (0, draws.PERMUTATION_MAX + 1), (0, 1000), (5, 100)):     # numpy's own
        assert np.array_equal(draws.permutation(seed, n), np.random.default_rng(seed).permutation(n))

