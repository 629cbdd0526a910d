"""Write calib/model/uniform_seed0.npy: the first calib.model.draws.TABLE_SIZE doubles of
``np.random.default_rng(0)`` (``.random``), which calib.model.draws.uniform uses for seed-0
configurations instead of loading numpy.random, and calib/model/permutations_seed0.npy:
``np.random.default_rng(0).permutation(n)`` for n = 1 ... PERMUTATION_MAX one after the other
(uint8), which calib.model.draws.permutation uses for cross-validation's folds
(tests/model/test_draws.py checks both files against the generator).

    python scripts/make_uniform_table.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.model.draws import (PERMUTATION_FILE, PERMUTATION_MAX, TABLE_FILE, TABLE_SEED,  # noqa: E402
                               TABLE_SIZE)


def main() -> None:
    table = np.random.default_rng(TABLE_SEED).random(TABLE_SIZE)
    np.save(TABLE_FILE, table, allow_pickle=False)
    print(f"wrote {TABLE_FILE}: {TABLE_SIZE} doubles of default_rng({TABLE_SEED})")
    perms = np.concatenate([np.random.default_rng(TABLE_SEED).permutation(n) for n in range(1, PERMUTATION_MAX + 1)])
    np.save(PERMUTATION_FILE, perms.astype(np.uint8), allow_pickle=False)
    print(f"wrote {PERMUTATION_FILE}: default_rng({TABLE_SEED}).permutation(n), n = 1 ... {PERMUTATION_MAX}")


if __name__ == "__main__":
    main()
