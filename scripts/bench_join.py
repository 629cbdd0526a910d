"""Benchmark of the joins of a joint file and a tracker file (issue 25, item 3).

Prints, for a 100 Hz joint log of the robot stopping 2 s at each pose and moving 1 s between
them (10,000 and 60,000 rows: about 3 and 17 minutes) and a tracker measuring 3 reflectors at
each stop, the median time of the join by nearest time alone (the two files already read:
:func:`calib.io.csv.join.join_tables`) and of the whole ``read_measurements``; and the same for a
tracker export with compound point names (P00001_SMR1 ...) joined to one joint row per pose by
key with ``target_from``.

Run: python scripts/bench_join.py
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import _bench
import numpy as np

import calib
from calib.io.csv.layer import read_table
from calib.io.csv.join import join_tables, sides
from calib.io.csv.specs import JOINT_SIDE, TRACKER_SIDE

ROOT = Path(__file__).resolve().parents[1]
REGEX = r"(?P<key>P\d+)_(?P<target>SMR\d+)"


def _files(folder: Path, robot, n_log: int):
    n = n_log // 300                                   # one stop per 3 s at 100 Hz
    Q = np.degrees(robot.random_configurations(n, 0))
    t = np.arange(n_log) / 100
    stop = np.minimum(t // 3, n - 1).astype(int)
    q = Q[stop]                                        # moving rows: the stop's values (timing only)
    (folder / "log.csv").write_text(
        "time_s," + ",".join(f"A{i}_deg" for i in range(1, 7)) + "\n"
        + "".join(f"{t[k]:.2f}," + ",".join(f"{v:.6f}" for v in q[k]) + "\n" for k in range(n_log)))
    times = np.round(3.0 * np.repeat(np.arange(n), 3) + 0.7 + np.tile([0.0, 0.4, 0.8], n), 3) + 0.0013
    smr = np.tile(["SMR1", "SMR2", "SMR3"], n)
    (folder / "timed.csv").write_text(
        "time_s;Reflector;X [mm];Y [mm];Z [mm]\n"
        + "".join(f"{times[k]:.4f};{smr[k]};441,0;0,0;-36,5\n" for k in range(3 * n)))
    (folder / "joints.csv").write_text(
        "Point," + ",".join(f"A{i}_deg" for i in range(1, 7)) + "\n"
        + "".join(f"P{k:05d}," + ",".join(f"{v:.6f}" for v in Q[k]) + "\n" for k in range(n)))
    (folder / "export.csv").write_text(
        "Point;X [mm];Y [mm];Z [mm]\n"
        + "".join(f"P{k // 3:05d}_{smr[k]};441,0;0,0;-36,5\n" for k in range(3 * n)))
    return n


def main() -> None:
    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    print(f"machine: {_bench.machine()}")
    print(f"{'joint rows':>10} {'measured':>9} {'join':<22} {'join alone':>11} {'read_measurements':>18}")
    for n_log in (10_000, 60_000):
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            n = _files(d, robot, n_log)
            cases = (("nearest time", d / "log.csv", d / "timed.csv", n_log,
                      calib.ReadOptions(join="nearest-time", time="time_s", max_gap=0.01,
                                        target_column="Reflector")),
                     ("key, --target-from", d / "joints.csv", d / "export.csv", n,
                      calib.ReadOptions(key="Point", target_from=REGEX)))
            for label, joints, tracker, rows, options in cases:
                js, ts = sides(JOINT_SIDE, TRACKER_SIDE, options)
                j, t = read_table(joints, js, robot, options), read_table(tracker, ts, robot, options)
                joined = join_tables(j, t, options)
                assert len(joined.joint) == 3 * n
                alone = _bench.median_time(lambda: join_tables(j, t, options), repeats=5)
                whole = _bench.median_time(lambda: calib.read_measurements(joints, robot, tracker=tracker,
                                                                           options=options), repeats=3)
                print(f"{rows:>10} {3 * n:>9} {label:<22} {alone * 1e3:>8.1f} ms {whole * 1e3:>15.1f} ms")


if __name__ == "__main__":
    main()
