"""Several targets per pose: cost of the per-target tool frames, and the accuracy of a
position-only calibration from three reflectors against its Cramer-Rao prediction.

    python scripts/bench_targets.py

Prints the median time of the pose Jacobian of 300 rows (one tool frame; three targets, rows
cycling through them), of a calibration of 60 configurations x 3 targets (position only, 0.02 mm
noise, params "base", no cross-validation), and that calibration's RMS error against the truth.
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread)

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib import calibrate, load_robot  # noqa: E402
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements

URDF = Path(__file__).resolve().parents[1] / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
OFFSETS = {"A": [0.10, 0.0, 0.05], "B": [-0.05, 0.08, 0.05], "C": [0.0, -0.07, 0.10]}


def main() -> None:
    print(_bench.machine())
    nominal = load_robot(URDF)
    model = nominal.with_target_offsets(OFFSETS)
    truth = apply_deviations(model, random_deviations(model, 2e-4, 1))
    Q = nominal.random_configurations(300, 0)
    rows = np.arange(300) % 3
    k1, k3 = ChainKinematics(nominal), ChainKinematics(truth)
    t1 = _bench.median_time(lambda: pose_jacobian(k1, Q), 9)
    t3 = _bench.median_time(lambda: pose_jacobian(k3, Q, targets=rows), 9)
    print(f"pose Jacobian, 300 rows: one tool frame {t1 * 1e3:.1f} ms, three targets {t3 * 1e3:.1f} ms")

    configs = nominal.random_configurations(60, 4)
    Qc, ids = np.repeat(configs, 3, axis=0), np.tile(list(OFFSETS), 60)
    m = simulate_measurements(truth, Qc, sigma_pos=0.02e-3, position_only=True, targets=ids, rng=5)
    tc = _bench.median_time(lambda: calibrate(nominal, m, params="base", cv=0), 3)
    res = calibrate(nominal, m, params="base", cv=0)
    r = res.robot.target_rows(m.target)
    _, p_true = ChainKinematics(truth).frame_poses(m.q, targets=r)
    _, p_cal = ChainKinematics(res.robot).frame_poses(m.q, targets=r)
    rms = float(np.sqrt(np.mean(np.sum((p_cal - p_true) ** 2, axis=1))))
    print(f"calibration, 60 configurations x 3 targets, position only: {tc:.2f} s, {res.status}, "
          f"{len(res.free)} parameters")
    print(f"  RMS error against the truth {rms * 1e3:.4f} mm; Cramer-Rao prediction "
          f"{res.predicted['position_rms'] * 1e3:.4f} mm; noise estimate {res.noise.position * 1e3:.4f} mm "
          f"(simulated 0.02)")


if __name__ == "__main__":
    main()
