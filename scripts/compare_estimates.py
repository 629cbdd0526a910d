"""How far this checkout's ``calibrate()`` estimates lie from another checkout's: the check of a
speed change that may move results by rounding (issue 27 item 7).

``--save FILE`` writes the estimates (values, standard deviations, estimator, free set, predicted
held-out RMS, iterations) of ``calibrate()`` with its defaults on the bundled robot (the paper's
deviations, simulated as scripts/bench_speed.py makes them) for N poses in --poses and seeds
1..--seeds, and on the bundled example (examples/brtirus0707a); ``--against FILE`` computes them
here and prints, per case, the largest deviation: relative for least squares (|dx| / max(|x|,
1e-4): the baseline test's rtol 1e-9 with its atol 1e-13), in standard deviations for EB-MAP
(whose evidence optimum amplifies rounding), and the worst of each kind.

Run: python scripts/compare_estimates.py --save /tmp/before.pkl   (in the other checkout)
     python scripts/compare_estimates.py --against /tmp/before.pkl
"""
from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def estimates(sizes, seeds: int) -> dict:
    import calib
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    runs = {(n, s): simulate_measurements(true, robot.random_configurations(n, s), rng=s + 1)
            for n in sizes for s in range(1, seeds + 1)}
    runs["example"] = calib.read_measurements(ROOT / "examples" / "brtirus0707a" / "measurements.csv", robot)
    out = {}
    for key, meas in runs.items():
        r = calib.calibrate(robot, meas)
        out[key] = {"x": np.array(r.robot.values), "std": np.sqrt(np.clip(np.diag(r.covariance), 0, None)),
                    "idx": robot.indices(r.free), "kind": r.estimator["kind"], "free": tuple(r.free),
                    "pred": r.predicted_holdout["position_rms"], "iterations": r.iterations}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", type=Path)
    ap.add_argument("--against", type=Path)
    ap.add_argument("--poses", type=int, nargs="+", default=[100, 40, 25, 12])
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args(argv)
    if (args.save is None) == (args.against is None):
        ap.error("give one of --save FILE, --against FILE")
    now = estimates(args.poses, args.seeds)
    if args.save:
        args.save.write_bytes(pickle.dumps(now))
        print(f"{len(now)} cases written to {args.save}")
        return 0
    ref = pickle.loads(args.against.read_bytes())
    worst = {"least-squares": 0.0, "eb-map": 0.0}
    for key, a in ref.items():
        b = now[key]
        if a["free"] != b["free"] or a["kind"] != b["kind"]:
            print(f"{key}: free set or estimator changed ({a['kind']} -> {b['kind']})")
            continue
        dx = np.abs(a["x"] - b["x"])[a["idx"]]
        if a["kind"] == "eb-map":
            dev, unit = float(np.max(dx / a["std"])), "std"
        else:
            dev, unit = float(np.max(dx / np.maximum(np.abs(a["x"][a["idx"]]), 1e-4))), "relative"
        worst[a["kind"]] = max(worst.get(a["kind"], 0.0), dev)
        print(f"{key}: {a['kind']}, largest deviation {dev:.2e} {unit}, predicted held-out RMS "
              f"{abs(a['pred'] - b['pred']) / a['pred']:.1e} relative, iterations {a['iterations']} -> {b['iterations']}")
    print(f"worst: least squares {worst['least-squares']:.2e} relative, EB-MAP {worst['eb-map']:.2e} std")
    return 0


if __name__ == "__main__":
    sys.exit(main())
