"""Shared fixtures: the bundled robot and arms from example-robot-data."""
from __future__ import annotations

import os

# Tiny matrices: BLAS threads only add contention (and made the suite slow under load).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import importlib.util  # noqa: E402
import sys  # noqa: E402
from functools import lru_cache  # noqa: E402
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BUNDLED_URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"

def load_script(name: str):
    """``scripts/NAME.py`` as a module, for the tests of a benchmark's functions: registered in
    ``sys.modules`` as NAME (a dataclass there looks its module up), with ``scripts/`` on the
    path while it loads (the benchmarks import their sibling ``_bench``)."""
    folder = ROOT / "scripts"
    spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.path.insert(0, str(folder))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(folder))
    return module


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


def bundled_or_ur5(name: str):
    """The robots the pose-selection tests run on: "bundled" (BRTIRUS0707A) or UR5 (tool0)."""
    from calib import load_robot

    if name == "bundled":
        return load_robot(BUNDLED_URDF)
    return load_robot(erd_urdf("ur5"), tool_frame="tool0")


def fd_pose_column(robot, Q, k: int, h: float = 1e-6):
    """(N, 6) central differences of the exact forward model (RobotModel.T_meas_tool: Eq. 1
    products, no batch kinematics) in parameter k at configurations Q: position (m) and the
    rotation's SO(3) log (rad) per unit of the parameter, as the identification Jacobian's
    rows."""
    import numpy as np

    from calib.model.spatial import log3_batch

    e = np.zeros(robot.n_params)
    e[k] = h
    Tp = np.array([robot.with_values(robot.values + e).T_meas_tool(q) for q in Q])
    Tm = np.array([robot.with_values(robot.values - e).T_meas_tool(q) for q in Q])
    dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
    dw = log3_batch(Tp[:, :3, :3] @ np.transpose(Tm[:, :3, :3], (0, 2, 1))) / (2 * h)
    return np.concatenate([dp, dw], axis=1)


def urdf_numbers(text: str):
    """(the URDF text with every number as #, the numbers (k,) float) of a calibrated URDF, to
    compare two calibrations number by number; without the comment's list of recomputed origins,
    which lists a joint whose origin moved by less than the writer's threshold in one reading and
    not the other (differences of 1e-16 in the data)."""
    import re

    import numpy as np

    text = re.sub(r"Recomputed joint origins: [^.]*\.", "", text)
    pattern = r"-?\d+\.?\d*(?:[eE][-+]?\d+)?"
    return re.sub(pattern, "#", text), np.array([float(v) for v in re.findall(pattern, text)])


def pytest_addoption(parser):
    group = parser.getgroup("calib documents (tests/test_docs.py)")
    group.addoption("--update-docs", action="store_true",
                    help="rewrite the output blocks of README.md and docs/*.md from what their commands print")
    group.addoption("--docs-bench", action="store_true",
                    help="also run the documents' benchmark blocks (minutes, or data in ../shared)")
