"""Benchmark of identification (issue 4): C-LM and LM on the paper's simulation.

Methods: search-lm (the default), c-lm (the paper's), lm. The problem: BRTIRUS0707A, the deviations of Tables 4-5, 100 random poses, Gaussian noise
0.02 mm / 0.002 rad. Prints the median wall time of ``calib.calibrate`` (everything: parameter
selection, frame check, iterations, covariance, statistics) and of the iterations alone, the
number of Jacobian evaluations, the cost of one FK+regressor pass for comparison, and the
scaling with the number of poses (100 ... 10,000). Targets: C-LM < 15 ms for 100 poses,
10,000 poses < 1 s, linear cost.

Run: python scripts/bench_calibrate.py
"""
from __future__ import annotations

from pathlib import Path

import _bench  # noqa: F401  (sets one BLAS thread before numpy loads)
import numpy as np

import calib
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
from calib.solvers.angles import RotationChain
from calib.solvers.lm import LMOptions, LMTrace, levenberg_marquardt
from calib.solvers.problem import Problem
from calib.solvers.schemes import cross_lm, search_lm

ROOT = Path(__file__).resolve().parents[1]


def iterations_only(robot, meas, free, method):
    """Just the LM / C-LM iterations on a prepared problem (what the paper's 2.3 s timed)."""
    kin = ChainKinematics(robot)
    idx = robot.indices(free)
    prob = Problem(kin, meas.q, meas.position, meas.rotation, robot.values, idx, 2e-5, 2e-3)
    trace = LMTrace()
    angular = np.array([robot.parameters[k].is_angular for k in idx])
    if method == "search-lm":
        search_lm(prob, robot.values[idx], angular, RotationChain(robot), options=LMOptions(), trace=trace)
    elif method == "c-lm":
        cross_lm(prob, robot.values[idx], angular, trace=trace)
    else:
        levenberg_marquardt(prob, robot.values[idx], trace=trace)
    return trace


def main() -> None:
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    print(f"machine: {_bench.machine()}")
    print("problem: BRTIRUS0707A, Tables 4-5 deviations, noise 0.02 mm / 0.002 rad, params 'base' (30)")
    free = calib.analyze_identifiability(robot).identifiable
    print(f"{'poses':>7} {'method':>6} {'calibrate()':>12} {'iterations':>11} {'J evals':>8} "
          f"{'FK+reg':>9} {'val RMS':>10}")
    for n in (100, 1000, 10_000):
        Q = robot.random_configurations(n, 1)
        meas = simulate_measurements(true, Q, rng=2)
        val = simulate_measurements(true, robot.random_configurations(200, 3), sigma_pos=0, sigma_rot=0)
        kin = ChainKinematics(robot)
        t_fk = _bench.median_time(lambda: pose_jacobian(kin, Q), 5 if n > 100 else 21)
        for method in ("search-lm", "c-lm", "lm"):
            repeats = 21 if n == 100 else 5
            t_cal = _bench.median_time(lambda: calib.calibrate(robot, meas, method=method), repeats)
            t_it = _bench.median_time(lambda: iterations_only(robot, meas, free, method), repeats)
            trace = iterations_only(robot, meas, free, method)
            res = calib.calibrate(robot, meas, method=method, validation=val)
            print(f"{n:>7} {method:>6} {t_cal * 1e3:>9.2f} ms {t_it * 1e3:>8.2f} ms {trace.jacobians:>8} "
                  f"{t_fk * 1e3:>6.2f} ms {res.validation_after.position['rms'] * 1e3:>7.4f} mm")
    print("targets: C-LM < 15 ms at 100 poses; < 1 s at 10,000 poses; cost linear in poses")
    print("(the paper's MATLAB C-LM: 2.295 s per identification, Table 8)")


if __name__ == "__main__":
    main()
