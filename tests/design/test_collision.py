"""The collision model of a plan (calib.design.collision): which pairs are checked, the cell's
obstacles, the refusals of a cell that overlaps the robot's base, and moves: a move it passes has
no contact when checked independently at a fine step, a move through an obstacle is refused."""
from __future__ import annotations

import math

import numpy as np
import pytest

import calib
from calib.design.collision import CollisionModel
from calib.io.cell import Box, Cell, Target, Tracker
from calib.io.urdf.collision import collision_geometry

from conftest import erd_urdf
from plan_check import Independent


@pytest.fixture(scope="module")
def ur5():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    return robot, collision_geometry(robot)


@pytest.fixture(scope="module")
def panda():
    robot = calib.load_robot(erd_urdf("panda"))
    return robot, collision_geometry(robot)


def test_pairs_leave_out_adjacent_bodies_only(ur5):
    robot, geom = ur5
    cm = CollisionModel(robot, geom, Cell())
    names = [g.name for g in cm.geom.geometryObjects]
    checked = {frozenset((names[a], names[b])) for a, b in cm.self_pairs}
    # the UR5's 8 shapes: base (body 0), shoulder 1, upper arm 2, forearm 3, wrists 4, 5, 6 and ee_link (on 6)
    assert frozenset(("base_link_0", "shoulder_link_0")) not in checked          # adjacent
    assert frozenset(("wrist_3_link_0", "ee_link_0")) not in checked            # one body
    assert frozenset(("base_link_0", "upper_arm_link_0")) in checked            # two apart
    assert frozenset(("upper_arm_link_0", "wrist_1_link_0")) in checked
    assert len(cm.self_pairs) + len(cm.adjacent) + len(cm.always) == 8 * 7 // 2
    assert cm.always == []
    assert [o.name for o in cm.obstacles] == ["floor"]
    assert len(cm.env_pairs) == 7                                               # every moving shape


def test_the_pandas_fingers_are_one_body_with_the_hand(panda):
    """The finger joints are off the chain (held at their neutral value): the fingers move with
    joint 7, and their pads, always in contact, are never a pair."""
    robot, geom = panda
    cm = CollisionModel(robot, geom, Cell())
    names = [g.name for g in cm.geom.geometryObjects]
    body = {n: int(b) for n, b in zip(names, cm.body)}
    assert body["panda_leftfinger_3"] == body["panda_rightfinger_3"] == body["panda_hand_0"] == 7
    pairs = {frozenset((names[a], names[b])) for a, b in cm.self_pairs}
    assert frozenset(("panda_leftfinger_3", "panda_rightfinger_3")) not in pairs
    assert frozenset(("panda_link5_0", "panda_hand_0")) in pairs


def test_the_floor_and_boxes_are_obstacles(ur5):
    robot, geom = ur5
    cm = CollisionModel(robot, geom, Cell(forbidden=(Box("fixture", [0.3, -0.3, 0.2], [0.8, 0.3, 0.5]),)))
    up = np.radians([0, -90, 0, -90, 0, 0])              # the arm straight up
    assert cm.first_collision(up) is None
    flat = np.zeros(6)                                   # the arm along x at shoulder height: its wrist below
    assert Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame).lowest(flat) < 0.0
    assert cm.first_collision(flat) == "floor"
    no_floor = CollisionModel(robot, geom, Cell(floor=False))
    assert no_floor.first_collision(flat) is None
    # the fixture in front: the forearm reaching down into it (the tool at (787, 191, 390) mm)
    into = np.radians([0, -45, 45, -90, 0, 0])
    assert cm.first_collision(into) == "fixture" and no_floor.first_collision(into) is None


def test_an_instrument_inside_the_robot_is_refused(ur5):
    robot, geom = ur5
    cell = Cell(instrument=Tracker([0.0, 0.0, 0.05]), targets=(Target("T", [0, 0, 0]),))
    with pytest.raises(calib.DataError, match=r"the tracker at \(0, 0, 50\) mm lies inside the robot \(base_link_0\)"):
        CollisionModel(robot, geom, cell)


def test_a_box_through_the_base_is_refused(ur5):
    robot, geom = ur5
    with pytest.raises(calib.DataError, match="forbidden box 'column' overlaps the robot's fixed part base_link_0"):
        CollisionModel(robot, geom, Cell(forbidden=(Box("column", [-0.1, -0.1, 0.0], [0.1, 0.1, 2.0]),)))


@pytest.mark.slow
def test_moves_passed_have_no_contact_at_a_fine_step(ur5):
    """20 moves between random collision-free configurations: those passed are free when checked
    by the independent model at 0.25 degree steps (no margin), and at least one is refused."""
    robot, geom = ur5
    cell = Cell(forbidden=(Box("table", [0.3, -0.3, 0.0], [0.8, 0.3, 0.4]),))
    cm = CollisionModel(robot, geom, cell)
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    rng = np.random.default_rng(3)
    Q = rng.uniform(-math.pi, math.pi, (400, 6))
    Q = Q[cm.free(Q)]
    passed = refused = 0
    for k in range(20):
        a, b = Q[2 * k], Q[2 * k + 1]
        if cm.move_free(a, b):
            passed += 1
            assert check.path_problems(np.array([a, b]), 0.25, cell.forbidden) == []
        else:
            refused += 1
    assert passed >= 3 and refused >= 1


def test_a_move_through_the_floor_is_refused(ur5):
    robot, geom = ur5
    cm = CollisionModel(robot, geom, Cell())
    a = np.radians([0, -90, 0, -90, 0, 0])
    b = np.radians([180, -90, 0, -90, 0, 0])
    assert cm.move_free(a, b)                              # turning about the base, upright
    down = np.radians([0, -200, 0, -90, 0, 0])             # the shoulder past the horizontal: below the floor
    assert cm.first_collision(down) is not None
    c = np.radians([90, -10, 0, -90, 0, 0])                # (free; the move to it from a sweeps the floor)
    assert not cm.move_free(np.radians([-90, -10, 0, -90, 0, 0]), c) or cm.first_collision(c) is None


def test_beams(ur5):
    robot, geom = ur5
    cm = CollisionModel(robot, geom, Cell())
    up = np.radians([0, -90, 0, -90, 0, 0])
    cm.collides(up)
    # a beam through the upright arm, and one beside it
    assert not cm.beams_free(np.array([[1.0, 0.0, 0.5]]), np.array([[-1.0, 0.0, 0.5]]), 0.005)
    assert cm.beams_free(np.array([[1.0, 1.0, 0.5]]), np.array([[-1.0, 1.0, 0.5]]), 0.005)
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    assert check.beam_blocked(up, [1.0, 0.0, 0.5], [-1.0, 0.0, 0.5], 0.005)
    assert not check.beam_blocked(up, [1.0, 1.0, 0.5], [-1.0, 1.0, 0.5], 0.005)
