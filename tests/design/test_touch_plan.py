"""Touch plans (calib.design.touch_plan): the TCP case, one nest touched 8 times within a 30
degree cone, reachable, free of collisions (checked independently), and calibrating in
simulation to the accuracy the plan predicts; an unreachable nest is one line. Three faces of a
cube: tests/scenarios/test_plan_acceptance.py."""
from __future__ import annotations

import math

import numpy as np
import pytest

import calib
from calib.design.touch_plan import plan_touch, probe_model
from calib.io.cell import Cell, Nest
from calib.model.kinematics import ChainKinematics

from conftest import erd_urdf
from plan_check import Independent, touch_errors

NEST = Cell(features=(Nest("N1", [0.5, 0.2, 0.25], normal=[0, 0, 1], cone=math.radians(30), poses=8),),
            tip=np.array([0.0, 0.0, 0.15]), home=np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0]))


@pytest.fixture(scope="module")
def tcp():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    return robot, plan_touch(robot, NEST, seed=0)


@pytest.mark.slow
def test_the_nest_is_touched_from_eight_orientations_within_the_cone(tcp):
    robot, plan = tcp
    model = probe_model(robot, NEST)
    R, p = ChainKinematics(model).frame_poses(plan.data.q)
    assert plan.data.n_rows == 8 and plan.params == "tool" and plan.free == ("v_x", "v_y", "v_z")
    np.testing.assert_allclose(p, np.tile(NEST.features[0].position, (8, 1)), atol=1e-8)
    tilt = np.degrees(np.arccos(-R[:, 2, 2]))              # the tool's z against -normal
    assert tilt.max() <= 30.0 + 1e-6
    # spread: the D-optimal rows lean the tool out to the cone, round about the normal
    assert tilt.min() > 15.0
    azimuth = np.degrees(np.arctan2(R[:, 1, 2], R[:, 0, 2]))
    assert np.ptp(np.sort(azimuth)) > 180.0


def test_the_touches_and_moves_are_free_when_checked_independently(tcp):
    robot, plan = tcp
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    for q in plan.data.q:
        assert not check.collides(q) and check.lowest(q) >= NEST.clearance - 1e-9
    assert check.path_problems(plan.path, 0.5) == []


def test_the_tcp_calibrates_to_the_accuracy_predicted(tcp):
    """12 simulated runs (the tool offset 2 mm off per axis, 0.02 mm touch noise): the RMS error
    of the calibrated offset lies within [0.6, 1.5] of the prediction (the spread of a 12-run RMS
    of a 3-degree-of-freedom error is about 12 %)."""
    robot, plan = tcp
    errors = touch_errors(plan, probe_model(robot, NEST), range(12))
    ratio = math.sqrt(np.mean(errors ** 2)) / plan.predicted
    assert 0.6 <= ratio <= 1.5, (errors, plan.predicted)
    assert 5e-6 < plan.predicted < 1e-4


def test_an_unreachable_nest_is_one_line():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    far = Cell(features=(Nest("far", [3.0, 0.0, 0.2]),), tip=np.array([0.0, 0.0, 0.15]))
    with pytest.raises(calib.DataError, match=r"nest 'far' at \(3000, 0, 200\) mm is unreachable") as info:
        plan_touch(robot, far, candidates=50)
    assert "\n" not in str(info.value)


def test_planes_alone_need_auto():
    from calib.io.cell import PlaneRegion

    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    cell = Cell(features=(PlaneRegion("top", [0.5, 0.0, 0.3]),))
    with pytest.raises(calib.ParameterError, match="needs a nest"):
        plan_touch(robot, cell, params="tool")
