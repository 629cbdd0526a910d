"""Benchmark of the identification Jacobian (issue 3): 100 and 10,000 poses x 37 parameters.

Prints the median over repeated runs of: a per-pose loop of Pinocchio's forward kinematics plus
kinematic regressor (the reference the tests compare with), and calib's whole Jacobian
(vectorised over poses, :meth:`calib.model.kinematics.ChainKinematics.poses_and_jacobian`), and their
ratio.
Targets: 100 poses < 1 ms, 10,000 poses < 60 ms, on one core.

Run: python scripts/bench_jacobian.py
"""
from __future__ import annotations

from pathlib import Path

import _bench  # noqa: F401  (sets one BLAS thread before numpy loads)
import numpy as np
import pinocchio as pin

import calib
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    kin = ChainKinematics(robot)
    print(f"machine: {_bench.machine()}")
    print(f"{'poses':>7} {'FK+regressor (Pinocchio)':>26} {'full Jacobian':>15} {'speed-up':>9}  target")
    for n, target in ((100, 1e-3), (10_000, 60e-3)):
        Q = robot.random_configurations(n, 0)
        Qp = np.hstack([Q, np.zeros((n, 1))])
        model, data, fid = kin.model, kin.data, kin.tool_frame_id

        def fk_reg():
            for q in Qp:
                pin.forwardKinematics(model, data, q)
                pin.updateFramePlacement(model, data, fid)
                pin.computeFrameKinematicRegressor(model, data, fid, pin.LOCAL_WORLD_ALIGNED)

        repeats = 31 if n <= 100 else 9
        t_pin = _bench.median_time(fk_reg, repeats)
        t_jac = _bench.median_time(lambda: pose_jacobian(kin, Q), repeats)
        ok = "ok" if t_jac < target else "MISSED"
        print(f"{n:>7} {t_pin * 1e3:>23.3f} ms {t_jac * 1e3:>12.3f} ms {t_pin / t_jac:>8.1f}x"
              f"  < {target * 1e3:g} ms {ok}")
    _, _, J = pose_jacobian(kin, robot.random_configurations(100, 0))
    print(f"Jacobian shape for 100 poses: {J.reshape(-1, J.shape[2]).shape}")


if __name__ == "__main__":
    main()
