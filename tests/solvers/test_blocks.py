"""Residual blocks (:mod:`calib.solvers.residuals`: measured rows; points, planes, spheres
touched) and the problem that assembles them (:class:`calib.solvers.blocks.BlockProblem`): the
residuals against the exact model row by row (robot.T_meas_tool, a direct product of the MDH
matrices; a plane's normal by rotation matrices), the Jacobian against finite differences of it,
each group's share of the normal equations, the measured rows equal to
:class:`calib.solvers.problem.Problem`'s, row masks, and the robust loss; on UR10 and Panda from
example-robot-data."""
from __future__ import annotations

import numpy as np
import pytest

from calib import load_robot
from calib.model.kinematics import ChainKinematics
from calib.model.spatial import elementary
from calib.model.touch import Feature, TouchData, frame_with_normal
from calib.solvers.blocks import BlockProblem
from calib.solvers.residuals.pose import MeasuredRows
from calib.solvers.residuals.touch import TouchRows

from conftest import erd_urdf

ROBOTS = [("ur10", "tool0"), ("panda", None)]


def _touch_data(robot, rng, probe_radius=0.004):
    features = (Feature("point", "P1"), Feature("plane", "A"), Feature("sphere", "S", radius=0.12),
                Feature("point", "P2"), Feature("plane", "B"))
    feature = np.array([0, 1, 2, 3, 4] * 4)
    rng.shuffle(feature)
    return TouchData(robot.random_configurations(len(feature), rng), feature, features, probe_radius)


def _exact_touch(robot, data, plane_refs, values, x_features):
    """Touch residuals from the reference kinematics, row by row (no vectorisation, no
    Pinocchio), in the block's order: point rows' 3 components, plane rows', sphere rows'."""
    model = robot.with_values(values)
    F = x_features.reshape(-1, 3)
    pts, scal = [], []
    for q, k in zip(data.q, data.feature):
        p = model.T_meas_tool(q)[:3, 3]
        f = data.features[k]
        if f.kind == "point":
            pts.append(p - F[k])
        elif f.kind == "plane":
            a, b, d = F[k]
            R = plane_refs[k] @ elementary("rx", a)[:3, :3] @ elementary("ry", b)[:3, :3]
            scal.append((f.kind, R[:, 2] @ p - d - data.probe_radius))
        else:
            scal.append((f.kind, np.linalg.norm(p - F[k]) - f.radius))
    order = [s for kind in ("plane", "sphere") for (kk, s) in scal if kk == kind]
    return np.concatenate([np.ravel(pts), order])


def _case(name, tool, seed, measured=True):
    import pinocchio as pin

    robot = load_robot(erd_urdf(name), tool_frame=tool)
    rng = np.random.default_rng(seed)
    # linearised away from the nominal values (no term vanishes by symmetry)
    robot = robot.with_values(robot.values + rng.normal(0.0, 0.01, robot.n_params))
    data = _touch_data(robot, rng)
    K = len(data.features)
    refs = np.array([frame_with_normal(rng.normal(size=3)) for _ in range(K)])
    xf = rng.normal(0.0, 0.3, 3 * K)
    Qm = robot.random_configurations(5, rng)
    Rm = np.array([pin.exp3(rng.normal(size=3)) for _ in Qm])
    pm = rng.normal(0.0, 0.5, (5, 3))
    blocks = ([MeasuredRows(Qm, pm, Rm, rows=np.arange(100, 105))] if measured else []) + [TouchRows(data, refs)]
    prob = BlockProblem(ChainKinematics(robot), robot.values, np.arange(robot.n_params), blocks,
                        5e-5, 1e-4, 2e-5)

    def exact(v, f):
        model = robot.with_values(v)
        T = [model.T_meas_tool(q) for q in Qm]
        dp = [t[:3, 3] - p for t, p in zip(T, pm)]
        dr = [pin.log3(t[:3, :3] @ R.T) for t, R in zip(T, Rm)]
        touch = _exact_touch(robot, data, refs, v, f)
        return np.concatenate([np.ravel(dp), np.ravel(dr), touch]) if measured else touch

    return robot, data, prob, np.concatenate([robot.values, xf]), exact


@pytest.mark.parametrize("name,tool", ROBOTS)
def test_blocks_jacobian_matches_finite_differences(name, tool):
    """Measured rows (position and orientation) and touch rows in one problem: the residuals of
    the exact model, their Jacobian by central differences, the features' columns zero on the
    measured rows, each group weighted by its own noise and its share of the normal equations."""
    robot, data, prob, x, exact = _case(name, tool, 8)
    n = robot.n_params
    r, J = prob.evaluate(x)
    assert prob.groups == ("position", "rotation", "touch") and prob.n_poses == 5 + 20
    assert J.shape == (30 + data.n_residuals, n + 15) == (30 + 3 * 8 + 12, n + 15)
    np.testing.assert_allclose(r, exact(robot.values, x[n:]), atol=1e-12)
    h = 1e-6
    fd = np.empty_like(J)
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h
        fd[:, j] = (exact(prob.full(x + e), (x + e)[n:]) - exact(prob.full(x - e), (x - e)[n:])) / (2 * h)
    # relative to each column (columns without effect, e.g. a tool twist about the tool point:
    # relative to the largest column)
    scale = np.maximum(np.abs(fd).max(axis=0), 1e-9 * np.abs(fd).max())
    err = np.abs(J - fd).max(axis=0) / scale
    assert err.max() <= 1e-6, dict(zip(robot.names + tuple(f"f{k}" for k in range(15)), err))
    assert not J[:30, n:].any()
    w = np.concatenate([np.full(15, 1 / 5e-5), np.full(15, 1 / 1e-4), np.full(data.n_residuals, 1 / 2e-5)])
    ne = prob.normal_equations(x)
    Jw, rw = J * w[:, None], r * w
    tol = 1e-13 * np.abs(Jw.T @ Jw).max()       # (entries near zero: to rounding of the largest)
    np.testing.assert_allclose(ne.A, Jw.T @ Jw, rtol=1e-12, atol=tol)
    np.testing.assert_allclose(ne.g, Jw.T @ rw, rtol=1e-12, atol=1e-13 * np.abs(Jw.T @ rw).max())
    for g, sl in (("position", slice(0, 15)), ("rotation", slice(15, 30)), ("touch", slice(30, None))):
        A_g, rss, n_g = ne.share(g)
        np.testing.assert_allclose(A_g, Jw[sl].T @ Jw[sl], rtol=1e-12, atol=tol)
        assert n_g == len(rw[sl]) and abs(rss - rw[sl] @ rw[sl]) <= 1e-12 * rss
    assert abs(ne.cost - 0.5 * rw @ rw) <= 1e-12 * ne.cost
    np.testing.assert_allclose(prob.residuals(x), rw, rtol=1e-12)


def test_measured_rows_are_those_of_problem():
    """The measured-rows block is the pose rows of :class:`Problem`: the same normal equations,
    cost and position / rotation shares on the same rows (to rounding)."""
    from calib.solvers.problem import Problem

    robot, _, _, _, _ = _case("ur10", "tool0", 3)
    rng = np.random.default_rng(3)
    import pinocchio as pin

    Q = robot.random_configurations(12, rng)
    p = rng.normal(0.0, 0.5, (12, 3))
    R = np.array([pin.exp3(rng.normal(size=3)) for _ in Q])
    free = np.arange(0, robot.n_params, 2)
    pr = Problem(ChainKinematics(robot), Q, p, R, robot.values, free, 5e-5, 1e-4)
    bp = BlockProblem(ChainKinematics(robot), robot.values, free, [MeasuredRows(Q, p, R)], 5e-5, 1e-4, 2e-5)
    x = robot.values[free] + rng.normal(0.0, 1e-3, len(free))
    a, b = pr.normal_equations(x), bp.normal_equations(x)
    for f in ("A", "g", "A_pos", "A_rot", "g_pos"):
        np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-10, atol=1e-10 * np.abs(getattr(a, f)).max())
    assert (b.n_pos, b.n_rot, b.n_touch) == (a.n_pos, a.n_rot, 0)
    assert abs(b.cost - a.cost) <= 1e-12 * a.cost
    dp_a, dr_a = pr.pose_residuals(x)
    dp_b, dr_b = bp.pose_residuals(x)
    np.testing.assert_allclose(dp_b, dp_a, atol=1e-15)
    np.testing.assert_allclose(dr_b, dr_a, atol=1e-15)
    huber_a = pr.derived(loss="huber").normal_equations(x)
    huber_b = bp.derived(loss="huber").normal_equations(x)
    np.testing.assert_allclose(huber_b.A, huber_a.A, rtol=1e-10, atol=1e-10 * np.abs(huber_a.A).max())
    assert abs(huber_b.cost - huber_a.cost) <= 1e-10 * huber_a.cost
    np.testing.assert_allclose(bp.derived(loss="huber").residuals(x) @ bp.derived(loss="huber").residuals(x),
                               2 * huber_a.cost, rtol=1e-10)


def test_rows_masks_strata_and_row_figures():
    """A row mask cuts each block (the features' columns stay); each row's whitened RMS, its
    error and its stratum; the blocks of rows by number of components cover every component."""
    robot, data, prob, x, _ = _case("panda", None, 5)
    n = robot.n_params
    keep = np.ones(prob.n_poses, bool)
    keep[[1, 7, 12]] = False
    sub = prob.derived(keep=keep)
    assert sub.n_poses == 22 and sub.n_free == prob.n_free
    np.testing.assert_array_equal(sub.rows, prob.rows[keep])
    r_all = prob.evaluate(x, jacobian=False)[0]
    mine = keep[prob.component_row]
    np.testing.assert_allclose(np.sort(sub.evaluate(x, jacobian=False)[0]), np.sort(r_all[mine]), atol=0)
    strata = prob.strata()
    assert (strata[:5] == 0).all() and set(strata[5:].tolist()) == {1, 2, 3, 4, 5}
    levels = (5e-5, 1e-4, 2e-5)
    rms = prob.row_rms(x, levels)
    w = r_all / np.asarray(levels)[prob.component_group]
    for row in (0, 5, 9, 24):
        c = prob.component_row == row
        assert abs(rms[row] - np.sqrt(np.mean(w[c] ** 2))) <= 1e-12 * rms[row]
    pos, rot = prob.row_errors(x)
    assert np.isnan(rot[5:]).all() and np.isfinite(rot[:5]).all()
    kind = np.array([f.kind for f in data.features])[data.feature]
    touch = r_all[30:]
    plane_rows = np.flatnonzero(kind == "plane")
    np.testing.assert_allclose(pos[5 + plane_rows], np.abs(touch[3 * np.sum(kind == "point"):][:len(plane_rows)]),
                               rtol=1e-12)
    seen = 0
    for rows, r, Jw, groups in prob.row_blocks(x):
        assert r.shape[:2] == Jw.shape[:2] == groups.shape and Jw.shape[2] == n + 15
        seen += r.size
        if r.shape[1] == 6:
            assert (groups == [0, 0, 0, 1, 1, 1]).all() and (rows < 5).all()
    assert seen == prob.n_residuals
