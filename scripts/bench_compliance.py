"""Joint compliance under gravity on UR10 (example-robot-data) with a 10 kg payload.

For each seed: a true model with random geometric deviations (``--scale-mm``) and compliances of a
few 1e-6 rad/(N m) on joints 2-6 (joint 1 turns about the vertical and carries no gravity torque),
calibration and held-out rows with noise; then ``calib.calibrate`` without and with
``compliance=True``. Prints per seed and as medians:

* held-out RMS position (mm) / orientation (rad) error of each calibration, against the noise
  floor (sigma_pos sqrt(3): the RMS length of the 3-axis noise);
* for each compliance: identified - true, in units of its standard deviation (|z| < 3 expected);
* the wall time of each calibration (median over seeds).

    python scripts/bench_compliance.py [--seeds 3] [--poses 200] [--scale-mm 0.3]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402  (one BLAS thread)

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.model.compliance import Payload, with_gravity

TRUE_C = np.array([0.0, 3e-6, 4e-6, 5e-6, 5e-6, 5e-6])       # rad/(N m)
PAYLOAD = Payload(10.0, np.array([0.0, 0.05, 0.10]))          # kg; m in the tool frame


def run(seed: int, n_cal: int, n_val: int, scale: float, sigma_pos: float, sigma_rot: float) -> dict:
    robot = calib.load_robot("ur10")
    rng = np.random.default_rng(seed)
    true = with_gravity(robot, payload=PAYLOAD, values=TRUE_C)
    true = true.with_changes(**calib.random_deviations(robot, scale, rng))
    Q = robot.random_configurations(n_cal + n_val, rng)
    m = calib.simulate_measurements(true, Q, sigma_pos=sigma_pos, sigma_rot=sigma_rot, rng=rng,
                                    sets=np.array(["cal"] * n_cal + ["val"] * n_val))
    out = {}
    for label, kw in (("geometry", {}), ("compliance", {"compliance": True, "payload": PAYLOAD})):
        t = time.perf_counter()
        res = calib.calibrate(robot, m, params="base", cv=0, **kw)
        out[label] = {"time": time.perf_counter() - t, "status": res.status,
                      "pos": res.validation_after.position["rms"], "rot": res.validation_after.rotation["rms"]}
        if kw:
            out[label]["z"] = {n: (res.parameter(n).identified - true.value(n)) / res.parameter(n).std
                               for n in res.free if n.startswith("c")}
            out[label]["std"] = {n: res.parameter(n).std for n in res.free if n.startswith("c")}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--poses", type=int, default=200, help="calibration poses (plus half as many held out)")
    ap.add_argument("--scale-mm", type=float, default=0.3, help="geometric deviations, mm (rad / 500)")
    ap.add_argument("--sigma-pos-mm", type=float, default=0.02)
    ap.add_argument("--sigma-rot-rad", type=float, default=0.0002)
    a = ap.parse_args()
    sp, sr = a.sigma_pos_mm * 1e-3, a.sigma_rot_rad
    floor = sp * np.sqrt(3)
    print(f"UR10, payload {PAYLOAD.mass:g} kg at {PAYLOAD.com_tool * 1e3} mm (tool frame), compliances "
          f"{TRUE_C * 1e6} urad/(N m); {a.poses} calibration + {a.poses // 2} held-out poses; noise "
          f"{a.sigma_pos_mm} mm, {sr} rad per axis (floor {floor * 1e3:.4f} mm RMS); {_bench.machine()}")
    rows = []
    for seed in range(a.seeds):
        r = run(seed, a.poses, a.poses // 2, a.scale_mm * 1e-3, sp, sr)
        rows.append(r)
        g, c = r["geometry"], r["compliance"]
        z = ", ".join(f"{n} {v:+.2f}" for n, v in c["z"].items())
        print(f"seed {seed}: held-out position RMS geometry-only {g['pos'] * 1e3:.4f} mm "
              f"({g['pos'] / floor:.1f} x floor, {g['status']}), with compliance {c['pos'] * 1e3:.4f} mm "
              f"({c['pos'] / floor:.2f} x floor, {c['status']}); orientation {g['rot']:.3g} / {c['rot']:.3g} rad; "
              f"compliance error / std: {z}")
    med = lambda key, sub: statistics.median(r[key][sub] for r in rows)  # noqa: E731
    zmax = max(abs(v) for r in rows for v in r["compliance"]["z"].values())
    print(f"median held-out position RMS: geometry-only {med('geometry', 'pos') * 1e3:.4f} mm "
          f"({med('geometry', 'pos') / floor:.1f} x floor), with compliance {med('compliance', 'pos') * 1e3:.4f} mm "
          f"({med('compliance', 'pos') / floor:.2f} x floor); largest |error / std| of a compliance {zmax:.2f}")
    print(f"median wall time: geometry-only {med('geometry', 'time'):.2f} s, with compliance "
          f"{med('compliance', 'time'):.2f} s")


if __name__ == "__main__":
    main()
