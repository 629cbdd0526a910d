"""EB-MAP against least squares on simulated few-row data (issue 22's simulated criterion).

For each case (robot, rows, pose or position-only) and each seed: a true robot with Gaussian
deviations of every parameter (``calib.random_deviations(robot, 1e-3)``: 1 mm lengths, 2 mrad
angles), the instrument 1.7 m from the base, random configurations within the joint limits,
noise 1 mm and 5 mrad per axis. Fits: least squares on the identifiable set
(``params="base"``), ``calib.calibrate`` defaults, :func:`calib.calibration.estimators.eb_map.eb_map`. Printed per
case: the mean over seeds of the RMS tool-position distance to the truth over 300 new random
configurations (mm), EB-MAP over LS, the share of seeds where EB-MAP is closer, EB-MAP's
predicted over observed held-out RMS on 300 new measured rows, and the oracle over LS: the same
MAP estimate with the simulation's true prior scales and noise levels held
(``eb_map(..., prior_scales=TRUE_SCALES, sigma_pos, sigma_rot)``), the best an estimator of this
kind can do on these rows (the Bayes estimate of the linearised model); the gap between EB-MAP
and the oracle is the cost of choosing the scales and noise from the rows themselves.

Run: PYTHONPATH=. python scripts/bench_ebmap_sim.py [--seeds 50]
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread before numpy loads)

import argparse
import sys
import warnings
from dataclasses import replace

import numpy as np

CASES = (("ur5", 15, False), ("ur5", 20, False), ("ur5", 30, False), ("ur5", 20, True),
         ("panda", 20, False), ("panda", 30, False), ("bundled", 25, False))


def load(name: str):
    import calib

    if name == "bundled":
        return calib.load_robot(calib.robot_path("robots/brtirus0707a/brtirus0707a.urdf"))
    import example_robot_data as erd

    return calib.load_robot(erd.load(name).urdf)


#: The simulation's parameter deviations (random_deviations(robot, 1e-3)) and noise, as prior
#: scales and noise levels for the oracle.
DEVIATION = 1e-3
TRUE_SCALES = {"theta": DEVIATION / 0.5, "length": DEVIATION, "twist": DEVIATION / 0.5}
SIGMA_POS, SIGMA_ROT = 1e-3, 5e-3


def one(robot, n: int, position_only: bool, seed: int) -> tuple[float, ...]:
    """(LS error, defaults error, EB-MAP error (m), EB-MAP predicted / observed, oracle error (m))
    of one seed."""
    import calib
    from calib.calibration.estimators.eb_map import eb_map
    from calib.model.kinematics import ChainKinematics
    from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements
    from calib.model.spatial import zyx_transform

    rng = np.random.default_rng(1000 + seed)
    true = apply_deviations(robot, random_deviations(robot, DEVIATION, rng))
    true = replace(true, T_meas_base_ref=zyx_transform(1.5, -0.8, 0.3, 0.5, 0.05, -0.03) @ true.T_meas_base_ref)
    m = simulate_measurements(true, robot.random_configurations(n, rng), sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=rng,
                              position_only=position_only)
    Qt = robot.random_configurations(300, rng)
    _, p_true = ChainKinematics(true).frame_poses(Qt)

    def err(model):
        _, p = ChainKinematics(model).frame_poses(Qt)
        return float(np.sqrt(np.mean(np.sum((p - p_true) ** 2, axis=1))))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            ls = err(calib.calibrate(robot, m, params="base").robot)
        except calib.CalibError:
            ls = np.nan
        try:
            de = err(calib.calibrate(robot, m).robot)
        except calib.CalibError:
            de = np.nan
        eb = eb_map(robot, m)
        oracle = eb_map(robot, m, sigma_pos=SIGMA_POS, sigma_rot=None if position_only else SIGMA_ROT,
                        prior_scales=TRUE_SCALES)
    fresh = simulate_measurements(true, Qt, sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=rng,
                                  position_only=position_only)
    ratio = eb.predicted_holdout(Qt)["position_rms"] / calib.evaluate(eb.robot, fresh).position["rms"]
    return ls, de, err(eb.robot), ratio, err(oracle.robot)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    args = ap.parse_args(argv)
    print(f"{args.seeds} seeds; mean RMS distance to the truth over 300 new configurations (mm)")
    print(f"{'case':<24}{'LS ident':>10}{'defaults':>10}{'EB-MAP':>10}{'EB/LS':>8}{'EB closer':>11}{'pred/obs':>10}{'oracle/LS':>11}")
    robots = {}
    for name, n, pos in CASES:
        robot = robots.setdefault(name, load(name))
        r = np.array([one(robot, n, pos, s) for s in range(args.seeds)])
        ls, de, eb = (np.nanmean(r[:, k]) * 1e3 for k in range(3))
        closer = np.mean(r[:, 2] < r[:, 0])
        label = f"{name} {n} {'position' if pos else 'pose'}"
        print(f"{label:<24}{ls:>10.3f}{de:>10.3f}{eb:>10.3f}{eb / ls:>8.3f}{closer:>10.0%}{np.mean(r[:, 3]):>10.3f}"
              f"{np.nanmean(r[:, 4]) * 1e3 / ls:>11.3f}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
