"""The order and moves of a plan (calib.design.tour): the travel metric, turning the short way,
orders that a brute force confirms, and waypoints round an obstacle."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import calib
from calib.design.collision import CollisionModel
from calib.design.tour import Travel, connect, move_times, order_poses, path_travel, random_travel, route, unwrapped
from calib.design.tour import _length
from calib.io.cell import Box, Cell
from calib.io.urdf.collision import collision_geometry

from conftest import erd_urdf
from plan_check import Independent


def travel(n=3, wrap=True, lim=2 * math.pi):
    return Travel(np.arange(1, n + 1, dtype=float), np.full(n, wrap), np.full(n, -lim), np.full(n, lim))


def test_a_move_takes_the_slowest_joints_time():
    t = travel()
    # joint speeds 1, 2, 3 rad/s: a move of (1, 1, 1) rad takes 1 s, one of (0, 3, 0) 1.5 s
    assert t.times(np.zeros(3), np.ones(3)) == pytest.approx(1.0)
    assert t.times(np.zeros(3), np.array([0.0, 3.0, 0.0])) == pytest.approx(1.5)
    # 350 degrees one way is 10 degrees the other
    assert t.times(np.zeros(3), np.radians([350.0, 0, 0])) == pytest.approx(math.radians(10))
    assert not travel(wrap=False).wrap.any()
    assert travel(wrap=False).times(np.zeros(3), np.radians([350.0, 0, 0])) == pytest.approx(math.radians(350))


def test_unwrapping_turns_each_joint_the_least_within_its_limits():
    t = travel(1, lim=2 * math.pi)
    path = np.radians([[170.0], [-170.0], [170.0], [-170.0]])
    out = unwrapped(t, path)
    np.testing.assert_allclose(np.abs(np.diff(out[:, 0])), math.radians(20), atol=1e-12)
    assert np.all(np.abs(out) <= 2 * math.pi + 1e-12)
    # a joint of +-pi cannot wrap: the long way
    t1 = travel(1, wrap=False, lim=math.pi)
    np.testing.assert_allclose(unwrapped(t1, path), path)
    # a home kept as given
    fixed = unwrapped(t, np.radians([[350.0], [-10.0]]), fixed_first=True)
    assert fixed[0, 0] == pytest.approx(math.radians(350)) and fixed[1, 0] == pytest.approx(math.radians(350))


@pytest.mark.parametrize("home", [False, True])
def test_the_order_is_the_shortest_for_a_few_poses(home):
    """Seven random poses: the order found equals the best of all orders (brute force)."""
    rng = np.random.default_rng(4)
    t = travel()
    Q = rng.uniform(-3, 3, (7, 3))
    D = move_times(t, Q)
    order = order_poses(D, home=home)
    rest = range(1, 7) if home else range(7)
    best = min(_length(([0] if home else []) + list(p), D, home) for p in itertools.permutations(rest))
    assert _length(order, D, home) == pytest.approx(best)
    assert sorted(order) == list(range(7)) and (order[0] == 0 if home else True)


def test_points_on_a_line_are_visited_in_line():
    t = travel(1, wrap=False, lim=10)
    x = np.random.default_rng(0).permutation(np.linspace(-5, 5, 40))[:, None]
    order = order_poses(move_times(t, x))
    assert path_travel(t, x[order]) == pytest.approx(10.0)
    assert random_travel(t, x, np.random.default_rng(1)) > 5 * 10.0


@pytest.fixture(scope="module")
def ur5_wall():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    cell = Cell(forbidden=(Box("wall", [0.35, -0.05, 0.0], [0.45, 0.05, 0.55]),))
    cm = CollisionModel(robot, collision_geometry(robot), cell)
    rng = np.random.default_rng(0)
    pool = rng.uniform(-math.pi, math.pi, (1500, 6))
    return robot, cell, cm, pool[cm.free(pool)]


def test_a_blocked_move_gets_waypoints_round_the_wall(ur5_wall):
    """The tool in front of the wall's two sides at waist height: the straight move between
    them sweeps through the wall; the waypoints found go round it (checked independently)."""
    robot, cell, cm, pool = ur5_wall
    a = np.radians([-25.0, -60.0, 100.0, -130.0, -90.0, 0.0])
    b = np.radians([25.0, -60.0, 100.0, -130.0, -90.0, 0.0])
    assert cm.first_collision(a) is None and cm.first_collision(b) is None
    assert not cm.move_free(a, b)
    t = Travel(np.full(6, 3.0), np.ones(6, bool), robot.lower, robot.upper)
    vias = connect(cm, t, a, b, pool)
    assert vias is not None and 1 <= len(vias) <= 3
    path = np.vstack([a, *vias, b])
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    assert check.path_problems(path, 0.5, cell.forbidden) == []


def test_route_names_poses_and_waypoints(ur5_wall):
    robot, cell, cm, pool = ur5_wall
    t = Travel(np.full(6, 3.0), np.ones(6, bool), robot.lower, robot.upper)
    Q = np.radians([[-25.0, -60.0, 100.0, -130.0, -90.0, 0.0], [25.0, -60.0, 100.0, -130.0, -90.0, 0.0],
                    [0.0, -90.0, 0.0, -90.0, 0.0, 0.0]])
    home = np.radians([90.0, -90.0, 0.0, -90.0, 0.0, 0.0])
    path, names, measured, order = route(cm, t, Q, home, pool)
    assert names[0] == "home" and names[-1] == "home_end" and not measured[0] and not measured[-1]
    assert [n for n, m in zip(names, measured) if m] == ["P01", "P02", "P03"]
    assert all(n.startswith("P0") and "_via" in n for n, m in zip(names, measured) if not m and "home" not in n)
    assert sorted(order) == [0, 1, 2]
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    assert check.path_problems(path, 0.5, cell.forbidden) == []
    for k, i in enumerate(order):
        np.testing.assert_allclose(t.delta(path[measured][k], Q[i]), 0.0, atol=1e-12)
