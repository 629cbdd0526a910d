"""Instructions per ``calibrate()`` call, counted by valgrind's callgrind: a figure that the load
of a shared machine does not move (its timings drift by tens of percent).

Runs this checkout's ``calibrate()`` with its defaults on N simulated poses of the bundled robot
(the paper's deviations, as scripts/bench_speed.py makes them) under callgrind twice, once with
R calls after three warm ones and once with none, and prints (difference) / R: the instructions of
one warm call (Python, numpy, BLAS and Pinocchio together). The bytecode is cached before the
counted runs (the environment may set PYTHONDONTWRITEBYTECODE).

With ``--first-call N`` the first call of a process instead (issue 27 item 1: at most 3x a warm one),
as scripts/bench_speed.py's first-call figure times it: N simulated poses made before the count,
then the first ``calibrate()`` (the import of its modules on the attribute's first use included)
and the second, each counted as the difference of two runs, and their ratio.

With ``--process`` the whole processes of issue 27 item 2 instead: ``calib calibrate`` on the
bundled example (its 100 + 200 rows) and ``python -c "import pinocchio"``, each counted R times
(the interpreter's start-up moves a count by ~1 %), their medians and ratio.

With ``--iiwa`` also the 1,402 real rows of ../shared/realdata/iiwa7_optical (the defaults, and any
``--iiwa-kwargs`` such as ``"terms='none'"``), skipped with a note when that folder is absent.

Run: python scripts/bench_instructions.py [--poses 100 25] [--calls 5] [--iiwa] [--first-call 25] [--process 3]
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


IIWA = ROOT.parent / "shared" / "realdata" / "iiwa7_optical"


def child(n: int, calls: int, kwargs: str = "", first: bool = False) -> None:
    sys.path.insert(0, str(ROOT))
    import calib
    if n == 0:         # the real iiwa rows
        robot = calib.load_robot(IIWA / "iiwa7_optical_inertial.urdf")
        meas = calib.read_measurements(IIWA / "iiwa7_optical.csv", robot)
        kw = eval(f"dict({kwargs})")
        for _ in range(2 + calls):
            calib.calibrate(robot, meas, **kw)
        return
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = simulate_measurements(true, robot.random_configurations(n, 1), rng=2)
    for _ in range((0 if first else 3) + calls):
        calib.calibrate(robot, meas)


def _counted(argv: list, env: dict | None = None, cwd=None) -> int:
    """The instructions of one run of ``argv`` under callgrind (the benchmark's environment by
    default)."""
    out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null"] + argv,
                         env=_env() if env is None else env, capture_output=True, text=True, cwd=cwd, check=True)
    return int(re.search(r"Collected : (\d+)", out.stderr).group(1))


def instructions(n: int, calls: int, kwargs: str = "") -> float:
    """Instructions of one warm calibrate() call on n poses (0: the real iiwa rows with ``kwargs``)
    (callgrind, difference of two runs)."""
    cmd = [sys.executable, __file__, "--kwargs", kwargs, "--child", str(n)]
    subprocess.run(cmd + ["0"], env=_env(), check=True)          # (the bytecode cached)
    total = [_counted(cmd + [str(k)]) for k in (0, calls)]
    return (total[1] - total[0]) / calls


def first_call_instructions(n: int) -> tuple[float, float]:
    """(instructions of the first calibrate() of a process on n poses, of the second), each the
    difference of two callgrind runs (0, 1 and 2 calls after the data are made)."""
    cmd = [sys.executable, __file__, "--first", "--child", str(n)]
    subprocess.run(cmd + ["1"], env=_env(), check=True)          # (the bytecode of what the call imports cached)
    total = [_counted(cmd + [str(k)]) for k in (0, 1, 2)]
    return total[1] - total[0], total[2] - total[1]


def process_instructions(repeats: int) -> dict:
    """Median callgrind instructions of whole processes: ``calib calibrate`` on the bundled example
    (with and without the dataclass cache) and ``import pinocchio``, after one uncounted run of
    each (the bytecode and the dataclass methods cached)."""
    import statistics
    import tempfile

    urdf = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
    example = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    with tempfile.TemporaryDirectory() as tmp:
        calibrate = [sys.executable, "-m", "calib", "calibrate", str(urdf), str(example), "-o", str(Path(tmp) / "c.urdf")]
        commands = {"calibrate": (calibrate, {}),
                    "pinocchio": ([sys.executable, "-c", "import pinocchio"], {})}
        counts = {name: [] for name in commands}
        for argv, extra in commands.values():
            subprocess.run(argv, env=dict(_env(), **extra), capture_output=True, cwd=tmp, check=True)
        for _ in range(repeats):
            for name, (argv, extra) in commands.items():
                counts[name].append(_counted(argv, env=dict(_env(), **extra), cwd=tmp))
    return {name: statistics.median(v) for name, v in counts.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, nargs="*", default=[100, 25])
    ap.add_argument("--calls", type=int, default=5, help="counted calls per size (default 5)")
    ap.add_argument("--iiwa", action="store_true", help="also the 1,402 real iiwa rows (2 counted calls)")
    ap.add_argument("--iiwa-kwargs", default="", help="calibrate()'s keywords for the iiwa rows, e.g. \"terms='none'\"")
    ap.add_argument("--first-call", type=int, metavar="N",
                    help="only the first call of a process on N poses and the second (issue 27 item 1)")
    ap.add_argument("--process", type=int, metavar="R",
                    help="only the whole processes of issue 27 item 2, R counted runs each: calib calibrate on the "
                         "bundled example over import pinocchio")
    ap.add_argument("--first", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--kwargs", default="", help=argparse.SUPPRESS)
    ap.add_argument("--child", type=int, nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(*args.child, args.kwargs, first=args.first)
        return 0
    if shutil.which("valgrind") is None:
        print("valgrind not found: no instruction counts")
        return 1
    if args.process:
        c = process_instructions(args.process)
        print(f"processes (callgrind, median of {args.process}): calib calibrate on the bundled example "
              f"{c['calibrate'] / 1e6:.1f}M instructions, "
              f"import pinocchio {c['pinocchio'] / 1e6:.1f}M: {c['calibrate'] / c['pinocchio']:.3f}x "
              f"(issue 38 item 4: <= 1.7x in time)")
        return 0
    if args.first_call:
        first, second = first_call_instructions(args.first_call)
        print(f"calibrate(), {args.first_call} poses, defaults: first call of a process {first / 1e6:.1f}M "
              f"instructions (the import of its modules included), the second {second / 1e6:.1f}M: "
              f"{first / second:.2f}x (callgrind; issue 27: first <= 3x warm)")
        return 0
    for n in args.poses:
        print(f"calibrate(), {n} poses, defaults: {instructions(n, args.calls) / 1e6:.2f}M instructions per warm call "
              f"(callgrind, {args.calls} calls)")
    if args.iiwa:
        if not IIWA.is_dir():
            print(f"{IIWA} not found: no iiwa figure")
        else:
            print(f"calibrate(), 1,402 real iiwa rows, {args.iiwa_kwargs or 'defaults'}: "
                  f"{instructions(0, 2, args.iiwa_kwargs) / 1e6:.1f}M instructions per warm call (callgrind, 2 calls)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
