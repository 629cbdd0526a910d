"""Issue 38 item 1's reliability cases of touch data, through the one calibrate (UR10 of
example-robot-data, 0.5 mm / 1 mrad errors, 0.02 mm touch noise):

* mixed: 2 points x 10 touch rows and 15 measured positions (0.05 mm) of an instrument 1.6 m away,
  5 of the measured rows moved 5 mm: the rows flagged, and the tool positions' error to the truth
  in the meas frame and after a rigid registration, against the clean run (the same data without
  the 5 rows);
* nests: a TCP calibration (a 150 mm tool on the nominal robot) from 8 rows of a point and 6 rows
  of a nest 120 mm away named as the same point: the rows flagged, the tool's error;
* cap: one sphere (100 mm) touched 40 times within 11 degrees of one direction: the status, the
  predicted tool error over the workspace, the nominal model's expected error and the calibrated
  and nominal models' errors to the truth.

Run: PYTHONPATH=. python scripts/touch_reliability.py [--seeds 3]
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread before numpy loads)

import argparse
from dataclasses import replace

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    import example_robot_data as erd
    from scipy.spatial.transform import Rotation

    import calib
    from calib.calibration.accuracy.errors import registered_error
    from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements
    from calib.model.touch import Feature, TouchData
    from calib.model.touch_simulate import reach_positions, simulate_touch

    robot = calib.load_robot(erd.load("ur10").urdf, tool_frame="tool0")
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = Rotation.from_rotvec([0.1, -0.3, 0.5]).as_matrix(), [1.5, -0.4, 0.2]
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        true = apply_deviations(robot, random_deviations(robot, 0.5e-3, rng))
        true = replace(true, T_meas_base_ref=X @ true.T_meas_base_ref)
        sim = simulate_touch(true, [Feature("point", "P1"), Feature("point", "P2")], [10, 10], sigma=0.02e-3, rng=rng)
        meas = simulate_measurements(true, robot.random_configurations(15, rng), sigma_pos=0.05e-3,
                                     position_only=True, rng=rng)
        pos = meas.position.copy()
        d = rng.normal(size=(5, 3))
        pos[:5] += 5e-3 * d / np.linalg.norm(d, axis=1)[:, None]
        data = replace(sim.data, measured=replace(meas, position=pos))
        Qt = robot.random_configurations(500, rng)
        res = calib.calibrate(robot, data, cv=0)
        clean = calib.calibrate(robot, replace(data, measured=data.measured.subset(np.arange(5, 15))), cv=0)
        e = [registered_error(r.robot, true, Qt, reg) * 1e3 for r in (res, clean) for reg in ("none", "rigid")]
        print(f"mixed seed {seed}: {res.status}, flagged rows {sorted(o.row for o in res.outliers)} (moved: "
              f"{data.measured.rows[:5].tolist()}); error meas frame {e[0]:.4f} mm (clean {e[2]:.4f}), rigid "
              f"{e[1]:.4f} mm (clean {e[3]:.4f})")
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        true = robot.with_changes(v_x=0.004, v_y=-0.003, v_z=0.150)
        sim = simulate_touch(true, [Feature("point", "TCP")], [8], sigma=0.02e-3, rng=rng)
        Q, ok = reach_positions(true, sim.truth[:3] + [0.12, 0.0, 0.0] + rng.normal(0.0, 0.02e-3, (6, 3)), rng,
                                attempts=12)
        data = TouchData(np.vstack([sim.data.q, Q[ok]]), np.zeros(8 + ok.sum(), int), sim.data.features)
        res = calib.calibrate(robot, data, params="tool")
        err = np.abs(res.robot.v()[:3] - true.v()[:3]).max() * 1e3
        print(f"nests seed {seed}: {res.status}, flagged rows {sorted(o.row for o in res.outliers)} (the second "
              f"nest: 9-14), touch residual RMS {res.group('touch').rms_after * 1e3:.4f} mm, tool error {err:.4f} mm")
    for seed in range(args.seeds):
        rng = np.random.default_rng(seed)
        true = apply_deviations(robot, random_deviations(robot, 0.5e-3, rng))
        c = simulate_touch(true, [Feature("sphere", "S", radius=0.1)], [4], sigma=0.0, rng=rng).truth[:3]
        R = Rotation.align_vectors([-c / np.linalg.norm(c)], [[0.0, 0.0, 1.0]])[0].as_matrix()
        angle, azimuth = np.radians(11) * np.sqrt(rng.uniform(size=40)), rng.uniform(0, 2 * np.pi, 40)
        dirs = np.column_stack([np.sin(angle) * np.cos(azimuth), np.sin(angle) * np.sin(azimuth), np.cos(angle)])
        Q, ok = reach_positions(true, c + 0.1 * dirs @ R.T + rng.normal(0.0, 0.02e-3, (40, 3)), rng, attempts=12)
        data = TouchData(Q[ok], np.zeros(ok.sum(), int), (Feature("sphere", "S", radius=0.1),))
        res = calib.calibrate(robot, data, cv=0)
        Qt = robot.random_configurations(500, rng)
        print(f"cap seed {seed}: {res.status}, predicted {res.predicted['position_rms'] * 1e3:.3g} mm, nominal "
              f"expected {res.predicted['nominal_rms'] * 1e3:.3g} mm; error calibrated "
              f"{registered_error(res.robot, true, Qt) * 1e3:.3g} mm, nominal {registered_error(robot, true, Qt) * 1e3:.3g} mm")


if __name__ == "__main__":
    main()
