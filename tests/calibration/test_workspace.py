"""Predictions over the workspace (calib.calibration.accuracy.workspace): the random configurations keep
to the joint limits (continuous and prismatic joints included), the coverage of each joint's
range, the propagation against Monte Carlo, and by simulation: poses bunched near a wrist
singularity get the note and a workspace prediction that matches the calibrated model's error
against the truth at random configurations; well-spread poses get no note."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import calib
from calib.calibration.accuracy.workspace import (
    WORKSPACE_CONFIGURATIONS,
    joint_coverage,
    predict_workspace,
    propagate_covariance,
    workspace_configurations,
    workspace_notes,
)
from calib.errors import CalibError, DataError
from calib.model.kinematics import ChainKinematics
from calib.model.chain import ChainJoint
from calib.model.robot import RobotModel
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements

from conftest import erd_urdf


@pytest.fixture(scope="module")
def ur5():
    return calib.load_robot(erd_urdf("ur5"))


def _mixed_chain() -> RobotModel:
    """A 4-joint chain with a limited revolute, a continuous, a limited prismatic and an
    unlimited prismatic joint."""
    joints = (ChainJoint("j1", "revolute", -1.0, 0.5), ChainJoint("j2", "continuous", -math.inf, math.inf),
              ChainJoint("j3", "prismatic", 0.1, 0.3), ChainJoint("j4", "prismatic", -math.inf, math.inf))
    return RobotModel.from_mdh(joints, theta=np.zeros(4), d=[0.3, 0.0, 0.0, 0.1], a=[0.0, 0.2, 0.0, 0.0],
                               alpha=[0.0, -math.pi / 2, math.pi / 2, 0.0])


# ------------------------------------------------------------------ configurations and coverage
def test_configurations_keep_to_the_limits_of_every_kind_of_joint():
    robot = _mixed_chain()
    q_cal = np.array([[0.0, 0.0, 0.2, -0.05], [0.1, 1.0, 0.25, 0.15]])
    Q = workspace_configurations(robot, 2000, seed=3, calibration_q=q_cal)
    assert Q.shape == (2000, 4)
    assert Q[:, 0].min() >= -1.0 and Q[:, 0].max() <= 0.5
    # the continuous joint over one turn, all of it (the largest of 2000 uniform gaps < 0.05 rad)
    assert Q[:, 1].min() >= -math.pi and Q[:, 1].max() < math.pi
    assert Q[:, 1].max() - Q[:, 1].min() > 2 * math.pi - 0.05
    assert Q[:, 2].min() >= 0.1 and Q[:, 2].max() <= 0.3
    # the unlimited prismatic joint over the calibration span, -0.05..0.15 m
    assert Q[:, 3].min() >= -0.05 and Q[:, 3].max() <= 0.15 and Q[:, 3].max() - Q[:, 3].min() > 0.19
    # the same seed, the same configurations
    np.testing.assert_array_equal(Q, workspace_configurations(robot, 2000, seed=3, calibration_q=q_cal))
    with pytest.raises(DataError, match="j4") as info:
        workspace_configurations(robot, 10)
    assert isinstance(info.value, CalibError) and "\n" not in str(info.value)


def test_revolute_joints_of_two_turns_are_drawn_over_one(ur5):
    # UR5 joints have limits of +-2 pi (elbow +-pi): further turns give the same poses
    Q = workspace_configurations(ur5, 3000, seed=1)
    assert np.all(np.abs(Q) <= math.pi)
    assert np.all(Q.max(axis=0) - Q.min(axis=0) > 2 * math.pi - 0.05)


def test_coverage_of_limited_circular_and_unlimited_joints():
    robot = _mixed_chain()
    Q = np.array([[-1.0, 3.0, 0.1, 5.0], [-0.25, -3.0, 0.15, 7.0], [-0.5, 3.1, 0.12, 6.0]])
    cov = joint_coverage(robot, Q)
    assert cov["j1"] == pytest.approx(0.75 / 1.5)           # -1..-0.25 of -1..0.5
    # 3.0, 3.1 and -3.0 (= 3.283) wrap around pi: they cover an arc of 0.283 rad
    assert cov["j2"] == pytest.approx((2 * math.pi - 6.0) / (2 * math.pi), abs=3e-5)
    # (measured in bins of the circle: exact to 2 bins of 65536)
    assert joint_coverage(robot, np.array([[0.0, 0.0, 0.1, 0.0], [0.1, math.pi, 0.2, 0.0]]))["j2"] == \
        pytest.approx(0.5, abs=3e-5)
    assert joint_coverage(robot, Q[:1])["j2"] == 0.0
    assert cov["j3"] == pytest.approx(0.25)
    assert cov["j4"] is None


# ------------------------------------------------------------------ the propagation
def test_propagation_matches_monte_carlo_parameter_errors(ur5):
    """sqrt(mean tr J C J^T) against the RMS tool error of models drawn from N(x, C): small
    errors (micrometres), so the linearisation holds; 400 draws give the RMS to ~4 %."""
    robot = apply_deviations(ur5, random_deviations(ur5, 1e-3, 5))
    free = tuple(n for n in robot.names if n.startswith(("theta", "a", "d", "alpha")))[:12]
    rng = np.random.default_rng(7)
    L = rng.normal(size=(len(free), len(free))) * 2e-6
    C = L @ L.T
    Q = robot.random_configurations(50, 8)
    pos, rot = propagate_covariance(robot, Q, free, C)
    R0, p0 = ChainKinematics(robot).frame_poses(Q)
    idx = robot.indices(free)
    kin = ChainKinematics(robot)
    sq_p = sq_r = 0.0
    draws = 400
    for dx in rng.multivariate_normal(np.zeros(len(free)), C, size=draws):
        v = robot.values.copy()
        v[idx] += dx
        kin.set_values(v)
        R, p = kin.frame_poses(Q)
        sq_p += float(np.mean(np.sum((p - p0) ** 2, axis=1)))
        # small rotations: the angle of R R0^T is the norm of the rotation vector
        cos = np.clip((np.einsum("nij,nij->n", R, R0) - 1.0) / 2.0, -1.0, 1.0)
        sq_r += float(np.mean(np.arccos(cos) ** 2))
    assert math.sqrt(sq_p / draws) == pytest.approx(pos, rel=0.1)
    assert math.sqrt(sq_r / draws) == pytest.approx(rot, rel=0.1)


def test_prediction_adds_the_noise_of_a_new_row_and_takes_every_target(bundled_robot):
    ids = ("A", "B", "C")
    robot = bundled_robot.with_targets(ids)
    free = ("theta2", "a2", "v_x@B", "v_y@C")
    C = np.diag([1e-6, 1e-8, 1e-8, 4e-8])
    w = predict_workspace(robot, free, C, sigma_pos=1e-4, sigma_rot=None)
    assert w["configurations"] == WORKSPACE_CONFIGURATIONS and w["rotation_rms"] is None
    # row k takes target k mod 3: the mean over the rows is the three targets' means weighted by
    # their rows
    Q = workspace_configurations(robot)
    parts = [propagate_covariance(robot, Q[k::3], free, C, targets=np.full(len(Q[k::3]), k))[0] ** 2
             for k in range(3)]
    counts = [len(Q[k::3]) for k in range(3)]
    assert w["model_position_rms"] == pytest.approx(math.sqrt(np.average(parts, weights=counts)), rel=1e-12)
    assert w["position_rms"] == pytest.approx(math.sqrt(w["model_position_rms"] ** 2 + 3e-8), rel=1e-12)
    # v_x@B moves target B's rows only
    only_b = np.diag([0.0, 0.0, 1e-8, 0.0])
    by_target = [propagate_covariance(robot, Q[k::3], free, only_b, targets=np.full(len(Q[k::3]), k))[0]
                 for k in range(3)]
    assert by_target[0] == by_target[2] == 0.0 and by_target[1] == pytest.approx(1e-4, rel=1e-9)


# ------------------------------------------------------------------ simulation
def _case(robot, seed, bunched, n=40):
    """A UR5 with ~1 mm / 1 mrad errors, 0.05 mm / 0.1 mrad noise; n rows either within
    +-0.15 rad of one configuration with the wrist singular (q5 = 0) or spread over the limits."""
    rng = np.random.default_rng(100 + seed)
    true = apply_deviations(robot, random_deviations(robot, 1e-3, rng))
    if bunched:
        centre = robot.random_configurations(1, rng)[0]
        centre[4] = 0.0
        Q = centre + rng.uniform(-0.15, 0.15, size=(n, robot.n_joints))
    else:
        Q = robot.random_configurations(n, rng)
    return true, simulate_measurements(true, Q, sigma_pos=0.05e-3, sigma_rot=1e-4, rng=rng)


def test_bunched_poses_get_the_note_and_an_honest_workspace_figure(ur5):
    """Three seeds pooled: the predicted error of the calibrated model over the workspace (against
    the truth, and on new noisy rows) within x1.5 of the observed one at 500 fresh random
    configurations, where the figure at the calibration configurations is 3x or more too
    optimistic."""
    pred_m = obs_m = pred_h = obs_h = cal_h = 0.0
    for seed in range(3):
        true, m = _case(ur5, seed, bunched=True)
        res = calib.calibrate(ur5, m)
        w = res.predicted_workspace
        Q = ur5.random_configurations(500, 50 + seed)
        new = simulate_measurements(true, Q, sigma_pos=0.05e-3, sigma_rot=1e-4, rng=60 + seed)
        _, p_true = ChainKinematics(true).frame_poses(Q)
        _, p_cal = ChainKinematics(res.robot).frame_poses(Q)
        obs_m += float(np.mean(np.sum((p_cal - p_true) ** 2, axis=1)))
        obs_h += calib.evaluate(res.robot, new).position["rms"] ** 2
        pred_m += w["model_position_rms"] ** 2
        pred_h += w["position_rms"] ** 2
        cal_h += res.predicted_holdout["position_rms"] ** 2
        note = next(n for n in res.notes if n.startswith("the predicted error on new rows over the workspace"))
        # the wrist joint 5 moved +-0.15 rad of its 2 pi: named, with its share
        assert "wrist_1_joint" in note or "wrist_2_joint" in note
        assert "add poses spread over the joint ranges" in note
        # +-0.15 rad of each joint's range: every joint's coverage is small
        assert max(w["joint_coverage"].values()) < 0.1
    assert 1 / 1.5 < math.sqrt(pred_m / obs_m) < 1.5
    assert 1 / 1.5 < math.sqrt(pred_h / obs_h) < 1.5
    assert math.sqrt(obs_h / cal_h) > 3.0


def test_spread_poses_get_no_note_and_an_equal_figure(ur5):
    true, m = _case(ur5, 0, bunched=False)
    res = calib.calibrate(ur5, m)
    w = res.predicted_workspace
    assert not any("over the workspace" in n for n in res.notes)
    assert 0.5 < w["position_rms"] / res.predicted_holdout["position_rms"] < 2.0
    assert min(w["joint_coverage"].values()) > 0.5
    Q = ur5.random_configurations(500, 9)
    _, p_true = ChainKinematics(true).frame_poses(Q)
    _, p_cal = ChainKinematics(res.robot).frame_poses(Q)
    obs = math.sqrt(float(np.mean(np.sum((p_cal - p_true) ** 2, axis=1))))
    assert 1 / 1.5 < w["model_position_rms"] / obs < 1.5


def test_note_threshold_and_wording():
    at_cal = {"position_rms": 1e-4, "rotation_rms": 1e-4, "where": "calibration configurations"}
    ws = {"position_rms": 1.9e-4, "rotation_rms": 1.9e-4, "where": "random configurations within the joint limits",
          "joint_coverage": {"j1": 0.9, "j2": 0.2, "j3": 0.05}}
    assert workspace_notes(at_cal, ws) == []
    (note,) = workspace_notes(at_cal, {**ws, "position_rms": 2.5e-4})
    assert "position 0.25 mm, 2.5x the 0.1 mm" in note
    # the poorly covered joints, worst first, the well covered one not named
    assert "the poses span only 5% of the range of j3, 20% of j2" in note
    assert "j1" not in note
    (note,) = workspace_notes(at_cal, {**ws, "rotation_rms": 3e-4, "joint_coverage": {"j1": 0.9}})
    assert "orientation 0.0003 rad, 3.0x" in note and "singular" in note


def test_result_reports_the_workspace_figures(bundled_robot, tmp_path):
    true = apply_deviations(bundled_robot, random_deviations(bundled_robot, 1e-3, 2))
    m = simulate_measurements(true, bundled_robot.random_configurations(60, 3), sigma_pos=2e-5,
                              sigma_rot=2e-3, rng=4)
    res = calib.calibrate(bundled_robot, m, cv=0)
    w = res.predicted_workspace
    text = res.format()
    assert (f"predicted RMS error on new measured rows ({WORKSPACE_CONFIGURATIONS} random configurations "
            f"within the joint limits): position {w['position_rms'] * 1e3:.4g} mm") in text
    d = json.loads(res.to_json())["predicted_workspace_rms"]
    assert d["position_mm"] == pytest.approx(w["position_rms"] * 1e3)
    assert d["model_rotation_rad"] == pytest.approx(w["model_rotation_rms"])
    assert set(d["joint_coverage"]) == set(bundled_robot.joint_names)
    # the same model and covariance give the same figure (seeded)
    again = predict_workspace(res.robot, res.free, res.covariance, res.sigma_pos, res.sigma_rot,
                              calibration_q=m.q)
    assert again["position_rms"] == pytest.approx(w["position_rms"], rel=1e-12)


def test_position_only_and_validation_rows(bundled_robot):
    true = apply_deviations(bundled_robot, random_deviations(bundled_robot, 1e-3, 2))
    Q = bundled_robot.random_configurations(80, 3)
    m = simulate_measurements(true, Q, sigma_pos=2e-5, rng=4, position_only=True)
    val = simulate_measurements(true, bundled_robot.random_configurations(30, 5), sigma_pos=2e-5, rng=6,
                                position_only=True)
    res = calib.calibrate(bundled_robot, m, validation=val, cv=0)
    w = res.predicted_workspace
    assert w["rotation_rms"] is None and w["model_rotation_rms"] is None
    # spread poses: the workspace and the validation configurations agree
    assert 0.5 < w["position_rms"] / res.predicted_holdout["position_rms"] < 2.0


def _arm_case(robot, seed, bunched, n=40):
    """As :func:`_case` for any arm: bunched rows within +-0.15 rad (+-20 mm for a prismatic
    joint) of a random configuration, clipped to the limits."""
    rng = np.random.default_rng(100 + seed)
    true = apply_deviations(robot, random_deviations(robot, 1e-3, rng))
    if bunched:
        centre = robot.random_configurations(1, rng)[0]
        half = np.where(robot.prismatic, 0.02, 0.15)
        Q = rng.uniform(np.maximum(centre - half, robot.lower), np.minimum(centre + half, robot.upper),
                        size=(n, robot.n_joints))
    else:
        Q = robot.random_configurations(n, rng)
    return true, simulate_measurements(true, Q, sigma_pos=0.05e-3, sigma_rot=1e-4, rng=rng)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["tiago", "kinova", "panda", "z1"])
def test_workspace_prediction_on_other_arms(name):
    """A prismatic torso (TIAGo), continuous joints (Kinova), 7 axes (Panda), limited ranges (Z1):
    bunched poses get the note and a workspace figure within x1.5 of the observed error against
    the truth (two seeds pooled; single seeds ranged 0.71-1.37); spread poses no note."""
    robot = calib.load_robot(name) if name == "tiago" else calib.load_robot(erd_urdf(name))
    pred = obs = 0.0
    for seed in range(2):
        true, m = _arm_case(robot, seed, bunched=True)
        res = calib.calibrate(robot, m)
        assert any(n.startswith("the predicted error on new rows over the workspace") for n in res.notes)
        Q = workspace_configurations(robot, 500, seed=77)
        _, p0 = ChainKinematics(true).frame_poses(Q)
        _, p1 = ChainKinematics(res.robot).frame_poses(Q)
        obs += float(np.mean(np.sum((p1 - p0) ** 2, axis=1)))
        pred += res.predicted_workspace["model_position_rms"] ** 2
    assert 1 / 1.5 < math.sqrt(pred / obs) < 1.5
    _, m = _arm_case(robot, 0, bunched=False)
    res = calib.calibrate(robot, m)
    assert not any("over the workspace" in n for n in res.notes)


def test_workspace_prediction_of_three_targets(bundled_robot):
    """Three reflectors measured by position at 40 configurations: the workspace figure takes
    every target and matches the calibrated model's error against the truth over all three."""
    from calib.model.spatial import zyx_transform

    ids = ("A", "B", "C")
    refs = np.array([bundled_robot.T_flange_tool_ref @ zyx_transform(*o, 0.0, 0.0, 0.0)
                     for o in [(0.10, 0.0, 0.05), (-0.05, 0.08, 0.05), (0.0, -0.07, 0.10)]])
    truth = apply_deviations(bundled_robot.with_targets(ids, refs),
                             random_deviations(bundled_robot.with_targets(ids, refs), 3e-4, 1))
    Q = np.repeat(bundled_robot.random_configurations(40, 2), 3, axis=0)
    m = simulate_measurements(truth, Q, sigma_pos=0.05e-3, position_only=True, targets=np.tile(ids, 40), rng=3)
    res = calib.calibrate(bundled_robot, m, params="base", cv=0)
    w = res.predicted_workspace
    assert res.robot.targets == ids and w["rotation_rms"] is None
    Qr = workspace_configurations(res.robot, 600, seed=5)
    rows = np.arange(600) % 3
    _, p0 = ChainKinematics(truth).frame_poses(Qr, targets=rows)
    _, p1 = ChainKinematics(res.robot).frame_poses(Qr, targets=rows)
    obs = math.sqrt(float(np.mean(np.sum((p1 - p0) ** 2, axis=1))))
    assert 1 / 1.5 < w["model_position_rms"] / obs < 1.5


def test_covered_arc_by_sorting_equals_the_binned_one():
    """Few angles are sorted (exact), many binned (to 2 bins of a turn): the two agree."""
    import calib.calibration.accuracy.workspace as W

    rng = np.random.default_rng(3)
    for q in (rng.uniform(-1.0, 2.0, 50), rng.uniform(-7.0, 7.0, 200), np.array([3.1, -3.1]), np.array([0.5])):
        exact = W._arc_covered(q)
        limit = W._ARC_SORT_BELOW
        try:
            W._ARC_SORT_BELOW = 0
            binned = W._arc_covered(q)
        finally:
            W._ARC_SORT_BELOW = limit
        assert abs(exact - binned) <= 2.0 / W._ARC_BINS, (q[:3], exact, binned)
    # two angles either side of +-pi cover the short arc between them
    assert W._arc_covered(np.array([3.1, -3.1])) == pytest.approx((2 * math.pi - 6.2) / (2 * math.pi), rel=1e-12)
