"""Touch residuals (points, planes, spheres) and their Jacobian: finite differences of the exact
model (robot.T_meas_tool, a direct product of the MDH matrices; the plane normal by rotation
matrices), on UR10 and Panda from example-robot-data."""
from __future__ import annotations

import numpy as np
import pytest

from calib import load_robot
from calib.model.kinematics import ChainKinematics
from calib.model.spatial import elementary
from calib.model.touch import Feature, TouchData, frame_with_normal
from calib.solvers.touch_problem import TouchProblem

from conftest import erd_urdf

ROBOTS = [("ur10", "tool0"), ("panda", None)]


def _mixed_data(robot, rng, probe_radius=0.004):
    features = (Feature("point", "P1"), Feature("plane", "A"), Feature("sphere", "S", radius=0.12),
                Feature("point", "P2"), Feature("plane", "B"))
    feature = np.array([0, 1, 2, 3, 4] * 4)
    rng.shuffle(feature)
    return TouchData(robot.random_configurations(len(feature), rng), feature, features, probe_radius)


def _exact_residuals(robot, data, plane_refs, values, x_features):
    """Residuals from the reference kinematics, row by row (no vectorisation, no Pinocchio)."""
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


@pytest.mark.parametrize("name,tool", ROBOTS)
def test_touch_jacobian_matches_finite_differences(name, tool):
    robot = load_robot(erd_urdf(name), tool_frame=tool)
    rng = np.random.default_rng(7)
    # linearise away from the nominal values (no term vanishes by symmetry)
    robot = robot.with_values(robot.values + rng.normal(0.0, 0.01, robot.n_params))
    data = _mixed_data(robot, rng)
    K = len(data.features)
    refs = np.array([frame_with_normal(rng.normal(size=3)) for _ in range(K)])
    xf = rng.normal(0.0, 0.3, 3 * K)
    free = np.arange(robot.n_params)
    prob = TouchProblem(ChainKinematics(robot), data, robot.values, free, refs, sigma=2e-5)
    x = prob.x0(xf)
    r, J = prob.evaluate(x)
    assert J.shape == (data.n_residuals, robot.n_params + 3 * K) == (3 * 8 + 12, robot.n_params + 15)
    np.testing.assert_allclose(r, _exact_residuals(robot, data, refs, robot.values, xf), atol=1e-12)
    h = 1e-6
    fd = np.empty_like(J)
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h
        rp = _exact_residuals(robot, data, refs, prob.full(x + e), (x + e)[robot.n_params:])
        rm = _exact_residuals(robot, data, refs, prob.full(x - e), (x - e)[robot.n_params:])
        fd[:, j] = (rp - rm) / (2 * h)
    # relative to each column (columns without effect, e.g. a tool twist about the tool point:
    # relative to the largest column)
    scale = np.maximum(np.abs(fd).max(axis=0), 1e-9 * np.abs(fd).max())
    err = np.abs(J - fd).max(axis=0) / scale
    assert err.max() <= 1e-6, dict(zip(robot.names + tuple(f"f{k}" for k in range(3 * K)), err))
    # the weighted normal equations are those of the stacked Jacobian
    ne = prob.normal_equations(x)
    A = J.T @ J / 2e-5 ** 2     # (entries near zero: to rounding of the largest)
    np.testing.assert_allclose(ne.A, A, rtol=1e-12, atol=1e-13 * np.abs(A).max())
    np.testing.assert_allclose(ne.g, J.T @ r / 2e-5 ** 2, rtol=1e-12, atol=1e-13 * np.abs(J.T @ r).max() / 2e-5 ** 2)
    np.testing.assert_allclose(prob.residuals(x), r / 2e-5, rtol=1e-12)


@pytest.mark.parametrize("name,tool", ROBOTS)
def test_mixed_rows_jacobian_matches_finite_differences(name, tool):
    """Touch rows with rows measured by an instrument (position and orientation): their pose
    residuals follow the touch rows', the features do not enter them, each group is weighted by
    its own noise."""
    from dataclasses import replace

    import pinocchio as pin

    from calib import Measurements

    robot = load_robot(erd_urdf(name), tool_frame=tool)
    rng = np.random.default_rng(8)
    robot = robot.with_values(robot.values + rng.normal(0.0, 0.01, robot.n_params))
    Qm = robot.random_configurations(5, rng)
    Rm = np.array([pin.exp3(rng.normal(size=3)) for _ in Qm])
    meas = Measurements(Qm, rng.normal(0.0, 0.5, (5, 3)), Rm)
    data = replace(_mixed_data(robot, rng), measured=meas)
    K = len(data.features)
    refs = np.array([frame_with_normal(rng.normal(size=3)) for _ in range(K)])
    xf = rng.normal(0.0, 0.3, 3 * K)
    prob = TouchProblem(ChainKinematics(robot), data, robot.values, np.arange(robot.n_params), refs,
                        sigma=2e-5, sigma_pos=5e-5, sigma_rot=1e-4)
    assert list(prob.slices) == ["touch", "position", "rotation"]
    x = prob.x0(xf)
    r, J = prob.evaluate(x)
    assert J.shape == (data.n_residuals + 30, robot.n_params + 3 * K)

    def exact(v, f):
        model = robot.with_values(v)
        T = [model.T_meas_tool(q) for q in Qm]
        dp = [t[:3, 3] - p for t, p in zip(T, meas.position)]
        dr = [pin.log3(t[:3, :3] @ R.T) for t, R in zip(T, Rm)]
        return np.concatenate([_exact_residuals(robot, data, refs, v, f), np.ravel(dp), np.ravel(dr)])

    np.testing.assert_allclose(r, exact(robot.values, xf), atol=1e-12)
    h = 1e-6
    fd = np.empty_like(J)
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h
        fd[:, j] = (exact(prob.full(x + e), (x + e)[robot.n_params:])
                    - exact(prob.full(x - e), (x - e)[robot.n_params:])) / (2 * h)
    scale = np.maximum(np.abs(fd).max(axis=0), 1e-9 * np.abs(fd).max())
    err = np.abs(J - fd).max(axis=0) / scale
    assert err.max() <= 1e-6, dict(zip(robot.names + tuple(f"f{k}" for k in range(3 * K)), err))
    # the features do not move the measured rows
    assert not J[data.n_residuals:, robot.n_params:].any()
    # each group weighted by its noise; the shares add up to the normal equations
    w = np.concatenate([np.full(data.n_residuals, 1 / 2e-5), np.full(15, 1 / 5e-5), np.full(15, 1 / 1e-4)])
    ne = prob.normal_equations(x)
    A, g = (J * w[:, None]).T @ (J * w[:, None]), (J * w[:, None]).T @ (r * w)
    tol = 1e-13 * np.abs(A).max()       # (entries near zero: to rounding of the largest)
    np.testing.assert_allclose(ne.A, A, rtol=1e-12, atol=tol)
    np.testing.assert_allclose(ne.g, g, rtol=1e-12, atol=1e-13 * np.abs(g).max())
    shares = prob.group_shares(x)
    np.testing.assert_allclose(sum(a for a, _, _ in shares.values()), ne.A, rtol=1e-12, atol=tol)
    assert [n for _, _, n in shares.values()] == [data.n_residuals, 15, 15]
    np.testing.assert_allclose(sum(s for _, s, _ in shares.values()), np.sum((r * w) ** 2), rtol=1e-12)
