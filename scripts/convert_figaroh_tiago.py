"""Convert FIGAROH's real TIAGo motion-capture calibration data to calib's measurement format.

Source: ``tests/fixtures/tiago/data/qualysis_base_hand_calibration.csv`` of the FIGAROH 1.0.2
source distribution (``pip download figaroh==1.0.2 --no-binary :all: --no-deps``; Apache
License 2.0, copyright Thanh D. V. Nguyen). 35 configurations of a PAL TIAGo's torso lift and
7 arm joints, each with the positions of markers on the hand measured by a Qualisys system,
in metres, in the frame of a marker plate on the robot's base; columns ``x1, y1, z1, ...,
x4, y4, z4`` then the joints (radians, the torso lift in metres), no units in the names.

What the conversion does, and nothing else:
- one row per configuration and marker (calib's format for several targets: a ``target``
  column, M1 .. M3), the joint values repeated;
- marker 4 is left out: it repeats marker 3 in every row (checked below);
- unit suffixes added to the names (``torso_lift_joint_m``, ``arm_1_joint_rad``, ``x_m`` ...);
  the numbers are copied as written (``repr`` of the parsed float: the same value).

Run: python scripts/convert_figaroh_tiago.py SOURCE.csv OUT.csv
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

JOINTS = ["torso_lift_joint"] + [f"arm_{k}_joint" for k in range(1, 8)]
MARKERS = (1, 2, 3)


def convert(source: Path, out: Path) -> int:
    """Write ``out`` from ``source``; returns the number of configurations."""
    with open(source, newline="") as f:
        rows = list(csv.DictReader(f))
    for i, r in enumerate(rows, start=2):
        if any(r[f"{c}3"] != r[f"{c}4"] for c in "xyz"):
            raise SystemExit(f"{source}, row {i}: marker 4 differs from marker 3; this script drops it")
    header = [f"{JOINTS[0]}_m"] + [f"{j}_rad" for j in JOINTS[1:]] + ["x_m", "y_m", "z_m", "target"]
    with open(out, "w", newline="") as f:
        f.write(f"# Real TIAGo measurements converted by scripts/convert_figaroh_tiago.py from {source.name}\n")
        f.write("# of FIGAROH 1.0.2 (Apache License 2.0, copyright Thanh D. V. Nguyen; see LICENSE beside this file)\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for r in rows:
            q = [repr(float(r[j])) for j in JOINTS]
            for m in MARKERS:
                w.writerow(q + [repr(float(r[f"{c}{m}"])) for c in "xyz"] + [f"M{m}"])
    return len(rows)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__.strip().splitlines()[-1])
    n = convert(Path(sys.argv[1]), Path(sys.argv[2]))
    print(f"{n} configurations, {n * len(MARKERS)} rows -> {sys.argv[2]}")
