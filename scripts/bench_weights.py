"""Position/orientation weights (issue 39, item 2): what the default weighting costs in position
against a fixed 1 mm : 0.01 rad weighting (FIGAROH's), on camera-like data whose orientation
noise is correlated or biased, and on honest data.

A Panda (7 axes) with a random truth (0.3 mm / 0.6 mrad deviations of every parameter) measured
by a camera at 114 random configurations (the real Franka camera set's size), full poses,
calibrated by calibrate's defaults and at the fixed weights (``sigma_pos=1e-3, sigma_rot=1e-2``,
least squares on the identifiable set: the same model, only the weighting differs). Scored
against the truth at 300 other configurations (position and rotation RMS of the calibrated
model's tool pose: the accuracy a user gets) and against 300 measured rows with the same noise
(held-out error, as the real-data benchmark scores).

Orientation noise laws (position noise 0.5 mm per axis, white, unless said):

* ``white``: 3 mrad per axis, independent (the control: the variance components are the best
  weights there, and the rule must keep them);
* ``tilt``: 2 mrad white plus a bias that depends on the marker's tilt to the camera's line of
  sight (4 mrad at 90 degrees);
* ``correlated``: 3 mrad white, and each row's position error correlated with it through a
  150 mm lever (a marker's pose estimated about a point off its centre), plus 0.3 mm white;
* ``field``: 1 mrad white plus an orientation bias over the image (a lens's distortion: 5 mrad
  at 0.5 m from the image centre), which the model can partly absorb into its parameters;
* ``field strong``: 2 mrad white, the field's bias 10 mrad at 0.5 m;
* ``angle scale``: 1 mrad white, the rotation angles read 1 % too large.

Methods: calibrate's defaults (the orientation's weight chosen by cross-validated position error,
:mod:`calib.calibration.estimators.weights`), the variance components' weights alone (the
defaults before issue 39: the rule's candidates limited to them), and the fixed weights.

Prints per law the means over the seeds of the RMS errors against the truth and held out, the
ratio of the defaults to the fixed weights, and how often the rule moved the weight.

Run: PYTHONPATH=. python scripts/bench_weights.py [--seeds 10]
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread before numpy loads)

import argparse
import math
import sys
import warnings
from dataclasses import replace

import numpy as np

LAWS = ("white", "tilt", "correlated", "field", "field strong", "angle scale")
ROWS = 114
VAL_ROWS = 300
SIGMA_POS = 0.5e-3


def orientation_noise(law: str, R: np.ndarray, P: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """(rotation vectors (N, 3) rad, position errors (N, 3) m) of the law named at measured tool
    poses (rotations R (N, 3, 3), positions P (N, 3) m) in the camera (meas) frame, whose line of
    sight is its z axis."""
    n = len(R)
    z_tool = R[:, :, 2]
    white_p = rng.normal(0.0, SIGMA_POS, (n, 3))
    if law == "white":
        return rng.normal(0.0, 3e-3, (n, 3)), white_p
    if law == "tilt":       # (zero when the marker faces the camera)
        return 4e-3 * np.cross(np.array([0.0, 0.0, 1.0]), z_tool) + rng.normal(0.0, 2e-3, (n, 3)), white_p
    if law == "correlated":
        w = rng.normal(0.0, 3e-3, (n, 3))
        return w, np.cross(w, R @ np.array([0.0, 0.0, 0.15])) + rng.normal(0.0, 0.3e-3, (n, 3))
    if law in ("field", "field strong"):
        amplitude, white = (5e-3, 1e-3) if law == "field" else (10e-3, 2e-3)
        c = P - P.mean(axis=0)          # (the image centre: the middle of the poses)
        bias = amplitude * np.stack([c[:, 1], -c[:, 0], 0.5 * c[:, 0]], axis=1) / 0.5
        return bias + rng.normal(0.0, white, (n, 3)), white_p
    if law == "angle scale":
        from scipy.spatial.transform import Rotation

        return 0.01 * Rotation.from_matrix(R).as_rotvec() + rng.normal(0.0, 1e-3, (n, 3)), white_p
    raise ValueError(f"unknown law {law!r}")


def measure(true, Q, law: str, rng):
    """Measurements of ``true`` at Q with the law's noise."""
    import calib
    from calib.model.spatial import rotation_from_rotvec

    m = calib.simulate_measurements(true, Q, sigma_pos=0.0, sigma_rot=0.0, rng=rng)
    dtheta, dp = orientation_noise(law, m.rotation, m.position, rng)
    return replace(m, position=m.position + dp, rotation=rotation_from_rotvec(dtheta) @ m.rotation)


def run(law: str, seed: int, robot, rows: int = ROWS):
    """{method: (pos vs truth m, rot vs truth rad, pos held out m, rot held out rad, moved)}."""
    import calib
    import calib.calibration.estimators.weights as weights

    rng = np.random.default_rng(seed)
    true = calib.apply_deviations(robot, calib.random_deviations(robot, 0.3e-3, rng))
    cal = measure(true, robot.random_configurations(rows, rng), law, rng)
    Qv = robot.random_configurations(VAL_ROWS, rng)
    truth = calib.simulate_measurements(true, Qv, sigma_pos=0.0, sigma_rot=0.0)
    val = measure(true, Qv, law, rng)
    out = {}
    rule = (weights.WEIGHT_FACTORS, weights.REFERENCE_RAD_PER_M)
    for method, kwargs in METHODS:
        if method == "variance components":     # (the rule's candidates: these weights alone)
            weights.WEIGHT_FACTORS, weights.REFERENCE_RAD_PER_M = (1.0,), 0.0
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = calib.calibrate(robot, cal, cv=0, **kwargs)
        finally:
            weights.WEIGHT_FACTORS, weights.REFERENCE_RAD_PER_M = rule
        a, h = calib.evaluate(res.robot, truth), calib.evaluate(res.robot, val)
        moved = any(n.startswith("orientation weighted as") for n in res.notes)
        out[method] = (a.position["rms"], a.rotation["rms"], h.position["rms"], h.rotation["rms"], moved)
    return out


METHODS = (("defaults", {}), ("variance components", {}),
           ("fixed 1 mm : 0.01 rad", {"params": "base", "sigma_pos": 1e-3, "sigma_rot": 1e-2}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--laws", default=",".join(LAWS))
    ap.add_argument("--rows", type=int, default=ROWS, help="calibration poses (40: the defaults run EB-MAP)")
    a = ap.parse_args(argv)
    import calib
    import example_robot_data as erd

    robot = calib.load_robot(erd.load("panda").urdf)
    print(f"machine: {_bench.machine()}")
    print(f"Panda, {a.rows} camera poses, {a.seeds} seeds; means of the RMS errors against the truth (model) and "
          f"of measured held-out rows (held out); mm and mrad")
    print(f"{'law':<16}{'method':<24}{'pos model':>10}{'rot model':>10}{'pos held':>10}{'rot held':>10}")
    for law in a.laws.split(","):
        runs = [run(law, 1000 + s, robot, a.rows) for s in range(a.seeds)]
        means = {k: np.mean([r[k][:4] for r in runs], axis=0) * 1e3 for k in runs[0]}
        for method, v in means.items():
            print(f"{law:<16}{method:<24}{v[0]:>10.4f}{v[1]:>10.4f}{v[2]:>10.4f}{v[3]:>10.4f}")
        d, f = means["defaults"], means["fixed 1 mm : 0.01 rad"]
        moved = sum(r["defaults"][4] for r in runs)
        print(f"{law:<16}{'defaults / fixed':<24}{d[0] / f[0]:>10.3f}{d[1] / f[1]:>10.3f}{d[2] / f[2]:>10.3f}"
              f"{d[3] / f[3]:>10.3f}   (weight moved in {moved} of {len(runs)})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
