"""Snapshot of calib's estimates and CLI outputs, to check that a refactoring changes nothing.

    python scripts/snapshot.py DIR                  # write DIR/estimates.json and DIR/<command>.out
    python scripts/snapshot.py DIR --against REF    # ... and compare with the snapshot REF

Estimates: calibrate on the bundled example (defaults, c-lm, auto, huber) and on the real TIAGo
data (defaults, params='all'): values, covariance, std, predicted hold-out, status, notes, free
set. CLI: nine commands (calibrate with --report, TIAGo, identifiability, simulate, a bad file,
--help, calibrate --help, compensate, evaluate), stdout, stderr and exit code, timing lines
masked. The comparison prints the worst relative difference of the estimates (0 for a pure
refactoring) and the output files that differ. Run from the repository root.
"""
import argparse
import json
import os
import re
import subprocess
import sys

import numpy as np

import calib


def snapshot(out: str) -> None:
    os.makedirs(out, exist_ok=True)
    res = {}
    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    m = calib.read_measurements("examples/brtirus0707a/measurements.csv", robot)
    cases = {"bundled": (robot, m, {}), "bundled_clm": (robot, m, {"method": "c-lm"}),
             "bundled_auto": (robot, m, {"params": "auto"}), "bundled_huber": (robot, m, {"loss": "huber"})}
    t = calib.load_robot("tiago")
    mt = calib.read_measurements("examples/tiago_qualisys/measurements.csv", t)
    cases["tiago"] = (t, mt, {})
    cases["tiago_all"] = (t, mt, {"params": "all"})
    for k, (r, mm, kw) in cases.items():
        x = calib.calibrate(r, mm, **kw)
        res[k] = {"values": x.robot.values.tolist(), "cov": np.asarray(x.covariance).ravel().tolist(),
                  "std": [p.std for p in x.parameters], "status": x.status, "notes": list(x.notes),
                  "pred": x.predicted_holdout["position_rms"], "free": list(x.free)}
    json.dump(res, open(f"{out}/estimates.json", "w"))
    cmds = {
     "cal": "calib calibrate robots/brtirus0707a/brtirus0707a.urdf examples/brtirus0707a/measurements.csv -o {o}/c.urdf --report {o}/r.json",
     "tiago": "calib calibrate tiago examples/tiago_qualisys/measurements.csv -o {o}/t.urdf",
     "ident": "calib identifiability robots/brtirus0707a/brtirus0707a.urdf",
     "sim": "calib simulate robots/brtirus0707a/brtirus0707a.urdf -o {o}/s.csv --poses 30 --seed 3",
     "bad": "calib calibrate robots/brtirus0707a/brtirus0707a.urdf README.md -o {o}/x.urdf",
     "help": "calib --help",
     "calhelp": "calib calibrate --help",
     "comp": "calib compensate {o}/c.urdf robots/brtirus0707a/brtirus0707a.urdf examples/brtirus0707a/targets.csv -o {o}/comp.csv",
     "eval": "calib evaluate {o}/c.urdf examples/brtirus0707a/measurements.csv",
    }
    for k, c in cmds.items():
        p = subprocess.run(c.format(o=out), shell=True, capture_output=True, text=True)
        norm = lambda s: re.sub(r"\d+\.?\d* m?s\b|elapsed[^\n]*|wall[^\n]*", "T", s.replace(out, "OUT"))
        res[k] = p.returncode
        open(f"{out}/{k}.out", "w").write(f"rc={p.returncode}\n--stdout\n{norm(p.stdout)}\n--stderr\n{norm(p.stderr)}")
    json.dump(res, open(f"{out}/estimates.json", "w"))

def compare(new: str, ref: str) -> None:
    a = json.load(open(os.path.join(ref, "estimates.json"))); b = json.load(open(os.path.join(new, "estimates.json")))
    worst = 0
    for k in a:
        if isinstance(a[k], dict):
            for f in ("values", "cov", "std", "pred"):
                x, y = np.array(a[k][f], float), np.array(b[k][f], float)
                rel = np.nanmax(np.abs(x - y) / np.maximum(np.abs(x), 1e-300)) if x.size else 0
                worst = max(worst, rel if np.isfinite(rel) else 0)
                if not rel <= 1e-9: print("DIFF", k, f, rel)
            for f in ("status", "notes", "free"):
                if a[k][f] != b[k][f]: print("DIFF", k, f, a[k][f], b[k][f])
        elif a[k] != b[k]: print("RC DIFF", k, a[k], b[k])
    print("worst relative difference", worst)
    r = subprocess.run(f"diff -r {ref} {new} -x '*.json' -x '*.urdf' -x '*.csv' -q", shell=True, capture_output=True, text=True)
    print(r.stdout or "outputs identical")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir")
    ap.add_argument("--against", metavar="REF", help="a snapshot to compare with")
    args = ap.parse_args()
    snapshot(args.dir)
    if args.against:
        compare(args.dir, args.against)
    return 0


if __name__ == "__main__":
    sys.exit(main())
