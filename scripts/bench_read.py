"""Benchmark of the CSV reader (issue 25, item 4): reading 200,000 and 1,000,000 rows.

Targets: 200,000 rows read in under 3 s; 1,000,000 rows read in at most 1 KB of memory per row.

For each size N a measurement file of the bundled robot is written once (calib's own format:
6 joints in degrees, x, y, z in mm, a quaternion, a set column; about 250 bytes a row) and read
by ``calib.read_measurements`` in fresh Python processes (``--repeats`` of them). The script
prints the medians of: the wall time and the CPU time of the read, the peak resident memory
(VmHWM) of the process, its growth over the process before the read (numpy, Pinocchio and the
robot loaded), both per row, and that growth per byte of the file: the figure the reader's
memory guard uses (:data:`calib.io.csv.layer.READ_BYTES_PER_FILE_BYTE`, printed beside it).
With ``--rtde`` each size is also read as a space-separated RTDE recording
(``--convention ur``, 40 columns of which 12 are read: about 420 bytes a row, so the memory per
row is the wide file's).

The machine is shared: the wall time grows with the load (printed), the CPU time much less.

Run: python scripts/bench_read.py [--repeats R] [--sizes N ...] [--rtde]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
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
def rss(field):
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1]) * 1024
import calib
robot = calib.load_robot(sys.argv[1])
before = rss("VmRSS:")
options = calib.ReadOptions(convention=sys.argv[3]) if len(sys.argv) > 3 else None
t, c = time.perf_counter(), time.process_time()
m = calib.read_measurements(sys.argv[2], robot, options=options)
wall, cpu = time.perf_counter() - t, time.process_time() - c
print(json.dumps({"wall": wall, "cpu": cpu, "before": before, "peak": rss("VmHWM:"), "n": m.n_poses}))
"""


def write_file(path: Path, n: int, rtde: bool = False) -> None:
    """n rows of the bundled robot (noisy measurements), written in blocks with numpy's
    formatting (write_measurements writes a million rows in about a minute)."""
    from scipy.spatial.transform import Rotation

    robot = calib.load_robot(URDF)
    rng = np.random.default_rng(n)
    with open(path, "w") as fh:
        if rtde:
            fh.write(" ".join(["timestamp"] + [f"{p}_{i}" for p in ("target_q", "actual_q", "actual_qd",
                                                                   "actual_TCP_pose", "actual_TCP_speed",
                                                                   "actual_current")
                                               for i in range(6)] + ["robot_mode", "safety_mode", "speed_scaling"])
                     + "\n")
        else:
            fh.write("# bench_read\n" + ",".join([f"joint{i}_deg" for i in range(1, 7)]
                                                + ["x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz", "set"]) + "\n")
        for start in range(0, n, 50_000):
            k = min(50_000, n - start)
            Q = robot.random_configurations(k, int(rng.integers(1 << 30)))
            m = calib.simulate_measurements(robot, Q, sigma_pos=2e-5, sigma_rot=2e-4, rng=rng)
            if rtde:
                z = np.zeros((k, 6))
                block = np.hstack([np.arange(start, start + k)[:, None] * 0.002, Q, Q, z, m.position,
                                   Rotation.from_matrix(m.rotation).as_rotvec(), z, z, np.ones((k, 3))])
                text = "\n".join(" ".join(f"{v:.17g}" for v in row) for row in block.tolist())
            else:
                wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
                block = np.hstack([np.degrees(Q), m.position * 1e3, wxyz])
                sets = np.where(rng.random(k) < 0.8, "cal", "val")
                text = "\n".join(",".join(f"{v:.17g}" for v in row) + "," + s
                                 for row, s in zip(block.tolist(), sets))
            fh.write(text + "\n")


def run(path: Path, repeats: int, convention: str | None = None) -> dict:
    out = []
    for _ in range(repeats):
        args = [sys.executable, "-c", CHILD, str(URDF), str(path)] + ([convention] if convention else [])
        proc = subprocess.run(args, capture_output=True, text=True, cwd=ROOT,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        if proc.returncode:
            raise SystemExit(proc.stderr)
        out.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return {k: statistics.median(r[k] for r in out) for k in out[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", type=int, nargs="+", default=[200_000, 1_000_000])
    ap.add_argument("--rtde", action="store_true")
    args = ap.parse_args()
    print(f"machine: {_bench.machine()}; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"median of {args.repeats} fresh processes each; reader's guard: "
          f"READ_BYTES_PER_FILE_BYTE = {READ_BYTES_PER_FILE_BYTE:g}")
    print(f"{'rows':>9} {'file':<6} {'MB':>6} {'wall s':>7} {'cpu s':>6} {'peak MB':>8} {'peak B/row':>10} "
          f"{'read B/row':>10} {'read B/file B':>13}")
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(n, "calib", None) for n in args.sizes]
        if args.rtde:
            cases += [(n, "rtde", "ur") for n in args.sizes]
        for n, kind, convention in cases:
            path = Path(tmp) / f"{kind}{n}.csv"
            write_file(path, n, rtde=kind == "rtde")
            size = path.stat().st_size
            r = run(path, args.repeats, convention)
            assert r["n"] == n
            grow = r["peak"] - r["before"]
            print(f"{n:>9} {kind:<6} {size / 1e6:>6.1f} {r['wall']:>7.2f} {r['cpu']:>6.2f} {r['peak'] / 1e6:>8.0f} "
                  f"{r['peak'] / n:>10.0f} {grow / n:>10.0f} {grow / size:>13.2f}")
            path.unlink()


if __name__ == "__main__":
    main()
