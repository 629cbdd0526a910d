"""Compensation speed (issue 27 item 4): pose targets and joint targets per second.

    python scripts/bench_compensate.py [--repeats 3]

The bundled robot with the paper's deviations plays the calibrated model; the targets are the
nominal model's tool poses at random configurations within the joint limits (what a program
holds). Prints, for 1k and 10k targets, the median over ``--repeats`` runs of
``compensate_poses`` without starting joints (the path that tried 17 starts per target: 145
targets per second before) and of ``compensate`` of joint targets (7,700 per second before),
the statuses, and the peak memory per pose target (tracemalloc, one run of 10k). Wall time and
CPU time of this process are printed side by side (the machine may be shared).
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread)

import argparse
import os
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from calib import PAPER_DEVIATIONS, apply_deviations, load_robot  # noqa: E402
from calib.compensation.compensate import compensate, compensate_poses  # noqa: E402
from calib.model.kinematics import ChainKinematics  # noqa: E402

URDF = Path(__file__).resolve().parents[1] / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
#: Figures of issue 27 before this work (targets per second).
BEFORE = {"pose": 145.0, "joint": 7700.0}
TARGET = {"pose": 5000.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    print(_bench.machine())
    print(f"load average {os.getloadavg()[0]:.2f} (wall times grow with the load; CPU times less)")
    nominal = load_robot(URDF)
    calibrated = apply_deviations(nominal, PAPER_DEVIATIONS)
    for n in (1_000, 10_000):
        Q = nominal.random_configurations(n, 7)
        R, p = ChainKinematics(nominal).frame_poses(Q)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
        res = {}

        def poses():
            res["pose"] = compensate_poses(calibrated, T_meas_tool=T)

        def joints():
            res["joint"] = compensate(calibrated, nominal, Q)
        tp = _bench.median_time(poses, args.repeats, warmup=0)
        cp = _bench.median_time(poses, args.repeats, warmup=0, clock=time.process_time)
        tj = _bench.median_time(joints, args.repeats, warmup=0)
        cj = _bench.median_time(joints, args.repeats, warmup=0, clock=time.process_time)
        print(f"{n:>6} pose targets : {n / tp:>7.0f} targets/s wall, {n / cp:>7.0f} per CPU second (medians of "
              f"{args.repeats}; before {BEFORE['pose']:.0f}/s, target >= {TARGET['pose']:.0f}/s); {res['pose'].counts()}")
        print(f"{n:>6} joint targets: {n / tj:>7.0f} targets/s wall, {n / cj:>7.0f} per CPU second (before "
              f"{BEFORE['joint']:.0f}/s); {res['joint'].counts()}")
    tracemalloc.start()
    compensate_poses(calibrated, T_meas_tool=T)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"peak memory of 10k pose targets: {peak / 1e6:.1f} MB ({peak / len(T) / 1e3:.1f} kB per target)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
