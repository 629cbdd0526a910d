"""Seeded uniform draws without loading ``numpy.random`` where a stored table covers them.

The default calibration draws random configurations with seed 0 only (the robot's reach, the
rank at random poses, the workspace prediction): ``np.random.default_rng(0).uniform(lo, hi,
size=(n, k))``. Importing ``numpy.random`` for them took ~6 ms of a ~220 ms ``calib calibrate``
(31M instructions). :data:`TABLE_FILE` holds the first :data:`TABLE_SIZE` doubles of that
generator (``np.random.default_rng(0).random(TABLE_SIZE)``, written by
``scripts/make_uniform_table.py``); numpy's ``uniform`` computes ``lo + (hi - lo) * u`` from the
same doubles in the same order (row-major), so :func:`uniform` returns the generator's values
bit for bit (``tests/model/test_draws.py`` checks the table against the generator and the draws
against ``uniform``). Other seeds, and draws longer than the table, ask numpy. Bit for bit
on x86-64; where numpy's C code fuses ``lo + range * u`` into one multiply-add (some arm64
builds), the draws may differ from numpy's by 1 ulp.

Cross-validation deals rows into folds by ``np.random.default_rng(0).permutation(n)`` (the
fit's choice of joint terms, 100 poses: the only use of ``numpy.random`` left on that run, 31M
instructions). :data:`PERMUTATION_FILE` holds those permutations for n = 1 ...
:data:`PERMUTATION_MAX` one after the other (integers: exact; written by the same script and
checked against the generator by the same test); :func:`permutation` takes them from there.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

#: The stored doubles of ``np.random.default_rng(0).random(TABLE_SIZE)``: 256 configurations of
#: up to 16 joints.
TABLE_SIZE = 4096
TABLE_FILE = Path(__file__).with_name("uniform_seed0.npy")
#: The seed the table stands for.
TABLE_SEED = 0

@functools.cache
def _stored(file: Path) -> np.ndarray:
    """A stored table (read-only), loaded on first use."""
    t = np.load(file)
    t.setflags(write=False)
    return t


def uniform(seed: int, lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """(n, k) draws ``np.random.default_rng(seed).uniform(lo, hi, size=(n, k))`` for the (k,)
    bounds ``lo``, ``hi`` (float arrays, any unit): from the stored table for seed 0 when it
    holds n * k doubles and the ranges are finite, else from numpy (which also raises on a
    range beyond the floats, or a seed it does not take)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    k = lo.shape[0]
    with np.errstate(over="ignore"):            # (numpy warns below, as before)
        span = hi - lo
    if type(seed) is int and seed == TABLE_SEED and n * k <= TABLE_SIZE and np.isfinite(span).all():
        return lo + span * _stored(TABLE_FILE)[:n * k].reshape(n, k)
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, k))


#: ``np.random.default_rng(0).permutation(n)`` for n = 1 ... PERMUTATION_MAX, concatenated (uint8).
PERMUTATION_MAX = 256
PERMUTATION_FILE = Path(__file__).with_name("permutations_seed0.npy")


def permutation(seed: int, n: int) -> np.ndarray:
    """(n,) int ``np.random.default_rng(seed).permutation(n)``: from the stored permutations for
    seed 0 and n <= :data:`PERMUTATION_MAX`, else from numpy."""
    if type(seed) is int and seed == TABLE_SEED and 0 < n <= PERMUTATION_MAX:
        start = n * (n - 1) // 2
        return _stored(PERMUTATION_FILE)[start:start + n].astype(np.int64)
    return np.random.default_rng(seed).permutation(n)
