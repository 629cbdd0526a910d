"""Held-out error against its prediction, and the parameter set chosen, under realistic conditions.

For each scenario and seed: simulate calibration rows and 1000 held-out rows of a perturbed
robot (noise, optionally an unmodelled joint-angle-dependent error and a measurement frame metres
from the base), run ``calib.calibrate`` with its defaults (noise estimated from the data, the
parameter set by its default rule) and print, as medians over the seeds:

* ``holdout``: RMS position (mm) / orientation (rad) error of the calibrated model on the held-out
  rows (measured values, noise included): what a user sees;
* ``pred/holdout``: the printed ``predicted_holdout_rms`` over that (1 is a perfect prediction);
* ``cv/holdout``: the cross-validated error over it;
* ``sigma est/true``: the estimated noise over the simulated one (position);
* the set chosen, and for the small scenarios the held-out error of "offsets+frames" and of the
  identifiable set fitted on their own ("hindsight"), against the default's.

    python scripts/bench_holdout.py [--seeds 5] [--scenario NAME ...]
"""
from __future__ import annotations

import argparse
import statistics
import sys
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402,F401  (one BLAS thread)

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.calibration.parameters import candidate_sets, identifiable_set
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, random_deviations, simulate_measurements
from calib.model.spatial import zyx_transform

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Scenario:
    name: str
    robot: str                    # "bundled" or an example-robot-data name
    frames: tuple | None          # (base, tool) or None for the defaults
    rows: int
    sigma_pos: float              # m
    sigma_rot: float              # rad
    position_only: bool = False
    unmodelled: float = 0.0       # rad amplitude
    deviation_mm: float = 0.0     # random deviations scale (0: the paper's Tables 4-5)
    far_frame: bool = False       # the measurement frame ~2.5 m from the base, turned
    tool_offset_mm: float = 0.0   # a marker this far off the flange
    give_sigma: bool = False      # pass the true noise to calibrate
    offsets_only: bool = False    # deviations mostly in joint offsets and frames (others x0.05)


SCENARIOS = [
    Scenario("paper, noise given", "bundled", None, 100, 0.02e-3, 0.002, give_sigma=True),
    Scenario("paper, noise estimated", "bundled", None, 100, 0.02e-3, 0.002),
    Scenario("unmodelled error, 60 rows", "bundled", None, 60, 0.05e-3, 0.0005, unmodelled=3e-4),
    Scenario("camera: ur5, 23 rows, mm noise", "ur5", None, 23, 1.0e-3, 0.005, unmodelled=3e-4,
             deviation_mm=1.0, far_frame=True, tool_offset_mm=60.0),
    Scenario("camera: ur5, 23 rows, offset errors", "ur5", None, 23, 1.0e-3, 0.005, unmodelled=3e-4,
             deviation_mm=1.0, far_frame=True, tool_offset_mm=60.0, offsets_only=True),
    Scenario("mocap: tiago 7+1 axes, 34 rows, position", "tiago", ("base_footprint", "arm_7_link"), 34,
             1.0e-3, 0.0, position_only=True, unmodelled=3e-4, deviation_mm=1.0, far_frame=True,
             tool_offset_mm=80.0),
]


def _load(s: Scenario) -> calib.RobotModel:
    if s.robot == "bundled":
        return calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    import example_robot_data as erd

    base, tool = s.frames or (None, None)
    return calib.load_robot(erd.load(s.robot).urdf, base_frame=base, tool_frame=tool)


def run(s: Scenario, seed: int, hindsight: bool) -> dict:
    robot = _load(s)
    rng = np.random.default_rng(seed)
    dev = PAPER_DEVIATIONS if s.deviation_mm == 0 else random_deviations(robot, s.deviation_mm * 1e-3, rng)
    if s.offsets_only:
        dev = {k: v if (k.startswith(("theta", "u_", "v_"))) else 0.05 * v for k, v in dev.items()}
    true = apply_deviations(robot, dev)
    if s.far_frame:
        true = replace(true, T_meas_base_ref=zyx_transform(2.0, -1.2, 0.4, 0.7, 0.05, -0.03) @ true.T_meas_base_ref)
    if s.tool_offset_mm:
        off = rng.normal(size=3)
        off *= s.tool_offset_mm * 1e-3 / np.linalg.norm(off)
        true = replace(true, T_flange_tool_ref=true.T_flange_tool_ref @ zyx_transform(*off, 0, 0, 0))
    n_val = 1000
    Q = robot.random_configurations(s.rows + n_val, rng)
    sets = np.array(["cal"] * s.rows + ["val"] * n_val)
    meas = simulate_measurements(true, Q, sigma_pos=s.sigma_pos, sigma_rot=s.sigma_rot,
                                 position_only=s.position_only, rng=rng, sets=sets, unmodelled=s.unmodelled)
    kw = dict(sigma_pos=s.sigma_pos, sigma_rot=s.sigma_rot) if s.give_sigma else {}
    res = calib.calibrate(robot, meas, **kw)
    va, ph = res.validation_after, res.predicted_holdout
    out = {"pos": va.position["rms"], "rot": None if va.rotation is None else va.rotation["rms"],
           "pred_pos": ph["position_rms"], "pred_rot": ph["rotation_rms"], "set": res.param_set,
           "sigma_ratio": res.noise.position / s.sigma_pos, "status": res.status}
    # cross-validated error of the same data (validation rows dropped)
    cal_only = meas.calibration()
    res_cv = calib.calibrate(robot, cal_only, **kw)
    out["cv_pos"] = res_cv.cross_validation.position_rms if res_cv.cross_validation else float("nan")
    if hindsight:
        start = robot
        ident = identifiable_set(start, cal_only.q, "position" if s.position_only else "pose")
        small = candidate_sets(robot, ident, cal_only.q, "position" if s.position_only else "pose")[0][1]
        for key, params in (("offsets_pos", list(small)), ("full_pos", "base")):
            r = calib.calibrate(robot, meas, params=params, **kw)
            out[key] = r.validation_after.position["rms"]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--scenario", nargs="*", default=None, help="substrings of scenario names")
    args = ap.parse_args(argv)
    print(f"# bench_holdout: {_bench.machine()}; medians over {args.seeds} seeds; 1000 held-out rows each")
    print(f"{'scenario':<42}{'holdout mm':>11}{'pred/hold':>10}{'cv/hold':>9}{'rot hold':>10}"
          f"{'pred/hold':>10}{'sig est/true':>13}  chosen set (hindsight: offsets / full / default, mm)")
    for s in SCENARIOS:
        if args.scenario and not any(k in s.name for k in args.scenario):
            continue
        hindsight = s.rows < 50
        runs = [run(s, seed, hindsight) for seed in range(args.seeds)]
        med = lambda k: statistics.median(r[k] for r in runs)  # noqa: E731
        pr = [r["pred_pos"] / r["pos"] for r in runs]
        cv = [r["cv_pos"] / r["pos"] for r in runs]
        rot = "" if runs[0]["rot"] is None else f"{med('rot'):>10.4f}{statistics.median(r['pred_rot'] / r['rot'] for r in runs):>10.2f}"
        sets = {}
        for r in runs:
            sets[r["set"]] = sets.get(r["set"], 0) + 1
        line = (f"{s.name:<42}{med('pos') * 1e3:>11.4f}{statistics.median(pr):>10.2f}{statistics.median(cv):>9.2f}"
                f"{rot or '-':>20}{med('sigma_ratio'):>13.2f}  "
                + ", ".join(f"{k} x{v}" for k, v in sets.items()))
        if hindsight:
            best = sum(min(r["offsets_pos"], r["full_pos"]) for r in runs) / len(runs)
            line += (f" ({np.mean([r['offsets_pos'] for r in runs]) * 1e3:.3f} / "
                     f"{np.mean([r['full_pos'] for r in runs]) * 1e3:.3f} / {np.mean([r['pos'] for r in runs]) * 1e3:.3f};"
                     f" better-of-two in hindsight {best * 1e3:.3f})")
        print(line, flush=True)
        print(f"{'':<42}pred/hold range {min(pr):.2f}-{max(pr):.2f}; statuses "
              f"{sorted({r['status'] for r in runs})}", flush=True)


if __name__ == "__main__":
    main()
