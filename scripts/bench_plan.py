"""Benchmark and acceptance figures of ``calib plan`` (issue 40).

For a UR10 (example-robot-data, tool0), a Panda (example-robot-data) and the KUKA KR16-2 (the
ROS-Industrial description with its collision meshes, read in place from /work/shared/vendor;
left out when absent), each with a tracker and a box in its cell (tests/plan_check.py's
ACCEPTANCE_CELLS): a 50-pose plan from 10,000 candidates, its time, then an independent check
(Pinocchio's own loader, pairs by its own rule, no margin, the moves at 0.25 degree steps, the
floor on the shapes' vertices, the beams by coal): collisions at the poses and along the moves,
the lowest point, range, cone and line of sight at every pose; the predicted accuracy over the
cell and over the joint limits beside the unconstrained selection's; the travel beside a random
order's; the programs (URScript, KRL, RAPID, FANUC) read back by calib's readers. Then the touch
plans on the UR10: the TCP case (one nest, 8 rows in a 30 degree cone) and three faces of a cube,
each calibrated in 10 simulated runs, the RMS error against the prediction.

    python scripts/bench_plan.py [--robots ur10 panda kr16] [--no-touch]
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import pytest  # noqa: E402

from plan_check import CUBE_CELL, NEST_CELL, acceptance_figures, touch_acceptance  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", nargs="+", default=["ur10", "panda", "kr16"])
    ap.add_argument("--no-touch", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in args.robots:
            try:
                f = acceptance_figures(name, folder)
            except pytest.skip.Exception as exc:
                print(f"{name}: skipped ({exc})")
                continue
            print(f"{name}: {f['poses']} poses of {f['candidates']} candidates ({f['feasible']} feasible) in "
                  f"{f['elapsed_s']:.1f} s  [{', '.join(f'{k} {v:.1f}' for k, v in f['timings'].items())}]")
            print(f"  independent check: {f['pose_collisions']} collisions at the poses, "
                  f"{len(f['move_problems'])} along the moves at 0.25 deg steps, lowest point "
                  f"{f['lowest_mm']:.1f} mm above the floor; range {'held' if f['range_ok'] else 'BROKEN'}, cone "
                  f"{f['cone_max_deg']:.1f} of {f['cone_deg']:.0f} deg at most, line of sight blocked at "
                  f"{f['sight_blocked']} poses")
            print(f"  predicted error over the cell {f['error_cell_mm']:.4f} mm, unconstrained "
                  f"{f['error_cell_free_mm']:.4f} mm ({100 * (f['error_cell_mm'] / f['error_cell_free_mm'] - 1):+.1f} %);"
                  f" over the joint limits {f['error_limits_mm']:.4f} mm, unconstrained "
                  f"{f['error_limits_free_mm']:.4f} mm "
                  f"({100 * (f['error_limits_mm'] / f['error_limits_free_mm'] - 1):+.1f} %)")
            print(f"  travel {f['travel_s']:.1f} s, a random order {f['random_travel_s']:.1f} s "
                  f"({f['travel_s'] / f['random_travel_s']:.2f}); {f['waypoints']} waypoints")
            if f["programs_max_rad"]:
                print("  programs read back: " + ", ".join(f"{k} {v:.1e} rad" for k, v in f["programs_max_rad"].items()))
        if not args.no_touch:
            for text, name in ((NEST_CELL, "nest"), (CUBE_CELL, "cube")):
                t = touch_acceptance(folder, text, name)
                print(f"touch {name}: {t['rows']} rows, params {t['params']} ({t['free']} robot parameters) in "
                      f"{t['elapsed_s']:.1f} s; predicted {t['predicted_mm']:.4f} mm ({t['what']}); 10 simulated "
                      f"calibrations: RMS {t['ratio'] * t['predicted_mm']:.4f} mm (ratio {t['ratio']:.2f}), each "
                      + " ".join(f"{e:.4f}" for e in t["errors_mm"]) + f"; {len(t['move_problems'])} move problems")


if __name__ == "__main__":
    main()
