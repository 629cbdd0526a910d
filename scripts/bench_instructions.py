"""Instructions per ``calibrate()`` call, counted by valgrind's callgrind: a figure that the load
of a shared machine does not move (its timings drift by tens of percent).

Runs this checkout's ``calibrate()`` with its defaults on N simulated poses of the bundled robot
(the paper's deviations, as scripts/bench_speed.py makes them) under callgrind twice, once with
R calls after three warm ones and once with none, and prints (difference) / R: the instructions of
one warm call (Python, numpy, BLAS and Pinocchio together). The bytecode is cached before the
counted runs (the environment may set PYTHONDONTWRITEBYTECODE).

Run: python scripts/bench_instructions.py [--poses 100 25] [--calls 5]
(about a minute per size; needs valgrind)
"""
from __future__ import annotations

import _bench

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
def _env() -> dict:
    return _bench.child_env(ROOT)


def child(n: int, calls: int) -> None:
    sys.path.insert(0, str(ROOT))
    import calib
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, robot.random_configurations(n, 1), rng=2)
    for _ in range(3 + calls):
        calib.calibrate(robot, meas)


def instructions(n: int, calls: int) -> float:
    """Instructions of one warm calibrate() call on n poses (callgrind, difference of two runs)."""
    cmd = [sys.executable, __file__, "--child", str(n)]
    subprocess.run(cmd + ["0"], env=_env(), check=True)          # (the bytecode cached)
    total = []
    for k in (0, calls):
        out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null"] + cmd + [str(k)],
                             env=_env(), capture_output=True, text=True, check=True).stderr
        total.append(int(re.search(r"Collected : (\d+)", out).group(1)))
    return (total[1] - total[0]) / calls


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, nargs="+", default=[100, 25])
    ap.add_argument("--calls", type=int, default=5, help="counted calls per size (default 5)")
    ap.add_argument("--child", type=int, nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(*args.child)
        return 0
    if shutil.which("valgrind") is None:
        print("valgrind not found: no instruction counts")
        return 1
    for n in args.poses:
        print(f"calibrate(), {n} poses, defaults: {instructions(n, args.calls) / 1e6:.2f}M instructions per warm call "
              f"(callgrind, {args.calls} calls)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
