"""Benchmark of the CSV layer (issue 11): reading measurement files of 300 and 10,000 poses.

Prints the median read time over repeated runs for: the calib style (commas, quaternion), a
European export (semicolons, decimal commas, controller joint names, ignored columns, rotation
vectors) and two files joined by a key (rows in reverse order). No target: for scale only.

Run: python scripts/bench_read.py
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import _bench
import numpy as np
from scipy.spatial.transform import Rotation

import calib

ROOT = Path(__file__).resolve().parents[1]


def _write(folder: Path, meas, n: int) -> dict:
    calib.write_measurements(folder / "calib.csv", meas)
    q = np.degrees(meas.q)
    p = meas.position * 1e3
    rv = Rotation.from_matrix(meas.rotation).as_rotvec(degrees=True)
    head = ";".join(["point"] + [f"A{i}_deg" for i in range(1, 7)]
                    + ["X (mm)", "Y (mm)", "Z (mm)", "rvx_deg", "rvy_deg", "rvz_deg", "temp"])
    lines = [head] + [";".join([f"P{k}"] + [repr(float(v)).replace(".", ",") for v in
                                           (*q[k], *p[k], *rv[k], 21.5)]) for k in range(n)]
    (folder / "euro.csv").write_text("\n".join(lines) + "\n")
    (folder / "joints.csv").write_text(
        "point," + ",".join(f"J{i}_deg" for i in range(1, 7)) + "\n"
        + "".join(f"P{k}," + ",".join(repr(float(v)) for v in q[k]) + "\n" for k in range(n)))
    (folder / "tracker.csv").write_text(
        "point,x_mm,y_mm,z_mm,rvx_deg,rvy_deg,rvz_deg\n"
        + "".join(f"P{k}," + ",".join(repr(float(v)) for v in (*p[k], *rv[k])) + "\n"
                  for k in reversed(range(n))))
    return {"calib style": (folder / "calib.csv", None, None),
            "; , A1_deg rotvec": (folder / "euro.csv", None, None),
            "joined by key": (folder / "joints.csv", folder / "tracker.csv",
                              calib.ReadOptions(key="point"))}


def main() -> None:
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    print(f"machine: {_bench.machine()}")
    print(f"{'poses':>7} {'file':<20} {'read (median)':>14}")
    for n in (300, 10_000):
        Q = robot.random_configurations(n, 0)
        meas = calib.simulate_measurements(robot, Q, sigma_pos=0.0, sigma_rot=0.0)
        with tempfile.TemporaryDirectory() as tmp:
            for label, (path, tracker, options) in _write(Path(tmp), meas, n).items():
                t = _bench.median_time(lambda: calib.read_measurements(path, robot, tracker=tracker,
                                                                       options=options),
                                       repeats=5)
                print(f"{n:>7} {label:<20} {t * 1e3:>11.1f} ms")


if __name__ == "__main__":
    main()
