"""The tool frame of a model of several targets (calib.model.flange): the last link's parameters
moved into the targets leave every target's pose unchanged, and the tool frame's own model."""
from __future__ import annotations

import numpy as np
import pytest

from calib import ChainJoint, RobotModel, load_robot
from calib.errors import DataError, ParameterError
from calib.model.flange import flange_robot, last_link_names, with_nominal_last_link
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import apply_deviations, random_deviations

from conftest import BUNDLED_URDF, erd_urdf

IDS = ("A", "B", "C")
OFFSETS = {"A": [0.06, 0.0, 0.04], "B": [-0.03, 0.055, 0.04], "C": [-0.03, -0.055, 0.04]}


def _nominal(name):
    if name == "bundled":
        return load_robot(BUNDLED_URDF)
    if name == "prismatic":     # a last joint that slides: L_n(q) = Trans(z, q) L_n(0)
        joints = [ChainJoint("j1", "revolute", -3.0, 3.0), ChainJoint("j2", "revolute", -2.0, 2.0),
                  ChainJoint("j3", "prismatic", -0.2, 0.2)]
        return RobotModel.from_mdh(joints, [0.0, 0.3, 0.0], [0.4, 0.0, 0.1], [0.2, 0.3, 0.0],
                                   [np.pi / 2, 0.0, 0.0])
    return load_robot(erd_urdf(name), tool_frame="tool0" if name == "ur10" else None)


def _poses(robot, Q):
    """(N, K, 4, 4) every target's pose at every configuration (Eq. 1 products, joint terms included)."""
    return np.array([[robot.T_meas_tool(q, k) for k in range(robot.n_targets)] for q in Q])


@pytest.mark.parametrize("name", ["bundled", "ur10", "prismatic"])
def test_last_link_at_the_nominal_leaves_every_target_where_it_was(name):
    nominal = _nominal(name).with_target_offsets(OFFSETS)
    robot = apply_deviations(nominal, random_deviations(nominal, 1e-4, 2))
    last = last_link_names(robot)
    assert last[0] == f"theta{robot.n_joints}" and len(last) >= 4
    # a fitted last link far from the nominal (mm and 0.1 rad: what a free fit may wander to)
    robot = robot.with_changes(**{n: (0.1 if robot.parameters[robot.index(n)].unit == "rad" else 3e-3)
                                  for n in last})
    moved = with_nominal_last_link(robot, nominal)
    np.testing.assert_array_equal(moved.values[moved.indices(last)], nominal.values[nominal.indices(last)])
    others = [n for n in robot.names if n not in last and not n.startswith("v_")]
    np.testing.assert_array_equal(moved.values[moved.indices(others)], robot.values[robot.indices(others)])
    Q = robot.random_configurations(25, 3)
    # the targets' poses at every configuration: the same to rounding (their transforms took G)
    assert np.abs(_poses(moved, Q) - _poses(robot, Q)).max() < 1e-12
    # ... and the flange did move: by the last link's change, metres
    dp = [np.linalg.norm((moved.T_base_flange(q) - robot.T_base_flange(q))[:3, 3]) for q in Q]
    assert min(dp) > 1e-3
    assert with_nominal_last_link(moved, nominal) is moved       # nothing left to move


def test_joint_terms_move_with_the_chain():
    """Periodic joint errors add to q before L_n: the poses stay the same with them."""
    nominal = _nominal("bundled").with_target_offsets(OFFSETS)
    robot = apply_deviations(nominal, random_deviations(nominal, 1e-4, 5)).with_changes(d6=2e-3, theta6=0.05)
    robot = robot.with_periodic(np.random.default_rng(1).normal(0.0, 1e-3, 4 * robot.n_joints))
    moved = with_nominal_last_link(robot, nominal)
    Q = robot.random_configurations(10, 4)
    assert moved.has_periodic and np.abs(_poses(moved, Q) - _poses(robot, Q)).max() < 1e-12


def test_the_tool_frame_model_is_the_chain_with_the_tool_transform_given(bundled_robot):
    robot = apply_deviations(bundled_robot.with_target_offsets(OFFSETS),
                             random_deviations(bundled_robot.with_target_offsets(OFFSETS), 1e-4, 7))
    ref = bundled_robot.T_flange_tool_ref
    tool = flange_robot(robot, ref)
    assert tool.targets == () and np.all(tool.v() == 0.0)
    Q = robot.random_configurations(10, 8)
    _, p = ChainKinematics(tool).frame_poses(Q)
    want = np.array([(robot.T_meas_base() @ robot.T_base_flange(q) @ ref)[:3, 3] for q in Q])
    assert np.abs(p - want).max() < 1e-12
    # the targets sit on it where the model puts them (A 72 mm from the flange)
    T_tool_A = np.linalg.inv(tool.T_meas_tool(Q[0])) @ robot.T_meas_tool(Q[0], "A")
    assert abs(np.linalg.norm(T_tool_A[:3, 3]) - np.linalg.norm(OFFSETS["A"])) < 1e-3


def test_bad_arguments_are_named(bundled_robot):
    with pytest.raises(ParameterError, match="one tool frame, no targets"):
        with_nominal_last_link(bundled_robot, bundled_robot)
    robot = bundled_robot.with_target_offsets(OFFSETS)
    with pytest.raises(ParameterError, match="nominal: expected a model of the joints"):
        with_nominal_last_link(robot, _nominal("prismatic"))
    with pytest.raises(DataError, match=r"T_flange_tool_ref must be a finite numeric array of shape \(4, 4\)"):
        flange_robot(robot, np.eye(3))
