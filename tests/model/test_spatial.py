"""The numpy rotation conversions of calib.model.spatial against scipy's Rotation."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from calib.model.spatial import (log3_batch, quaternion_from_rotation, rotation_from_rotvec,
                                 rotation_from_zyx, zyx_from_rotation)


@pytest.fixture(scope="module")
def rotations():
    rng = np.random.default_rng(7)
    R = Rotation.random(200, random_state=rng)
    # plus turns near pi, near identity and at gimbal lock (beta = +-pi/2)
    extra = Rotation.from_rotvec(np.vstack([np.pi * np.eye(3), 1e-9 * np.eye(3)]))
    lock = Rotation.from_euler("ZYX", [[0.3, np.pi / 2, 0.0], [0.0, -np.pi / 2, 0.2]])
    return Rotation.concatenate([R, extra, lock])


def test_quaternions(rotations):
    R = rotations.as_matrix()
    wxyz = quaternion_from_rotation(R)
    ref = rotations.as_quat()[:, [3, 0, 1, 2]]
    ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
    # same sign convention (w >= 0); the pi turns have w = 0 and either sign of (x, y, z)
    same = np.abs(wxyz[:, 0]) > 1e-9
    np.testing.assert_allclose(wxyz[same], ref[same], atol=1e-15)
    np.testing.assert_allclose(Rotation.from_quat(wxyz, scalar_first=True).as_matrix(), R, atol=1e-15)


def test_zyx_angles(rotations):
    R = rotations.as_matrix()
    ang = zyx_from_rotation(R)
    np.testing.assert_allclose(rotation_from_zyx(ang), R, atol=1e-14)
    regular = np.abs(np.abs(ang[:, 1]) - np.pi / 2) > 1e-6
    with pytest.warns(UserWarning, match="Gimbal lock"):
        ref = rotations.as_euler("ZYX")
    np.testing.assert_allclose(ang[regular], ref[regular], atol=1e-14)
    np.testing.assert_allclose(rotation_from_zyx(ref), R, atol=1e-14)
    # gimbal lock: gamma set to 0
    assert np.all(ang[~regular, 2] == 0.0) and (~regular).sum() == 2
    # one matrix at a time (the scalar path) gives the same angles and matrices
    for k in (0, 1, 2, len(R) - 2, len(R) - 1):
        np.testing.assert_allclose(zyx_from_rotation(R[k]), ang[k], atol=1e-15)
        np.testing.assert_allclose(rotation_from_zyx(ang[k]), rotation_from_zyx(ang[k:k + 1])[0], atol=1e-15)


def test_rotation_vectors(rotations):
    v = rotations.as_rotvec()
    np.testing.assert_allclose(rotation_from_rotvec(v), rotations.as_matrix(), atol=1e-15)
    tiny = np.array([[1e-9, -2e-9, 3e-10], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(rotation_from_rotvec(tiny), Rotation.from_rotvec(tiny).as_matrix(), atol=1e-18)
    keep = np.linalg.norm(v, axis=1) < np.pi - 1e-9   # at pi the sign of the axis is free
    np.testing.assert_allclose(log3_batch(rotations.as_matrix())[keep], v[keep], atol=1e-14)


def test_zyx_angles_give_back_the_rotation_a_hair_away_from_gimbal_lock():
    """beta within 1e-14 .. 1e-5 of +-pi/2 (TIAGo's hand_palm_link is 1.2e-11 from it): the
    angles rebuild R to 1e-13 in scalar and array form (the textbook gamma = atan2(R21, R22) was
    off by up to 1e-16 / cos(beta), 1.7e-5 rad there, and the mdh-csv export refused TIAGo)."""
    rng = np.random.default_rng(3)
    for eps in (1e-14, 1e-12, 1.2e-11, 1e-9, 1e-7, 1e-5):
        for sign in (-1.0, 1.0):
            a = rng.uniform(-3.0, 3.0, (20, 3))
            a[:, 1] = sign * (np.pi / 2 - eps)
            # matrices rounded otherwise than rotation_from_zyx does (as a URDF's products are)
            R = np.array([pin.rpy.rpyToMatrix(g, b, al) for al, b, g in a])
            assert np.abs(rotation_from_zyx(zyx_from_rotation(R)) - R).max() < 3e-12, eps
            assert max(np.abs(rotation_from_zyx(zyx_from_rotation(r)) - r).max() for r in R) < 3e-12, eps


def test_zyx_parameters_jacobian_matches_finite_differences():
    """d zyx_parameters(L zyx(p) R) / d p against central differences of the exact map (random
    frames, 1e-7 absolute: differences of step 1e-6), and NaN angle rows at gimbal lock."""
    from calib.model.spatial import zyx_parameters, zyx_parameters_jacobian, zyx_transform

    rng = np.random.default_rng(3)
    for _ in range(10):
        L, R = zyx_transform(*rng.normal(size=6)), zyx_transform(*rng.normal(size=6))
        p = rng.normal(size=6) * 0.6
        J = zyx_parameters_jacobian(L, p, R)
        h = 1e-6
        Jn = np.column_stack([(zyx_parameters(L @ zyx_transform(*(p + h * e)) @ R)
                               - zyx_parameters(L @ zyx_transform(*(p - h * e)) @ R)) / (2 * h) for e in np.eye(6)])
        np.testing.assert_allclose(J, Jn, atol=1e-7)
    J = zyx_parameters_jacobian(np.eye(4), np.array([0, 0, 0, 0.3, np.pi / 2, 0.1]), np.eye(4))
    assert np.isnan(J[3:, 3:]).all() and np.isfinite(J[:3]).all()


def test_cross3_is_np_cross_to_the_bit():
    """cross3 (one pair of 3-vectors, as the MDH derivation asks) gives np.cross's bits: the same
    products and differences, over magnitudes from 1e-8 to 1e3."""
    from calib.model.spatial import cross3

    rng = np.random.default_rng(7)
    for _ in range(2000):
        a, b = rng.normal(size=3) * 10 ** rng.uniform(-8, 3), rng.normal(size=3) * 10 ** rng.uniform(-8, 3)
        np.testing.assert_array_equal(cross3(a, b), np.cross(a, b))
    np.testing.assert_array_equal(cross3(np.array([1.0, 0, 0]), np.array([0, 1.0, 0])), [0.0, 0.0, 1.0])
