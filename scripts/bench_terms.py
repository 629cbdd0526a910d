"""The choice of joint terms (calib.calibration.terms.choose_terms) on simulated arms with known truth.

For each arm of example-robot-data (real link masses: compliance is a candidate) and each truth:
geometric deviations only; + gravity compliance (a few urad/(N m) on the joints that carry
torque); + periodic joint errors (first and second harmonics, ``--periodic-urad`` per
coefficient), calibration rows of pose data with noise, and ``choose_terms`` on them. Prints how
often each candidate is chosen over the seeds: the geometry-only truth measures the rule's false
positives (terms taken for noise), the others its power.

    python scripts/bench_terms.py [--seeds 10] [--poses 300] [--arms ur10,panda]
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402,F401  (one BLAS thread)

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.calibration.terms import choose_terms  # noqa: E402
from calib.model.compliance import with_gravity  # noqa: E402


def truth(robot, kind: str, rng, periodic_rad: float):
    true = robot.with_changes(**calib.random_deviations(robot, 3e-4, rng))
    if kind in ("compliance", "both"):
        c = rng.uniform(2e-6, 5e-6, robot.n_joints)
        true = with_gravity(true, values=c)
    if kind in ("periodic", "both"):
        n_rev = int((~robot.prismatic).sum())
        true = true.with_periodic(rng.normal(0.0, periodic_rad, 4 * n_rev))
    return true


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--arms", default="ur10,panda")
    ap.add_argument("--periodic-urad", type=float, default=100.0)
    ap.add_argument("--sigma-pos-mm", type=float, default=0.05)
    ap.add_argument("--sigma-rot-rad", type=float, default=0.0005)
    args = ap.parse_args(argv)
    print(f"{args.poses} pose rows, noise {args.sigma_pos_mm} mm / {args.sigma_rot_rad} rad per axis, "
          f"{args.seeds} seeds; periodic coefficients N(0, {args.periodic_urad:g} urad)")
    for arm in args.arms.split(","):
        robot = calib.load_robot(arm)
        for kind in ("geometry", "compliance", "periodic", "both"):
            chosen, t0 = Counter(), time.perf_counter()
            for seed in range(args.seeds):
                rng = np.random.default_rng(1000 + seed)
                true = truth(robot, kind, rng, args.periodic_urad * 1e-6)
                m = calib.simulate_measurements(true, robot.random_configurations(args.poses, rng),
                                                sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad,
                                                rng=rng)
                chosen[choose_terms(robot, m).label] += 1
            per = (time.perf_counter() - t0) / args.seeds
            print(f"  {arm:<7} truth {kind:<11} chosen: " +
                  ", ".join(f"{k} {v}" for k, v in sorted(chosen.items())) + f"   ({per:.2f} s per choice)",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
