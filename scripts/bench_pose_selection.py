"""Benchmark of pose selection (calib.design.poses): accuracy of a calibration on N selected poses
against N random poses, and the time of the selection.

For each robot and N, and for each of --draws draws: a "true" robot (the bundled BRTIRUS0707A
with the paper's deviations of Tables 4-5; UR5 with random deviations, 0.5 mm / 1 mrad scale,
new each draw), 200 noise-free validation poses uniform within the joint limits, and two
calibrations from noisy measurements (0.02 mm, 0.002 rad per axis, as the paper's simulation):
one on N poses selected by `select_poses` (2000 candidates, criterion D, seed = draw), one on N
uniform random poses. Prints the median over the draws of the validation RMS position error of
the calibrated model (mm), the ratio selected / random, and how often the selection won; and the
same for the Cramer-Rao prediction of that error (from the covariance of the fit: free of the
luck of one noise draw, it measures the pose set itself). Then the
wall time of `select_poses` for n = 20 and 50 from 2000 candidates, each criterion, one core.

    python scripts/bench_pose_selection.py [--draws 20] [--n 20 30] [--criterion D]
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.design.poses import CRITERIA, design_poses

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUNDLED = os.path.join(ROOT, "robots", "brtirus0707a", "brtirus0707a.urdf")


def robots():
    import example_robot_data as erd

    bundled = calib.load_robot(BUNDLED)
    ur5 = calib.load_robot(erd.load("ur5").urdf, tool_frame="tool0")
    return [("BRTIRUS0707A, paper deviations", bundled, lambda r, rng: dict(calib.PAPER_DEVIATIONS)),
            ("UR5, random deviations 0.5 mm", ur5, lambda r, rng: calib.random_deviations(r, 0.5e-3, rng))]


def accuracy(robot, deviations, n, draws, candidates, criterion):
    """Validation RMS (m) of calibrations on selected and on random poses, per draw, achieved
    and predicted (Cramer-Rao, at the validation configurations)."""
    out = {"selected": [], "random": [], "selected_cr": [], "random_cr": []}
    for draw in range(draws):
        rng = np.random.default_rng(1000 + draw)
        true = calib.apply_deviations(robot, deviations(robot, rng))
        val = calib.simulate_measurements(true, robot.random_configurations(200, rng),
                                          sigma_pos=0.0, sigma_rot=0.0)
        sets = {"selected": calib.design.poses.select_poses(robot, n, candidates=candidates,
                                                     criterion=criterion, seed=draw),
                "random": robot.random_configurations(n, rng)}
        for label, Q in sets.items():
            meas = calib.simulate_measurements(true, Q, sigma_pos=2e-5, sigma_rot=2e-3, rng=rng)
            result = calib.calibrate(robot, meas, validation=val)
            out[label].append(result.validation_after.position["rms"])
            out[label + "_cr"].append(result.predicted["position_rms"])
    return {k: np.array(v) for k, v in out.items()}


def selection_time(robot, n, criterion, candidates, repeats=3):
    times = []
    for seed in range(repeats):
        t = time.perf_counter()
        design_poses(robot, n, candidates=candidates, criterion=criterion, seed=seed)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--n", type=int, nargs="+", default=[20, 30])
    parser.add_argument("--candidates", type=int, default=2000)
    parser.add_argument("--criterion", default="D", choices=CRITERIA)
    args = parser.parse_args()

    import pinocchio

    print(f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"numpy {np.__version__}, pinocchio {pinocchio.__version__}, 1 BLAS thread")
    print(f"\nValidation RMS position error after calibration (mm), median over {args.draws} draws "
          f"(truth, noise, pose sets); selection: criterion {args.criterion}, "
          f"{args.candidates} candidates")
    print(f"{'':<38}{'achieved':^41}{'predicted (Cramer-Rao)':^30}")
    print(f"{'robot':<34}{'N':>4}{'selected':>11}{'random':>11}{'ratio':>8}{'sel. wins':>11}"
          f"{'selected':>11}{'random':>11}{'ratio':>8}")
    for name, robot, deviations in robots():
        for n in args.n:
            r = accuracy(robot, deviations, n, args.draws, args.candidates, args.criterion)
            sel, rnd = np.median(r["selected"]) * 1e3, np.median(r["random"]) * 1e3
            wins = int((r["selected"] < r["random"]).sum())
            sel_cr, rnd_cr = np.median(r["selected_cr"]) * 1e3, np.median(r["random_cr"]) * 1e3
            print(f"{name:<34}{n:>4}{sel:>11.4f}{rnd:>11.4f}{sel / rnd:>8.2f}"
                  f"{f'{wins}/{args.draws}':>11}{sel_cr:>11.4f}{rnd_cr:>11.4f}{sel_cr / rnd_cr:>8.2f}")

    print(f"\nSelection time (s, median of 3 seeds), {args.candidates} candidates, pose "
          f"measurements, one core")
    print(f"{'robot':<34}{'n':>4}" + "".join(f"{c:>9}" for c in CRITERIA))
    for name, robot, _ in robots():
        for n in (20, 50):
            times = [selection_time(robot, n, c, args.candidates) for c in CRITERIA]
            print(f"{name:<34}{n:>4}" + "".join(f"{t:>9.2f}" for t in times))
        design = design_poses(robot, 50, candidates=args.candidates, seed=0)
        print("  " + design.format().replace("\n", "\n  "))


if __name__ == "__main__":
    main()
