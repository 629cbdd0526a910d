"""Write calib/model/uniform_seed0.npy: the first calib.model.draws.TABLE_SIZE doubles of
``np.random.default_rng(0)`` (``.random``), which calib.model.draws.uniform uses for seed-0
configurations instead of loading numpy.random (tests/model/test_draws.py checks the file
against the generator).

    python scripts/make_uniform_table.py
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.model.draws import TABLE_FILE, TABLE_SEED, TABLE_SIZE  # noqa: E402


def main() -> None:
    table = np.random.default_rng(TABLE_SEED).random(TABLE_SIZE)
    np.save(TABLE_FILE, table, allow_pickle=False)
    print(f"wrote {TABLE_FILE}: {TABLE_SIZE} doubles of default_rng({TABLE_SEED})")


if __name__ == "__main__":
    main()
