"""Shared fixtures: the bundled robot and arms from example-robot-data."""
from __future__ import annotations

import os

# Tiny matrices: BLAS threads only add contention (and made the suite slow under load).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from functools import lru_cache  # noqa: E402
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BUNDLED_URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"

#: (name, URDF path getter, tool frame or None for the default)
ERD_ARMS = [("ur5", None), ("ur10", "tool0"), ("panda", None), ("kinova", None), ("xarm7", None)]


@lru_cache(maxsize=None)
def erd_urdf(name: str) -> str:
    import example_robot_data as erd

    return erd.load(name).urdf


@pytest.fixture(scope="session")
def bundled_urdf() -> Path:
    return BUNDLED_URDF


@pytest.fixture(scope="session")
def bundled_robot():
    from calib import load_robot

    return load_robot(BUNDLED_URDF)
