"""Write examples/tracker/: a laser tracker measuring three reflectors on the bundled robot's tool.

    python scripts/make_tracker_example.py

1. ``calib simulate`` writes ``smr.csv`` (calib's own format: one row per reflector measured,
   joint values repeated, a ``target`` column) and ``true.urdf``: the bundled BRTIRUS0707A with
   random deviations (0.3 mm, 0.6 mrad), 40 calibration and 10 validation poses, reflectors at
   100,0,50 / -50,80,50 / 0,-70,100 mm in the tool frame, positions only (noise 0.02 mm per
   axis), in the frame of a tracker standing 2.9 m from the robot.
2. The same rows as a controller and a tracker would write them: ``joints.csv``, the
   controller's log (one row per pose: a point name, joints A1..A6 in degrees to 6 decimals, the
   ``set`` a user adds), and ``tracker.csv``, the tracker's export (a preamble, semicolons,
   decimal commas, ``X [mm]``, one row per reflector named ``P001_SMR1``, mm to 3 decimals).

``calib calibrate ROBOT joints.csv --tracker tracker.csv --key Point --target-from
'(?P<key>P\\d+)_(?P<target>SMR\\d+)'`` joins them back into the rows of ``smr.csv`` (to the
rounding of the two exports).
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "examples" / "tracker"
URDF = "robots/brtirus0707a/brtirus0707a.urdf"
SIMULATE = ["simulate", URDF, "-o", "examples/tracker/smr.csv", "--deviations", "random:0.3",
            "--position-only", "--poses", "40", "--val-poses", "10", "--target", "SMR1=100,0,50",
            "--target", "SMR2=-50,80,50", "--target", "SMR3=0,-70,100",
            "--meas-frame", "2400,-1500,800,-17,11,40", "--seed", "3",
            "--truth-urdf", "examples/tracker/true.urdf"]


def _comma(x: float) -> str:
    return f"{x:.3f}".replace(".", ",")


def split(smr: Path, joints: Path, tracker: Path) -> int:
    """Write the controller's log and the tracker's export of the rows of ``smr``; returns the
    number of poses."""
    with open(smr, newline="") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    names = [f"joint{k}_deg" for k in range(1, 7)]
    poses: dict[tuple, str] = {}
    with open(joints, "w", newline="") as fj, open(tracker, "w", newline="") as ft:
        ft.write("Project: calib example;Instrument: laser tracker, 3 SMR on the tool\n")
        ft.write("Point;X [mm];Y [mm];Z [mm]\n")
        w = csv.writer(fj, lineterminator="\n")
        w.writerow(["Point"] + [f"A{k}_deg" for k in range(1, 7)] + ["set"])
        for r in rows:
            q = tuple(f"{float(r[n]):.6f}" for n in names)
            if q not in poses:
                poses[q] = f"P{len(poses) + 1:03d}"
                w.writerow([poses[q], *q, r["set"]])
            ft.write(";".join([f"{poses[q]}_{r['target']}"] + [_comma(float(r[c])) for c in ("x_mm", "y_mm", "z_mm")])
                     + "\n")
    return len(poses)


def main() -> int:
    sys.path.insert(0, str(ROOT))
    from calib.cli.main import main as calib_main

    import os

    OUT.mkdir(exist_ok=True)
    os.chdir(ROOT)      # the simulate command names its paths from the repository root
    code = calib_main(SIMULATE)
    if code:
        return code
    n = split(OUT / "smr.csv", OUT / "joints.csv", OUT / "tracker.csv")
    print(f"{n} poses -> examples/tracker/joints.csv, examples/tracker/tracker.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
