"""The identification Jacobian: finite differences of the exact model, and the paper's Tables 1-2."""
from __future__ import annotations

import numpy as np
import pytest

from calib import identification_jacobian, load_robot
from calib.model.factors import _Factor
from calib.model.kinematics import _FactorTable


def _product_and_twists(factors, values, n_params):
    """One placement's product (4x4) and local twists (6, n_params) from the factor table."""
    M, _, tw = _FactorTable([factors], n_params).products(values)
    return M[0], tw
from calib.model.mdh import link_transform
from calib.model.spatial import inverse, skew, zyx_transform

from conftest import BUNDLED_URDF, erd_urdf, fd_pose_column


def _fd_jacobian(robot, Q, h=1e-6):
    """Central differences of the exact forward model (Eq. 1 products, no Pinocchio)."""
    return np.array([fd_pose_column(robot, Q, k, h).reshape(-1) for k in range(robot.n_params)]).T


@pytest.mark.parametrize("name,tool", [("bundled", None), ("ur5", "tool0"), ("panda", None),
                                       ("kinova", None)])
def test_jacobian_matches_finite_differences(name, tool):
    path = BUNDLED_URDF if name == "bundled" else erd_urdf(name)
    robot = load_robot(path, tool_frame=tool)
    rng = np.random.default_rng(1)
    # linearise away from the nominal values, so no term vanishes by symmetry
    robot = robot.with_values(robot.values + rng.normal(0.0, 0.02, robot.n_params))
    Q = robot.random_configurations(15, rng)
    J = identification_jacobian(robot, Q)
    fd = _fd_jacobian(robot, Q)
    assert J.shape == (6 * 15, robot.n_params)
    rel = np.abs(J - fd).max(axis=0) / np.maximum(np.abs(fd).max(axis=0), 1e-300)
    assert rel.max() <= 1e-6, dict(zip(robot.names, rel))
    Jp = identification_jacobian(robot, Q, measure="position")
    np.testing.assert_array_equal(Jp, J.reshape(15, 6, -1)[:, :3].reshape(-1, robot.n_params))


def _differential(T, xi):
    """The paper's differential matrix dT . T^-1 of a local twist xi (T^-1 dT = xi^)."""
    X = np.zeros((4, 4))
    X[:3, :3] = skew(xi[3:])
    X[:3, 3] = xi[:3]
    return T @ X @ inverse(T)


def test_table1_link_derivatives():
    rng = np.random.default_rng(2)
    names = ["theta", "d", "a", "alpha", "beta"]
    factors = [_Factor(k, i) for i, k in enumerate(["rz", "tz", "tx", "rx", "ry"])]
    for _ in range(20):
        th, d, a, al = rng.uniform(-3, 3), rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-3, 3)
        vals = np.array([th, d, a, al, 0.0])  # Table 1 is evaluated at nominal beta = 0
        T, tw = _product_and_twists(factors, vals, 5)
        np.testing.assert_allclose(T, link_transform(th, d, a, al, 0.0), atol=1e-14)
        c, s, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
        table1 = {
            "theta": [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]],
            "d": [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]],
            "a": [[0, 0, 0, c], [0, 0, 0, s], [0, 0, 0, 0]],
            "alpha": [[0, 0, s, -d * s], [0, 0, -c, d * c], [-s, c, 0, 0]],
            "beta": [[0, -sa, c * ca, a * s * sa - d * c * ca],
                     [sa, 0, s * ca, -a * c * sa - d * s * ca],
                     [-c * ca, -s * ca, 0, a * ca]],
        }
        for k, name in enumerate(names):
            D = _differential(T, tw[:, k])
            np.testing.assert_allclose(D[:3], table1[name], atol=1e-12, err_msg=name)
            np.testing.assert_allclose(D[3], 0, atol=1e-15)


def test_table2_frame_derivatives():
    """Table 2 (C_x ... C_gamma). C_alpha is garbled in the extracted text and is derived here
    (rotation about z through (x, y, z)); the printed C_beta lacks the x c(alpha) term of its
    (3, 4) entry, which differentiating Eq. (3) gives, so the test uses the derived entry."""
    rng = np.random.default_rng(3)
    factors = [_Factor(k, i) for i, k in enumerate(["tx", "ty", "tz", "rz", "ry", "rx"])]
    for _ in range(20):
        u = rng.uniform(-2, 2, 6)
        x, y, z, al, be, ga = u
        T, tw = _product_and_twists(factors, u, 6)
        np.testing.assert_allclose(T, zyx_transform(*u), atol=1e-14)
        ca, sa, cb, sb = np.cos(al), np.sin(al), np.cos(be), np.sin(be)
        table2 = {
            0: [[0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0]],
            1: [[0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 0, 0]],
            2: [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]],
            3: [[0, -1, 0, y], [1, 0, 0, -x], [0, 0, 0, 0]],
            4: [[0, 0, ca, -z * ca], [0, 0, sa, -z * sa], [-ca, -sa, 0, y * sa + x * ca]],
            5: [[0, sb, sa * cb, -y * sb - z * sa * cb],
                [-sb, 0, -ca * cb, x * sb + z * ca * cb],
                [-sa * cb, ca * cb, 0, -cb * (y * ca - x * sa)]],
        }
        for k in range(6):
            D = _differential(T, tw[:, k])
            np.testing.assert_allclose(D[:3], table2[k], atol=1e-12, err_msg=str(k))
