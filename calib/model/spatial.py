"""Rigid transforms used by the error model: elementary screws, the ZYX transform of Eq. (3),
the model's own vectorised rotation maps (ZYX angles of Eq. 3, rotation vectors for the
simulated noise, the quaternion inside the SO(3) log) and SO(3) log maps. Rotations read from
files are converted by Pinocchio / scipy in :mod:`calib.io.csv.specs`.

Conventions: 4x4 homogeneous matrices ``T_a_b`` (pose of frame b in frame a), SI units.
Twists are 6-vectors ``(v, w)``, linear part first, as in Pinocchio's ``Motion``.
Quaternions are (w, x, y, z). ZYX angles are (alpha, beta, gamma): yaw about z, pitch about y,
roll about x, ``R = Rz(alpha) Ry(beta) Rx(gamma)`` (scipy's intrinsic "ZYX" Euler angles).
These maps are plain numpy, batched over poses (scipy.spatial takes longer to import than a
whole short calibration; the tests compare them with it).
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

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
    T[:3, :3] = rotation_from_zyx(np.array([alpha, beta, gamma], float))
    T[:3, 3] = (x, y, z)
    return T


def zyx_parameters(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zyx_transform`: ``(x, y, z, alpha, beta, gamma)`` of a 4x4 transform."""
    return np.concatenate([T[:3, 3], zyx_from_rotation(T[:3, :3])])


def zyx_axes(alpha: float, beta: float) -> np.ndarray:
    """(3, 3) columns: the axes, in the parent frame, about which d alpha, d beta, d gamma turn
    Rz(alpha) Ry(beta) Rx(gamma): d R R^T = skew(E @ (d alpha, d beta, d gamma))."""
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    return np.array([[0.0, -sa, ca * cb], [0.0, ca, sa * cb], [1.0, 0.0, -sb]])


def zyx_parameters_jacobian(T_left: np.ndarray, p: np.ndarray, T_right: np.ndarray) -> np.ndarray:
    """(6, 6) d zyx_parameters(T_left @ zyx_transform(*p) @ T_right) / d p: how the ZYX parameters
    (x, y, z m, alpha, beta, gamma rad) of a frame built from constant transforms around ZYX
    parameters p (6,) change with p (a reference frame and its deviation parameters, as the
    measurement and tool frames are modelled). Rows of the result's angles are NaN at its gimbal
    lock (its beta = +-pi/2: alpha and gamma are not separately defined there)."""
    x, y, z, alpha, beta, gamma = np.asarray(p, float).tolist()
    Z = zyx_transform(x, y, z, alpha, beta, gamma)
    F = T_left @ Z @ T_right
    L = T_left[:3, :3]
    E = zyx_axes(alpha, beta)
    J = np.zeros((6, 6))
    J[:3, :3] = L
    ax, ay, az = (Z[:3, :3] @ T_right[:3, 3]).tolist()      # the right transform's origin, turned by Z
    arm_x = np.array([[0.0, -az, ay], [az, 0.0, -ax], [-ay, ax, 0.0]])     # skew(arm)
    J[:3, 3:] = -L @ arm_x @ E                             # d t = L (e_k x arm) d theta_k
    a_F, b_F = zyx_from_rotation(F[:3, :3])[:2].tolist()
    cb = math.cos(b_F)
    if abs(cb) < 1e-9:
        J[3:, 3:] = np.nan
    else:
        # omega = L E d theta = E_F d theta_F, solved by E_F's inverse in closed form
        ca, sa, tb = math.cos(a_F), math.sin(a_F), math.sin(b_F) / cb
        E_F_inv = np.array([[ca * tb, sa * tb, 1.0], [-sa, ca, 0.0], [ca / cb, sa / cb, 0.0]])
        J[3:, 3:] = E_F_inv @ (L @ E)
    return J


def rotation_from_zyx(angles: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) ``Rz(alpha) Ry(beta) Rx(gamma)`` of ZYX angles (..., 3), rad."""
    angles = np.asarray(angles, float)
    if angles.ndim == 1:    # one rotation: scalar math is many times faster than array calls
        (ca, cb, cg), (sa, sb, sg) = map(math.cos, angles), map(math.sin, angles)
        return np.array([[ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg],
                         [sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg],
                         [-sb, cb * sg, cb * cg]])
    ca, cb, cg = np.moveaxis(np.cos(angles), -1, 0)
    sa, sb, sg = np.moveaxis(np.sin(angles), -1, 0)
    R = np.empty(angles.shape[:-1] + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = -sb, cb * sg, cb * cg
    return R


def zyx_from_rotation(R: np.ndarray) -> np.ndarray:
    """ZYX angles (..., 3) (alpha, beta, gamma), radians, of rotation matrices (..., 3, 3).

    alpha and gamma in (-pi, pi], beta in [-pi/2, pi/2]. At gimbal lock (beta = +-pi/2, where
    only alpha -+ gamma is defined) gamma is set to 0. gamma is taken from alpha and the entries
    that stay of order one near the lock (sin gamma = sa R02 - ca R12, cos gamma = ca R11 - sa R01),
    so the angles give back R to rounding also a hair away from the lock, where alpha and the
    textbook atan2(R21, R22) are each off by ~1e-16 / cos(beta) (1.7e-5 rad at 1e-11 from it).
    """
    R = np.asarray(R, float)
    if R.ndim == 2:         # one rotation, in scalar math (on Python floats: indexing costs more)
        (r00, r01, r02), (r10, r11, r12), (r20, _, _) = R[:3, :3].tolist()
        c = math.hypot(r00, r10)
        if c < 1e-12:
            return np.array([math.atan2(-r01, r11), math.atan2(-r20, c), 0.0])
        alpha = math.atan2(r10, r00)
        sa, ca = math.sin(alpha), math.cos(alpha)
        return np.array([alpha, math.atan2(-r20, c), math.atan2(sa * r02 - ca * r12, ca * r11 - sa * r01)])
    c = np.hypot(R[..., 0, 0], R[..., 1, 0])   # |cos beta|
    beta = np.arctan2(-R[..., 2, 0], c)
    lock = c < 1e-12
    alpha = np.where(lock, np.arctan2(-R[..., 0, 1], R[..., 1, 1]), np.arctan2(R[..., 1, 0], R[..., 0, 0]))
    sa, ca = np.sin(alpha), np.cos(alpha)
    gamma = np.where(lock, 0.0, np.arctan2(sa * R[..., 0, 2] - ca * R[..., 1, 2], ca * R[..., 1, 1] - sa * R[..., 0, 1]))
    return np.stack([alpha, beta, gamma], axis=-1)


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) (w, x, y, z), w >= 0, of rotation matrices (n, 3, 3).

    Shepperd's method: the largest of w, x, y, z is computed from the diagonal, the others from
    it, so it is accurate for every angle up to pi. Branch-free over the rows: K = 4 q q^T has
    entries that are sums and differences of entries of R, and q = K[k] / (2 sqrt(K[k, k])) for
    k its largest diagonal entry.
    """
    R = np.asarray(R, float)
    n = len(R)
    F = R.reshape(n, 9)
    m00, m11, m22 = F[:, 0], F[:, 4], F[:, 8]
    K = np.empty((n, 4, 4))
    K[:, 0, 0] = 1.0 + m00 + m11 + m22
    K[:, 1, 1] = 1.0 + m00 - m11 - m22
    K[:, 2, 2] = 1.0 + m11 - m00 - m22
    K[:, 3, 3] = 1.0 + m22 - m00 - m11
    K[:, 0, 1] = K[:, 1, 0] = F[:, 7] - F[:, 5]      # 4 w x
    K[:, 0, 2] = K[:, 2, 0] = F[:, 2] - F[:, 6]      # 4 w y
    K[:, 0, 3] = K[:, 3, 0] = F[:, 3] - F[:, 1]      # 4 w z
    K[:, 1, 2] = K[:, 2, 1] = F[:, 1] + F[:, 3]      # 4 x y
    K[:, 1, 3] = K[:, 3, 1] = F[:, 2] + F[:, 6]      # 4 x z
    K[:, 2, 3] = K[:, 3, 2] = F[:, 5] + F[:, 7]      # 4 y z
    rows = np.arange(n)
    k = np.argmax(K[:, [0, 1, 2, 3], [0, 1, 2, 3]], axis=1)
    quat = K[rows, k]                                  # 4 q_k q
    quat /= (2.0 * np.sqrt(quat[rows, k]))[:, None]    # q (up to sign)
    quat[quat[:, 0] < 0] *= -1.0
    return quat


def rotation_from_quaternion(wxyz: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of unit quaternions (N, 4) (w, x, y, z), as Eigen's
    toRotationMatrix computes them, vectorised (a million rows: no per-row objects)."""
    w, x, y, z = wxyz.T
    R = np.empty((len(wxyz), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotation_from_rotvec(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) ``exp([v])`` of rotation vectors (..., 3), radians."""
    v = np.asarray(v, float)
    th = np.linalg.norm(v, axis=-1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    # sin(th) / th and (1 - cos th) / th^2, with their series near 0
    a = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th ** 2 / 24.0, (1.0 - np.cos(ths)) / ths ** 2)
    S = skew(v)
    return np.eye(3) + a[..., None, None] * S + b[..., None, None] * (S @ S)


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def to_se3(T: np.ndarray) -> pin.SE3:
    """A 4x4 matrix as a ``pinocchio.SE3``."""
    return pin.SE3(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The cross product a x b of two 3-vectors, (3,) float: ``np.cross``'s arithmetic (a1 b2 -
    a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0, each product rounded, then the difference), so the same
    bits, without its overhead for one pair (~25 us a call: deriving a model made ~20)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def skew(w: np.ndarray) -> np.ndarray:
    """3x3 skew matrix of a 3-vector (or (..., 3, 3) of (..., 3))."""
    w = np.asarray(w)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


_LOG3_PLUS, _LOG3_MINUS = np.array([7, 2, 3]), np.array([5, 6, 1])


def log3_batch(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3), radians, of rotation matrices (n, 3, 3).

    Through the unit quaternion (:func:`quaternion_from_rotation`), so it is accurate for every
    angle up to pi.
    """
    R = np.asarray(R, float)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    tr = m00 + m11 + m22
    if np.all(tr >= np.maximum(np.maximum(m00, m11), m22)):
        # every angle below ~120 deg (w the largest quaternion component, Shepperd's first
        # branch of quaternion_from_rotation): the same arithmetic with fewer array operations
        s = np.sqrt(1.0 + m00 + m11 + m22) * 2.0
        flat = R.reshape(len(R), 9)
        # (R21 - R12, R02 - R20, R10 - R01)
        v = flat[:, _LOG3_PLUS] - flat[:, _LOG3_MINUS]
        v /= s[:, None]
        w = 0.25 * s
        nv = np.sqrt(np.einsum("ij,ij->i", v, v))
        small = ~(nv > 1e-12)
        if small.any():
            f = 2.0 * np.arctan2(nv, w) / np.where(small, 1.0, nv)
            f[small] = 2.0 / w[small]
        else:
            f = 2.0 * np.arctan2(nv, w) / nv
        v *= f[:, None]
        return v
    quat = quaternion_from_rotation(R)
    v = quat[:, 1:]
    nv = np.linalg.norm(v, axis=1)
    angle = 2.0 * np.arctan2(nv, quat[:, 0])
    # angle / sin(angle / 2), with its limit 2 at zero
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(nv > 1e-12, angle / np.where(nv > 1e-12, nv, 1.0), 2.0 / quat[:, 0])
    return v * f[:, None]


def rotation_angle(R: np.ndarray) -> float:
    """The angle of one rotation matrix R (3, 3), radians in [0, pi]: |log3(R)|, in scalar math
    (the batch call on one matrix costs ~40 us): atan2 of its sine, half the norm of R - R^T as a
    vector, and its cosine, (tr R - 1) / 2, accurate at every angle."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R, float)[:3, :3].tolist()
    s = 0.5 * math.sqrt((r21 - r12) ** 2 + (r02 - r20) ** 2 + (r10 - r01) ** 2)
    return math.atan2(s, 0.5 * (r00 + r11 + r22 - 1.0))


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


def best_fit_motion(p: np.ndarray, p_ref: np.ndarray, registration: str = "rigid"):
    """(R (3, 3), t (3,), scale) of the best-fit rigid motion (``"similarity"``: and scale) of
    points p onto p_ref (both (N, 3) metres; Kabsch / Umeyama): ``scale R p + t ~ p_ref``."""
    mp, mr = p.mean(axis=0), p_ref.mean(axis=0)
    a, b = p - mp, p_ref - mr
    U, s, Vt = np.linalg.svd(a.T @ b)
    D = np.array([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = (U * D @ Vt).T
    scale = float(s @ D / np.sum(a * a)) if registration == "similarity" else 1.0
    return R, mr - scale * R @ mp, scale
