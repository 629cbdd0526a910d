"""Write the example files of docs/instruments.md (run from the repository root:
``python examples/instruments/make_examples.py``; the files are deterministic).

Simulated, not measured: a UR5 (example-robot-data) with small joint-geometry errors, a tracker
2.1 m away and turned 34 degrees about its vertical, a T-Mac on a 120 mm adaptor; 30 stops.

- ``ur5_rtde.csv``: the UR's RTDE recording at 500 Hz around each stop, as UR's recorder writes
  it (space separated; ``timestamp`` in s, ``target_q_*``, ``actual_q_*`` in rad,
  ``actual_TCP_pose_*``, ``robot_mode``), and two rows while moving between stops.
- ``leica_tmac.csv``: the tracker's 6-DoF export, ``Point;Time [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3``,
  decimal commas, Q0 the scalar; noise 0.01 mm and 2e-5 rad per axis.
- ``ur5_waypoints.csv``: the UR's joint values at the stops, one row per point (``Point``, joint
  names of the UR convention, rad).
- ``sa_points.txt``: a SpatialAnalyzer ASCII export of three reflectors measured at each stop
  (``// `` comments, no header line, ``Collection Group Target X Y Z``, mm), point names
  ``P001_SMR1`` ...; noise 0.01 mm.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import calib

HERE = Path(__file__).resolve().parent
N = 30
DEVIATIONS = {"theta2": 1.2e-3, "theta3": -0.8e-3, "theta4": 0.6e-3, "a2": 0.4e-3, "a3": -0.3e-3,
              "d4": 0.25e-3, "alpha2": 0.5e-3, "alpha3": -0.4e-3,
              "u_x": 2.1, "u_y": -0.8, "u_z": 0.35, "u_gamma": 0.6,          # the tracker's place
              "v_z": 0.12}                                                     # the T-Mac's adaptor
SMR = {"SMR1": [0.08, 0.0, 0.05], "SMR2": [-0.04, 0.07, 0.05], "SMR3": [0.0, -0.06, 0.09]}


def _c(v: float, digits: int) -> str:
    return f"{v:.{digits}f}".replace(".", ",")


def main() -> None:
    robot = calib.load_robot("ur5", tool_frame="tool0")
    truth = calib.apply_deviations(robot, DEVIATIONS)
    Q = robot.random_configurations(N, 37)
    meas = calib.simulate_measurements(truth, Q, sigma_pos=1e-5, sigma_rot=2e-5, rng=37)
    stops = 4.0 + 6.0 * np.arange(N)                   # a stop every 6 s

    # the RTDE recording: 500 Hz around each stop, two rows while moving to the next
    names = (["timestamp"] + [f"target_q_{i}" for i in range(6)] + [f"actual_q_{i}" for i in range(6)]
             + [f"actual_TCP_pose_{i}" for i in range(6)] + ["robot_mode"])
    T = np.array([robot.T_meas_tool(q) for q in Q])    # what the controller believes (nominal model)
    tcp = np.hstack([T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_rotvec()])
    rows = []
    for k in range(N):
        for dt in np.arange(-0.006, 0.0061, 0.002):
            rows.append([stops[k] + dt, *Q[k], *Q[k], *tcp[k], 7])
        if k + 1 < N:
            for f in (1 / 3, 2 / 3):
                q = Q[k] + f * (Q[k + 1] - Q[k])
                rows.append([stops[k] + f * 6.0, *q, *q, *tcp[k], 7])
    (HERE / "ur5_rtde.csv").write_text(" ".join(names) + "\n" + "".join(
        f"{r[0]:.3f} " + " ".join(f"{v:.9f}" for v in r[1:-1]) + f" {r[-1]}\n" for r in rows))

    # the Leica export: one row per stop, its time 0.7 ms after the stop's
    wxyz = Rotation.from_matrix(meas.rotation).as_quat(scalar_first=True)
    (HERE / "leica_tmac.csv").write_text("Point;Time [s];X [mm];Y [mm];Z [mm];Q0;Q1;Q2;Q3\n" + "".join(
        ";".join([f"P{k + 1:03d}", _c(stops[k] + 0.0007, 4)] + [_c(v, 4) for v in meas.position[k] * 1e3]
                 + [_c(v, 8) for v in wxyz[k]]) + "\n" for k in range(N)))

    # the waypoints and SpatialAnalyzer's export of three reflectors at each stop
    (HERE / "ur5_waypoints.csv").write_text(
        "Point,base,shoulder,elbow,wrist1,wrist2,wrist3\n" + "".join(
            f"P{k + 1:03d}," + ",".join(f"{v:.9f}" for v in Q[k]) + "\n" for k in range(N)))
    three = truth.with_target_offsets(SMR)
    ids = list(SMR) * N
    smr = calib.simulate_measurements(three, np.repeat(Q, 3, axis=0), sigma_pos=1e-5, position_only=True,
                                      targets=ids, rng=38)
    lines = ["// SpatialAnalyzer Version: 2023.1.0623.7", "// Working Frame: Robot Cal::World"]
    lines += [f"Robot_Cal Stops P{k // 3 + 1:03d}_{ids[k]} " + " ".join(f"{v:.4f}" for v in smr.position[k] * 1e3)
              for k in range(len(ids))]
    (HERE / "sa_points.txt").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
