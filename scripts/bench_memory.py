"""Benchmark of memory (issue 13, item 7): peak memory per row of reading and calibrating.

For each size N (default 20,000 and 100,000 rows of the bundled robot, noisy, paper deviations)
a fresh Python process imports calib, reads the file and runs ``calibrate`` with its defaults
(noise estimation, cross-validation, statistics); the script prints the file size, the peak
resident memory (VmHWM) after import, after reading, after calibrating, and the growth
per row above the loaded data, and the estimate calib's reader uses to refuse a file too large
for the machine (:data:`calib.io.csv.layer.READ_BYTES_PER_FILE_BYTE`, measured by bench_read.py).

Run: python scripts/bench_memory.py [N ...]
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import _bench
import numpy as np

import calib
from calib.io.csv.lines import READ_BYTES_PER_FILE_BYTE

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"

CHILD = r"""
import json, resource, sys, time
def rss():
    # peak resident memory of this process image: VmHWM is reset by exec, while ru_maxrss keeps
    # the parent's peak across fork + exec (the parent holds the simulated data)
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
import calib
robot = calib.load_robot(sys.argv[1])     # (numpy and Pinocchio loaded: not per row)
r0 = rss()
t = time.perf_counter()
m = calib.read_measurements(sys.argv[2], robot)
t_read = time.perf_counter() - t
r1 = rss()
t = time.perf_counter()
res = calib.calibrate(robot, m)
t_cal = time.perf_counter() - t
r2 = rss()
print(json.dumps({"import": r0, "read": r1, "calibrate": r2, "status": res.status,
                  "t_read": t_read, "t_cal": t_cal}))
"""


def measure(n: int, folder: Path) -> dict:
    robot = calib.load_robot(URDF)
    rng = np.random.default_rng(n)
    true = calib.apply_deviations(robot, calib.PAPER_DEVIATIONS)
    meas = calib.simulate_measurements(true, robot.random_configurations(n, rng), rng=rng)
    path = folder / f"meas_{n}.csv"
    calib.write_measurements(path, meas)
    out = subprocess.run([sys.executable, "-c", CHILD, str(URDF), str(path)], capture_output=True,
                         text=True, check=True, env={**_bench.os.environ, "PYTHONPATH": str(ROOT)})
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    rec["n"], rec["bytes"] = n, path.stat().st_size
    return rec


def main(argv: list[str]) -> None:
    sizes = [int(a) for a in argv] or [20_000, 100_000]
    print(f"machine: {_bench.machine()}")
    print(f"{'rows':>8} {'file MB':>8} {'import MB':>10} {'+read MB':>9} {'+calib MB':>10} "
          f"{'read B/row':>11} {'calib B/row':>12} {'read s':>7} {'calib s':>8}  status")
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            r = measure(n, Path(tmp))
            read, cal = r["read"] - r["import"], r["calibrate"] - r["read"]
            print(f"{n:>8} {r['bytes'] / 1e6:>8.1f} {r['import'] / 1e6:>10.0f} {read / 1e6:>9.0f} "
                  f"{cal / 1e6:>10.0f} {read / n:>11.0f} {cal / n:>12.0f} {r['t_read']:>7.1f} "
                  f"{r['t_cal']:>8.1f}  {r['status']}")
            print(f"{'':>8} peak above import per file byte: "
                  f"{(r['calibrate'] - r['import']) / r['bytes']:.1f} (the reader refuses a file when "
                  f"{READ_BYTES_PER_FILE_BYTE:g} x its size exceeds the available memory)")


if __name__ == "__main__":
    main(sys.argv[1:])
