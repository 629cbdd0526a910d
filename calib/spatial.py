"""Rigid transforms used by the error model: elementary screws, the ZYX transform of Eq. (3),
and vectorised SO(3) log maps.

Conventions: 4x4 homogeneous matrices ``T_a_b`` (pose of frame b in frame a), SI units.
Twists are 6-vectors ``(v, w)``, linear part first, as in Pinocchio's ``Motion``.
"""
from __future__ import annotations

import warnings

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

#: Unit twists of the elementary motions, indexed by name (linear part first).
SCREWS: dict[str, np.ndarray] = {
    "tx": np.array([1.0, 0, 0, 0, 0, 0]),
    "ty": np.array([0, 1.0, 0, 0, 0, 0]),
    "tz": np.array([0, 0, 1.0, 0, 0, 0]),
    "rx": np.array([0, 0, 0, 1.0, 0, 0]),
    "ry": np.array([0, 0, 0, 0, 1.0, 0]),
    "rz": np.array([0, 0, 0, 0, 0, 1.0]),
}


def elementary(kind: str, value: float) -> np.ndarray:
    """4x4 transform of one elementary motion: ``kind`` in tx, ty, tz (metres) or rx, ry, rz (rad)."""
    T = np.eye(4)
    if kind[0] == "t":
        T["xyz".index(kind[1]), 3] = value
    else:
        c, s = np.cos(value), np.sin(value)
        i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[kind[1]]
        T[i, i] = c
        T[j, j] = c
        T[i, j] = -s
        T[j, i] = s
    return T


def zyx_transform(x: float, y: float, z: float, alpha: float, beta: float, gamma: float) -> np.ndarray:
    """Eq. (3): Trans(x, y, z) Rot(z, alpha) Rot(y, beta) Rot(x, gamma), 4x4.

    alpha is the yaw about z, beta the pitch about y, gamma the roll about x (radians).
    """
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [alpha, beta, gamma]).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


def zyx_parameters(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zyx_transform`: ``(x, y, z, alpha, beta, gamma)`` of a 4x4 transform.

    At gimbal lock (beta = +-pi/2) scipy's choice (gamma = 0) is kept, without its warning."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        ang = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX")
    return np.concatenate([T[:3, 3], ang])


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def to_se3(T: np.ndarray) -> pin.SE3:
    """A 4x4 matrix as a ``pinocchio.SE3``."""
    return pin.SE3(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def adjoint_inverse_apply(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``Ad(T^-1) xi`` for a twist ``xi = (v, w)``: the twist expressed in the frame T leads to."""
    R, p = T[:3, :3], T[:3, 3]
    v, w = xi[:3], xi[3:]
    return np.concatenate([R.T @ (v - np.cross(p, w)), R.T @ w])


def skew(w: np.ndarray) -> np.ndarray:
    """3x3 skew matrix of a 3-vector (or (..., 3, 3) of (..., 3))."""
    w = np.asarray(w)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


def log3_batch(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3), radians, of rotation matrices (n, 3, 3).

    Through the unit quaternion (Shepperd's method: the largest of w, x, y, z is computed from
    the diagonal, the others from it), so it is accurate for every angle up to pi.
    """
    R = np.asarray(R, float)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    tr = m00 + m11 + m22
    n = len(R)
    quat = np.empty((n, 4))
    cand = np.stack([tr, m00, m11, m22], axis=1)
    k = np.argmax(cand, axis=1)
    # w largest
    i = k == 0
    s = np.sqrt(1.0 + tr[i]) * 2.0
    quat[i] = np.stack([0.25 * s, (R[i, 2, 1] - R[i, 1, 2]) / s, (R[i, 0, 2] - R[i, 2, 0]) / s,
                        (R[i, 1, 0] - R[i, 0, 1]) / s], axis=1)
    i = k == 1
    s = np.sqrt(1.0 + m00[i] - m11[i] - m22[i]) * 2.0
    quat[i] = np.stack([(R[i, 2, 1] - R[i, 1, 2]) / s, 0.25 * s, (R[i, 0, 1] + R[i, 1, 0]) / s,
                        (R[i, 0, 2] + R[i, 2, 0]) / s], axis=1)
    i = k == 2
    s = np.sqrt(1.0 + m11[i] - m00[i] - m22[i]) * 2.0
    quat[i] = np.stack([(R[i, 0, 2] - R[i, 2, 0]) / s, (R[i, 0, 1] + R[i, 1, 0]) / s, 0.25 * s,
                        (R[i, 1, 2] + R[i, 2, 1]) / s], axis=1)
    i = k == 3
    s = np.sqrt(1.0 + m22[i] - m00[i] - m11[i]) * 2.0
    quat[i] = np.stack([(R[i, 1, 0] - R[i, 0, 1]) / s, (R[i, 0, 2] + R[i, 2, 0]) / s,
                        (R[i, 1, 2] + R[i, 2, 1]) / s, 0.25 * s], axis=1)
    quat[quat[:, 0] < 0] *= -1.0
    v = quat[:, 1:]
    nv = np.linalg.norm(v, axis=1)
    angle = 2.0 * np.arctan2(nv, quat[:, 0])
    # angle / sin(angle / 2), with its limit 2 at zero
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(nv > 1e-12, angle / np.where(nv > 1e-12, nv, 1.0), 2.0 / quat[:, 0])
    return v * f[:, None]


def left_jacobian_inverse_batch(r: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SO(3) at rotation vectors r (n, 3): (n, 3, 3).

    If ``R' = exp(dw) R`` (a small rotation ``dw`` applied on the left, in the fixed frame)
    then ``log(R') = log(R) + Jl^-1(log R) dw`` to first order.
    """
    th = np.linalg.norm(r, axis=-1)
    S = skew(r)
    S2 = S @ S
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    # coefficient of S^2: 1/th^2 - (1 + cos th) / (2 th sin th); series 1/12 + th^2/720
    with np.errstate(all="ignore"):
        c2 = 1.0 / ths**2 - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths))
    c2 = np.where(small, 1.0 / 12.0 + th**2 / 720.0, c2)
    return np.eye(3) - 0.5 * S + c2[..., None, None] * S2
