"""Identification against known truth from simulation (issue 4's acceptance on the paper's setup)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import calib
from calib import DataError, ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
from calib.solvers.lm import LMOptions
from calib.model.spatial import log3_batch

from conftest import erd_urdf

NOISE_FREE = dict(sigma_pos=0.0, sigma_rot=0.0)


@pytest.fixture(scope="module")
def setup(bundled_robot):
    """The paper's simulation: Tables 4-5 deviations, 100 random poses, 200 validation poses."""
    true = apply_deviations(bundled_robot, PAPER_DEVIATIONS)
    rng = np.random.default_rng(2023)
    Q = bundled_robot.random_configurations(100, rng)
    Qv = bundled_robot.random_configurations(200, rng)
    val = simulate_measurements(true, Qv, **NOISE_FREE)
    return bundled_robot, true, Q, Qv, val


def flange_in_base_errors(model, truth, Q):
    """Position (m) and rotation (rad) errors of the flange relative to the base (Tables 10-11)."""
    poses = []
    for m in (model, truth):
        k = ChainKinematics(m)
        Rb, pb = k.frame_poses(Q, "base")
        Rf, pf = k.frame_poses(Q, "flange")
        poses.append((np.einsum("nji,nj->ni", Rb, pf - pb), np.transpose(Rb, (0, 2, 1)) @ Rf))
    (p1, R1), (p2, R2) = poses
    return (np.linalg.norm(p1 - p2, axis=1),
            np.linalg.norm(log3_batch(R1 @ np.transpose(R2, (0, 2, 1))), axis=1))


def test_paper_set_meets_table10(setup):
    robot, true, Q, Qv, val = setup
    meas = simulate_measurements(true, Q, rng=1)
    res = calib.calibrate(robot, meas, params="paper", validation=val)
    assert res.success and res.param_set == "paper" and len(res.free) == 31
    pe, re = flange_in_base_errors(res.robot, true, Qv)
    pe0, _ = flange_in_base_errors(robot, true, Qv)
    assert pe.mean() <= 0.0122e-3, pe.mean()           # Table 10, TM-MDH mean: 0.0122 mm
    assert pe0.mean() > 1e-3                            # before: millimetres (paper: 1.95 mm)
    assert re.mean() < 1e-3


@pytest.mark.parametrize("method", ["c-lm", "lm"])
def test_estimator_is_efficient(setup, method):
    """Averaged over 20 noise draws, the validation RMS error is within 10% of Cramer-Rao."""
    robot, true, Q, Qv, val = setup
    achieved, predicted, achieved_rot, predicted_rot = [], [], [], []
    for k in range(20):
        res = calib.calibrate(robot, simulate_measurements(true, Q, rng=100 + k), method=method,
                              validation=val)
        assert res.success
        achieved.append(res.validation_after.position["rms"])
        achieved_rot.append(res.validation_after.rotation["rms"])
        predicted.append(res.predicted["position_rms"])
        predicted_rot.append(res.predicted["rotation_rms"])
    ratio = np.sqrt(np.mean(np.square(achieved))) / np.mean(predicted)
    ratio_rot = np.sqrt(np.mean(np.square(achieved_rot))) / np.mean(predicted_rot)
    assert abs(ratio - 1) < 0.10, ratio
    assert abs(ratio_rot - 1) < 0.10, ratio_rot


def test_reduced_chi2_and_std(setup):
    robot, true, Q, Qv, val = setup
    res = calib.calibrate(robot, simulate_measurements(true, Q, rng=7))
    # the noise model matches the data: chi^2 / dof has standard deviation sqrt(2 / dof) = 0.06
    dof = 600 - len(res.free)
    assert abs(res.reduced_chi2 - 1) < 4 * np.sqrt(2 / dof)
    # identified within 4 sigma of the truth for every free parameter
    for p in res.parameters:
        if p.free and p.name[0] not in "uv":
            assert abs(p.identified - true.value(p.name)) < 4 * p.std, p


def test_noise_free_reproduces_truth(setup):
    robot, true, Q, Qv, val = setup
    meas = simulate_measurements(true, Q, **NOISE_FREE)
    for params in ("base", "paper", "all"):
        res = calib.calibrate(robot, meas, params=params, validation=val)
        assert res.success
        assert res.validation_after.position["max"] < 1e-9, params    # metres
        assert res.validation_after.rotation["max"] < 1e-9, params    # radians


def test_noise_free_paper_set_recovers_structure(setup):
    """With params="paper" (31 parameters, rank 30) the structural parameters come back exactly
    except along the one exact null direction, which the damped LM leaves where it started
    (the minimum-change split). That direction is d2 - d3 to first order (Section 4.2); because
    the true axes 2 and 3 are not exactly parallel (Delta alpha2 = 0.0035, Delta beta2 = 0.001 rad)
    it also moves theta2, theta3, a2, alpha2 and beta2, by about 1% of the d2/d3 split or less.
    The issue's "every structural parameter to 1e-9 except d2 and d3" holds for those five only
    to that level."""
    robot, true, Q, Qv, val = setup
    res = calib.calibrate(robot, simulate_measurements(true, Q, **NOISE_FREE), params="paper")
    err = {n: res.robot.value(n) - true.value(n) for n in robot.names}
    coupled = ("theta2", "theta3", "a2", "alpha2", "beta2")
    assert abs(err["d2"] + err["d3"]) < 1e-9            # their sum is recovered (metres)
    assert abs(err["d2"]) > 1e-6                          # each one is not
    for name, e in err.items():
        if name not in ("d2", "d3") + coupled:
            assert abs(e) < 1e-9, (name, e)
    for name in coupled:
        assert abs(err[name]) < 0.02 * abs(err["d2"]), (name, err[name])


def test_all_set_reproduces_tables_6_7_structure(setup):
    """Identifying all 37 parameters (C-LM, 20 rounds, noise-free): the same 14 anomalies as
    Tables 6-7 (relative error > 2%), and each of the seven pairs sums to its preset sum (Eq. 29),
    to first order in the deviations (the largest second-order miss, 3e-6 rad for theta6 +
    v_alpha, comes from alpha6 = -0.001 rad tilting axis 6 against the flange z axis)."""
    robot, true, Q, Qv, val = setup
    res = calib.calibrate(robot, simulate_measurements(true, Q, **NOISE_FREE), params="all",
                          fixed_rounds=20)
    dev = {n: res.robot.value(n) - robot.value(n) for n in robot.names}
    pairs = [("d2", "d3"), ("d1", "u_z"), ("theta1", "u_alpha"), ("a6", "v_x"), ("d6", "v_z"),
             ("theta6", "v_alpha"), ("alpha6", "v_gamma")]
    anomalous = {n for n in robot.names
                 if abs(dev[n] - PAPER_DEVIATIONS[n]) > 0.02 * max(abs(PAPER_DEVIATIONS[n]), 1e-4)}
    assert anomalous == {n for p in pairs for n in p}     # 14, as in the paper
    for a, b in pairs:
        preset = PAPER_DEVIATIONS[a] + PAPER_DEVIATIONS[b]
        assert abs(dev[a] + dev[b] - preset) < 0.02 * abs(preset) + 1e-7, (a, b)
        assert abs(dev[a] + dev[b] - preset) < 5e-6, (a, b)


@pytest.mark.parametrize("position_only", [False, True])
def test_far_measurement_frame_and_tool_offset(setup, position_only):
    """Tracker anywhere within 5 m at any orientation, tool 300 mm off the flange: converges
    from the nominal model with no initial guess (closed-form frames)."""
    robot, true, Q, Qv, _ = setup
    for seed in range(4):
        g = np.random.default_rng(seed)
        X = np.eye(4)
        X[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        direction = g.normal(size=3)
        X[:3, 3] = direction / np.linalg.norm(direction) * g.uniform(0.5, 5.0)
        Y = np.eye(4)
        Y[:3, :3] = Rotation.from_rotvec(g.normal(size=3) * 0.5).as_matrix()
        offset = g.normal(size=3)
        Y[:3, 3] = offset / np.linalg.norm(offset) * 0.3
        truth = replace(true, T_meas_base_ref=X, T_flange_tool_ref=Y)
        meas = simulate_measurements(truth, Q, rng=seed, position_only=position_only)
        val = simulate_measurements(truth, Qv, position_only=position_only, **NOISE_FREE)
        res = calib.calibrate(robot, meas, validation=val)
        assert res.success, res.message
        assert res.validation_after.position["rms"] < 0.03e-3, (seed, res.validation_after.position)
        assert any("closed form" in n for n in res.notes)
        if position_only:
            assert any("position-only data" in n and "ran LM" in n for n in res.notes)


def test_position_only_from_nominal(setup):
    robot, true, Q, Qv, _ = setup
    truth = true.with_changes(v_x=0.15, v_z=0.1)
    meas = simulate_measurements(truth, Q, rng=3, position_only=True)
    val = simulate_measurements(truth, Qv, position_only=True, **NOISE_FREE)
    res = calib.calibrate(robot, meas, validation=val)
    assert res.success and res.validation_after.position["rms"] < 0.03e-3
    assert res.validation_after.rotation_errors is None


def test_ur5_calibrates(setup):
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    true = apply_deviations(robot, calib.random_deviations(robot, 0.5e-3, rng=4))
    Q = robot.random_configurations(100, 5)
    Qv = robot.random_configurations(100, 6)
    res = calib.calibrate(robot, simulate_measurements(true, Q, rng=5),
                          validation=simulate_measurements(true, Qv, **NOISE_FREE))
    assert res.success
    assert res.validation_before.position["rms"] > 1e-3
    assert res.validation_after.position["rms"] < 1.2 * res.predicted["position_rms"] + 1e-6


def test_status_reports_non_convergence(setup):
    robot, true, Q, _, _ = setup
    res = calib.calibrate(robot, simulate_measurements(true, Q, rng=1), method="lm",
                          options=LMOptions(max_iterations=1))
    assert res.status == "max_iterations" and not res.success


def test_bad_arguments(setup):
    robot, true, Q, _, _ = setup
    meas = simulate_measurements(true, Q, rng=1)
    with pytest.raises(ParameterError, match="unknown method"):
        calib.calibrate(robot, meas, method="gauss")
    with pytest.raises(ParameterError, match="unknown parameter"):
        calib.calibrate(robot, meas, params=["d1", "d9"])
    with pytest.raises(ParameterError, match="unknown parameter set"):
        calib.calibrate(robot, meas, params="everything")
    with pytest.raises(DataError, match="fewer than the 30 identifiable parameters need"):
        calib.calibrate(robot, meas.subset(slice(0, 4)))


def test_evaluate(setup):
    robot, true, Q, _, _ = setup
    meas = simulate_measurements(true, Q, **NOISE_FREE)
    assert calib.evaluate(true, meas).position["max"] < 1e-12
    s = calib.evaluate(robot, meas)
    e = s.position_errors
    assert s.position == pytest.approx({"mean": e.mean(), "rms": np.sqrt((e ** 2).mean()),
                                        "max": e.max(), "min": e.min()})


def test_distinct_configurations_counts_as_numpy_unique():
    from calib.calibration.prepare import distinct_configurations

    rng = np.random.default_rng(3)
    Q = np.round(rng.normal(size=(30, 6)), 1)
    Q = np.vstack([Q, Q[:7], Q[:2] + 1e-12, -0.0 * np.ones((1, 6)), np.zeros((1, 6))])
    assert distinct_configurations(Q) == len(np.unique(np.round(Q / 1e-9), axis=0)) == 31


def test_normal_equations_reweighted_from_the_shared_linearisation():
    """A problem derived with other noise levels re-scales the normal equations of its parent
    at the same x: equal to computing them afresh."""
    from calib.model.kinematics import ChainKinematics
    from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, simulate_measurements
    from calib.solvers.problem import Problem

    robot = calib.load_robot(Path(__file__).resolve().parents[2] / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    meas = simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(20, 1), rng=2)
    idx = robot.indices(["theta2", "d3", "alpha4", "u_x", "v_y"])
    keep = np.arange(20) % 4 != 0
    x = robot.values[idx] + 1e-3
    root = Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, idx, 2e-5, 2e-3)
    first = root.derived(keep=keep)
    first.normal_equations(x)
    shared = root.derived(keep=keep, sigma_pos=3e-5, sigma_rot=1e-3).normal_equations(x)
    fresh = Problem(ChainKinematics(robot), meas.q[keep], meas.position[keep], meas.rotation[keep], robot.values,
                    idx, 3e-5, 1e-3).normal_equations(x)
    for name in ("A", "g", "A_pos", "A_rot", "rss_pos", "rss_rot"):   # to rounding of their largest entries
        want = getattr(fresh, name)
        np.testing.assert_allclose(getattr(shared, name), want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)),
                                   err_msg=name)
    assert (shared.n_pos, shared.n_rot) == (45, 45)
    # other rows are not served from the cache
    other = root.derived(keep=~keep, sigma_pos=3e-5, sigma_rot=1e-3).normal_equations(x)
    assert other.n_pos == 15 and not np.allclose(other.A, shared.A)
