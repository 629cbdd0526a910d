"""The predicted error over the workspace (issue 22 item 4): its cost and its honesty.

1. Cost: ``calib.calibrate()`` on the bundled robot's 100 simulated poses (paper deviations,
   noise 0.02 mm / 0.002 rad), median CPU time with the workspace prediction and with it
   replaced by nothing, interleaved; and ``predict_workspace`` alone.
2. Honesty: for each arm (UR5, TIAGo, Kinova, Panda, Z1) and seed, 40 rows either bunched
   within +-0.15 rad (+-20 mm prismatic) of one random configuration (the UR5's with its wrist
   singular, q5 = 0) or spread over the limits; ~1 mm / 1 mrad errors, 0.05 mm / 0.1 mrad noise;
   ``calibrate()`` with defaults. Printed: the predicted error on new rows at the calibration
   configurations (``predicted_holdout``), over the workspace (``predicted_workspace``), the
   predicted error against the truth over the workspace, the observed one at 500 fresh random
   configurations, their ratio, and whether the note appeared.

    python scripts/bench_workspace.py [--seeds 3] [--robots ur5 tiago kinova panda z1]
"""
from __future__ import annotations

import argparse
import functools
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402,F401  (one BLAS thread)

import numpy as np  # noqa: E402

import calib  # noqa: E402
import calib.calibration.accuracy.statistics as stats_module  # noqa: E402
from calib.calibration.accuracy.workspace import WORKSPACE_CONFIGURATIONS, predict_workspace, workspace_configurations  # noqa: E402
from calib.model.kinematics import ChainKinematics  # noqa: E402
from calib.model.simulate import (PAPER_DEVIATIONS, apply_deviations, random_deviations,  # noqa: E402
                                  simulate_measurements)

ROOT = Path(__file__).resolve().parents[1]


def cost(repeats: int = 40) -> None:
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    m = simulate_measurements(true, robot.random_configurations(100, 1), sigma_pos=0.02e-3, sigma_rot=0.002, rng=2)
    original = stats_module.predict_workspace
    variants = {"with the workspace prediction": original, "without it": lambda *a, **k: None}
    times = {v: [] for v in variants}
    try:
        for _ in range(repeats):
            for v, f in variants.items():
                stats_module.predict_workspace = f
                t = time.process_time()
                calib.calibrate(robot, m)
                times[v].append(time.process_time() - t)
    finally:
        stats_module.predict_workspace = original
    print("calibrate(), bundled robot, 100 poses, defaults (median CPU over "
          f"{repeats - 3} interleaved runs):")
    for v, ts in times.items():
        print(f"  {v:<32}{statistics.median(ts[3:]) * 1e3:8.2f} ms")
    res = calib.calibrate(robot, m)
    one = functools.partial(predict_workspace, res.robot, res.free, res.covariance, res.sigma_pos, res.sigma_rot,
                            calibration_q=m.q, kin=ChainKinematics(res.robot))
    print(f"  predict_workspace alone ({WORKSPACE_CONFIGURATIONS} configurations, {len(res.free)} parameters): "
          f"{_bench.median_time(one, 41, 3, time.process_time) * 1e3:.2f} ms")


def _case(robot, name, seed, bunched, n=40):
    rng = np.random.default_rng(100 + seed)
    true = apply_deviations(robot, random_deviations(robot, 1e-3, rng))
    if bunched:
        centre = robot.random_configurations(1, rng)[0]
        if name == "ur5":
            centre[4] = 0.0
        half = np.where(robot.prismatic, 0.02, 0.15)
        Q = rng.uniform(np.maximum(centre - half, robot.lower), np.minimum(centre + half, robot.upper),
                        size=(n, robot.n_joints))
    else:
        Q = robot.random_configurations(n, rng)
    return true, simulate_measurements(true, Q, sigma_pos=0.05e-3, sigma_rot=1e-4, rng=rng)


def honesty(robots, seeds: int) -> None:
    import example_robot_data as erd

    print("\n40 rows, ~1 mm errors, 0.05 mm noise; figures in mm (position):")
    print(f"  {'arm':<8}{'poses':<9}{'seed':>4}{'at cal.':>9}{'workspace':>11}{'vs truth':>10}"
          f"{'observed':>10}{'pred/obs':>10}  note")
    for name in robots:
        robot = calib.load_robot(name) if name == "tiago" else calib.load_robot(erd.load(name).urdf)
        for bunched in (True, False):
            for seed in range(seeds):
                true, m = _case(robot, name, seed, bunched)
                res = calib.calibrate(robot, m)
                w = res.predicted_workspace
                Q = workspace_configurations(robot, 500, seed=77)
                _, p0 = ChainKinematics(true).frame_poses(Q)
                _, p1 = ChainKinematics(res.robot).frame_poses(Q)
                obs = math.sqrt(float(np.mean(np.sum((p1 - p0) ** 2, axis=1))))
                note = any(n.startswith("the predicted error on new rows over the workspace") for n in res.notes)
                print(f"  {name:<8}{'bunched' if bunched else 'spread':<9}{seed:>4}"
                      f"{res.predicted_holdout['position_rms'] * 1e3:>9.3f}{w['position_rms'] * 1e3:>11.3f}"
                      f"{w['model_position_rms'] * 1e3:>10.3f}{obs * 1e3:>10.3f}"
                      f"{w['model_position_rms'] / obs:>10.2f}  {'yes' if note else 'no'}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--robots", nargs="*", default=["ur5", "tiago", "kinova", "panda", "z1"])
    args = ap.parse_args()
    print(_bench.machine())
    cost()
    honesty(args.robots, args.seeds)


if __name__ == "__main__":
    main()
