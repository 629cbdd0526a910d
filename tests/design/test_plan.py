"""A measurement plan (calib.design.plan) on a UR5 with a tracker and a table, checked without
calib's own collision code (tests/plan_check.py): no collision at any pose nor along any move at
0.5 degree steps, nothing below the floor, every target in range, within its cone and in sight;
the predicted accuracy near the unconstrained selection's; the files it becomes read back.
The 50-pose plans of 10,000 candidates on a UR10, a Panda and the KR16 are
tests/scenarios/test_plan_acceptance.py and scripts/bench_plan.py."""
from __future__ import annotations

import math

import numpy as np
import pytest

import calib
from calib.design.plan import measurement_model, plan_measurements
from calib.io.cell import Box, Cell, Target, Tracker
from calib.model.kinematics import ChainKinematics

from conftest import erd_urdf
from plan_check import Independent

CELL = Cell(instrument=Tracker([2.0, 0.3, 0.7], range=(0.6, 20.0)),
            targets=(Target("SMR1", [0.0, 0.0, 0.05]),),
            forbidden=(Box("table", [0.3, -0.9, 0.0], [0.9, -0.4, 0.3]),),
            home=np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0]))


@pytest.fixture(scope="module")
def planned():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    plan = plan_measurements(robot, 20, CELL, candidates=2000, seed=0)
    check = Independent(erd_urdf("ur5"), robot.joint_names, robot.base_frame)
    return robot, plan, check


@pytest.mark.slow
def test_every_pose_and_move_is_free_when_checked_independently(planned):
    robot, plan, check = planned
    assert plan.n_poses == 20 and plan.path[0] == pytest.approx(CELL.home) and plan.path[-1] == pytest.approx(CELL.home)
    for q in plan.q:
        assert not check.collides(q)
        assert check.lowest(q) >= CELL.clearance - 1e-9          # the floor at the clearance
    assert check.path_problems(plan.path, 0.5, CELL.forbidden) == []
    lo, hi = robot.lower + CELL.joint_margin, robot.upper - CELL.joint_margin
    assert np.all(plan.path >= lo - 1e-9) and np.all(plan.path <= hi + 1e-9)


def test_every_target_is_in_range_within_its_cone_and_in_sight(planned):
    robot, plan, check = planned
    R, p = ChainKinematics(robot).frame_poses(plan.q)
    target = p + R @ CELL.targets[0].offset
    axis = R[:, :, 2]
    to = CELL.instrument.position - target
    dist = np.linalg.norm(to, axis=1)
    assert np.all((dist >= 0.6) & (dist <= 20.0))
    angle = np.degrees(np.arccos(np.einsum("ni,ni->n", axis, to) / dist))
    assert angle.max() <= 30.0
    for q, x, u, d in zip(plan.q, target, to / dist[:, None], dist):
        start = CELL.instrument.position - u * CELL.instrument.head / 2
        assert not check.beam_blocked(q, start, x + u * CELL.instrument.standoff, CELL.instrument.beam / 2)
    assert plan.visible.all()


def test_the_cells_prediction_is_near_the_unconstrained_selections(planned):
    _, plan, _ = planned
    a = plan.accuracy
    # over the configurations the cell allows, within the 5 % travel budget and the 10 % asked
    assert a["plan"]["cell"][0] <= 1.10 * a["unconstrained"]["cell"][0]
    assert plan.shortened["error"][1][1] <= 1.05 * plan.shortened["error"][0][1] + 1e-15
    assert plan.travel < plan.random_travel
    assert "predicted error, mm rms (cell)" in plan.format()


def test_the_prediction_is_the_covariance_propagated():
    """predicted_error: the error of a model identified from noise-free-plus-noise data at the
    plan's poses matches it (Monte Carlo, 200 draws of the noise, to 10 %)."""
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    model = measurement_model(robot, CELL)
    Q = model.random_configurations(30, 0)
    from calib.design.plan import predicted_error
    from calib.model.identifiability import weighted_jacobian
    from calib.model.identifiability_report import analyze_identifiability

    params = analyze_identifiability(model, Q, measure="position").identifiable
    Qe = model.random_configurations(50, 1)
    pos, rot = predicted_error(model, Q, params, "position", 2e-5, 2e-3, Qe)
    assert rot is None
    cols = model.indices(params)
    J = weighted_jacobian(model, Q, "position", 2e-5, 2e-3)[:, cols]
    rng = np.random.default_rng(0)
    from calib.model.jacobian import pose_jacobian

    Je = pose_jacobian(ChainKinematics(model), Qe, cols)[2][:, :3]
    errs = []
    for _ in range(200):
        dx = np.linalg.lstsq(J, rng.normal(size=len(J)), rcond=None)[0]      # the estimate's error
        errs.append(np.mean(np.sum((Je @ dx) ** 2, axis=1)))
    assert math.sqrt(np.mean(errs)) == pytest.approx(pos, rel=0.1)


def test_a_cell_leaving_too_few_poses_is_refused_naming_why():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    cell = Cell(workspace=Box("workspace", [0.0, 0.0, 2.0], [0.1, 0.1, 2.1]))     # above the reach
    with pytest.raises(calib.DataError, match=r"the cell leaves 0 feasible poses of 300 candidates, fewer than the "
                                              r"10 asked \(refused: 300 workspace\)"):
        plan_measurements(robot, 10, cell, candidates=300)


def test_options_are_checked():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    with pytest.raises(calib.ParameterError, match="measure must be"):
        plan_measurements(robot, 10, None, candidates=300, measure="angle")
    with pytest.raises(calib.ParameterError, match="cell must be"):
        plan_measurements(robot, 10, "cell.yaml")
    with pytest.raises(calib.ParameterError, match="touch features"):
        from calib.io.cell import Nest

        plan_measurements(robot, 10, Cell(features=(Nest("N", [0.5, 0, 0.2]),)))
    from dataclasses import replace

    with pytest.raises(calib.ParameterError, match="a plan needs a robot loaded from a URDF"):
        plan_measurements(replace(robot, source=None), 10)


@pytest.mark.slow
def test_a_camera_sees_every_target_in_its_field_of_view():
    from calib.io.cell import Camera

    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    cam = Camera([1.8, 0.0, 0.6], look_at=[0.3, 0.0, 0.4], fov=(math.radians(50), math.radians(40)), range=(0.5, 4.0))
    cell = Cell(instrument=cam, targets=(Target("M", [0.0, 0.0, 0.03], cone=math.radians(40)),))
    plan = plan_measurements(robot, 12, cell, candidates=1500, seed=1)
    R, p = ChainKinematics(robot).frame_poses(plan.q)
    x = p + R @ cell.targets[0].offset
    z = cam.look_at - cam.position
    z /= np.linalg.norm(z)
    xc = np.cross(-cam.up, z)
    xc /= np.linalg.norm(xc)
    yc = np.cross(z, xc)
    v = x - cam.position
    depth = v @ z
    assert np.all(depth > 0)
    assert np.all(np.abs(v @ xc) <= np.tan(math.radians(25)) * depth + 1e-9)
    assert np.all(np.abs(v @ yc) <= np.tan(math.radians(20)) * depth + 1e-9)
    assert plan.feasibility.rejected.get("out of view", 0) > 0


@pytest.mark.slow
def test_several_targets_each_pose_measures_those_it_sees():
    """Two SMRs facing different ways: every pose sees at least one; the prediction counts the
    rows of those it sees only (a pose seeing both informs more than one seeing one)."""
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    cell = Cell(instrument=Tracker([2.0, 0.3, 0.7], range=(0.6, 20.0)),
                targets=(Target("A", [0.0, 0.0, 0.05], axis=[0, 0, 1]), Target("B", [0.05, 0.0, 0.0], axis=[1, 0, 0])))
    plan = plan_measurements(robot, 12, cell, candidates=1500, seed=2)
    assert plan.robot.targets == ("A", "B")
    assert plan.visible.shape == (12, 2) and plan.visible.any(axis=1).all()
    R, p = ChainKinematics(robot).frame_poses(plan.q)
    for k, t in enumerate(cell.targets):
        x = p + R @ t.offset
        a = R @ t.axis
        to = cell.instrument.position - x
        cos = np.einsum("ni,ni->n", a, to) / np.linalg.norm(to, axis=1)
        assert np.all(cos[plan.visible[:, k]] >= math.cos(t.cone) - 1e-12)
    from calib.design.plan import predicted_error

    params = plan.design.parameters
    Qe = plan.robot.random_configurations(40, 0)
    both = predicted_error(plan.robot, plan.q, params, "position", 2e-5, 2e-3, Qe, np.ones((12, 2), bool))[0]
    seen = predicted_error(plan.robot, plan.q, params, "position", 2e-5, 2e-3, Qe, plan.visible)[0]
    assert seen >= both


def test_selection_over_a_pool_with_every_target_seen_is_the_plain_one():
    """design_from_pool with every target visible selects as design_poses does over the same
    pool; a target hidden in every pose makes its rows count for nothing."""
    from calib.design.poses import design_from_pool

    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0").with_target_offsets(
        {"A": [0, 0, 0.05], "B": [0.05, 0, 0]})
    pool = robot.random_configurations(300, 0)
    a = design_from_pool(robot, 10, pool, measure="position", seed=0)
    b = design_from_pool(robot, 10, pool, visible=np.ones((300, 2), bool), measure="position", seed=0)
    np.testing.assert_array_equal(a.indices, b.indices)
    only_a = np.column_stack([np.ones(300, bool), np.zeros(300, bool)])
    c = design_from_pool(robot, 10, pool, visible=only_a, measure="position", seed=0)
    assert c.criteria["D"] < a.criteria["D"]
    with pytest.raises(calib.ParameterError, match="every candidate must measure at least one target"):
        design_from_pool(robot, 10, pool, visible=np.zeros((300, 2), bool), measure="position")


@pytest.mark.slow
def test_the_same_seed_gives_the_same_plan():
    robot = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    a, b = (plan_measurements(robot, 10, CELL, candidates=400, seed=5) for _ in range(2))
    np.testing.assert_array_equal(a.path, b.path)
    assert a.path_names == b.path_names
    c = plan_measurements(robot, 10, CELL, candidates=400, seed=6)
    assert c.path.shape != a.path.shape or not np.array_equal(c.path, a.path)
