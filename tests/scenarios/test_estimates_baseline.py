"""Speed work must not change results: estimates recorded from the code before the speed changes
(issue 14), on the bundled robot with a fixed-seed simulation, are reproduced to 1e-9 relative.

The reference values in tests/data/speed_baseline.json were written by ``compute_baseline`` with
the code of commit d51ca26 (``python tests/test_speed_baseline.py --record`` rewrites them; do
that only for a deliberate change of results), and recorded again for issue 39, item 3: of a
frame offset and a link length tied, the frame is fitted (u_z, v_x, v_z instead of d1, a6, d6),
the calibrated kinematics the same to 4.4e-16 m and rad, the cost and predictions to 4e-13.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parents[1] / "data" / "speed_baseline.json"


def compute_baseline() -> dict:
    """Estimates and statistics of fixed-seed calibrations of the bundled robot (SI units)."""
    import calib
    from calib.solvers.angles import RotationChain
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    Q = robot.random_configurations(100, 1)
    meas = simulate_measurements(true, Q, rng=2)
    val = simulate_measurements(true, robot.random_configurations(50, 3), sigma_pos=0, sigma_rot=0)
    out = {}
    for method in ("search-lm", "c-lm", "lm"):
        r = calib.calibrate(robot, meas, method=method, validation=val, sigma_pos=0.02e-3, sigma_rot=0.002)
        out[method] = {"free": list(r.free), "x": r.x.tolist(), "std": r.std.tolist(),
                       "cost": r.cost, "reduced_chi2": r.reduced_chi2,
                       "predicted_position_rms": r.predicted["position_rms"],
                       "predicted_rotation_rms": r.predicted["rotation_rms"],
                       "iterations": r.iterations}
    pos = simulate_measurements(true, Q, rng=2, position_only=True)
    r = calib.calibrate(robot, pos, sigma_pos=0.02e-3, sigma_rot=0.002)
    out["position"] = {"free": list(r.free), "x": r.x.tolist(), "std": r.std.tolist(), "cost": r.cost}
    J = calib.identification_jacobian(true, Q[:5])
    out["jacobian_sum"] = float(np.abs(J).sum())
    out["jacobian_00"] = J[:6, :].tolist()
    start = robot.with_changes(theta1=2.0, alpha2=-1.5)
    angular = [k for k, p in enumerate(start.parameters) if p.is_angular]
    v, c = RotationChain(start).search(start.values, meas.q, meas.rotation, angular, 0.002)
    out["angle_search"] = {"values": v.tolist(), "cost": c}
    rep = calib.analyze_identifiability(robot)
    out["identifiable"] = list(rep.identifiable)
    out["condition_number"] = rep.condition_number
    return out


@pytest.fixture(scope="module")
def pair():
    return json.loads(DATA.read_text()), compute_baseline()


# Converged LM estimates agree to 1e-9 relative; the absolute floor 1e-13 (m or rad) covers
# parameters whose value is near zero, nine orders below the noise (0.02 mm, 0.002 rad).
RTOL, ATOL = 1e-9, 1e-13


@pytest.mark.parametrize("method", ["search-lm", "c-lm", "lm", "position"])
def test_estimates_unchanged(pair, method):
    ref, now = pair[0][method], pair[1][method]
    assert now["free"] == ref["free"]
    np.testing.assert_allclose(now["x"], ref["x"], rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(now["std"], ref["std"], rtol=1e-7)
    np.testing.assert_allclose(now["cost"], ref["cost"], rtol=1e-9)


@pytest.mark.parametrize("method", ["search-lm", "c-lm", "lm"])
def test_statistics_unchanged(pair, method):
    ref, now = pair[0][method], pair[1][method]
    for key in ("reduced_chi2", "predicted_position_rms", "predicted_rotation_rms"):
        np.testing.assert_allclose(now[key], ref[key], rtol=1e-7, err_msg=key)


def test_jacobian_and_angle_search_unchanged(pair):
    ref, now = pair
    np.testing.assert_allclose(now["jacobian_00"], ref["jacobian_00"], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(now["jacobian_sum"], ref["jacobian_sum"], rtol=1e-12)
    # theta1 and u_alpha turn about the same axis while u_beta = u_gamma = 0: the greedy search
    # meets an exact tie there, which rounding decides; their sum is what the data fix
    v_now, v_ref = np.array(now["angle_search"]["values"]), np.array(ref["angle_search"]["values"])
    tied = [0, 28]   # theta1, u_alpha
    np.testing.assert_allclose(v_now[tied].sum(), v_ref[tied].sum(), rtol=1e-9)
    v_now[tied] = v_ref[tied] = 0.0
    np.testing.assert_allclose(v_now, v_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(now["angle_search"]["cost"], ref["angle_search"]["cost"], rtol=1e-9)
    assert now["identifiable"] == ref["identifiable"]
    np.testing.assert_allclose(now["condition_number"], ref["condition_number"], rtol=1e-9)


EB_MAP_DATA = DATA.with_name("eb_map_baseline.json")
#: EB-MAP on few rows carries rounding further than least squares: a one-ulp change of one
#: measured row moved the estimates of these cases by up to 4e-6 standard deviations (review of
#: issue 27), so they are compared in standard deviations, at a few times that.
EB_MAP_STD_TOL = 2e-5


def compute_eb_map() -> dict:
    """The default (EB-MAP) estimates of fixed-seed simulations of the bundled robot at 12, 25
    and 40 poses (SI units) and their posterior standard deviations."""
    import calib
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements

    robot = calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    out = {}
    for n, seed in ((12, 4), (25, 3), (40, 2)):
        r = calib.calibrate(robot, simulate_measurements(true, robot.random_configurations(n, seed), rng=seed + 1))
        out[f"{n}"] = {"param_set": r.param_set, "free": list(r.free), "x": r.x.tolist(), "std": r.std.tolist()}
    return out


@pytest.fixture(scope="module")
def eb_map_pair():
    return json.loads(EB_MAP_DATA.read_text()), compute_eb_map()


@pytest.mark.parametrize("n", ["12", "25", "40"])
def test_eb_map_estimates_unchanged(eb_map_pair, n):
    """The EB-MAP estimates recorded at the end of the speed work (issue 27), to EB_MAP_STD_TOL
    standard deviations."""
    ref, now = eb_map_pair[0][n], eb_map_pair[1][n]
    assert now["param_set"] == ref["param_set"] == "eb-map" and now["free"] == ref["free"]
    dev = np.abs(np.array(now["x"]) - np.array(ref["x"])) / np.array(ref["std"])
    assert float(dev.max()) < EB_MAP_STD_TOL
    np.testing.assert_allclose(now["std"], ref["std"], rtol=1e-4)


if __name__ == "__main__":
    if "--record" in sys.argv:
        DATA.write_text(json.dumps(compute_baseline(), indent=1))
        print(f"wrote {DATA}")
    if "--record-eb-map" in sys.argv:
        EB_MAP_DATA.write_text(json.dumps(compute_eb_map(), indent=1))
        print(f"wrote {EB_MAP_DATA}")
