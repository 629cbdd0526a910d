"""Closed-form estimates of the measurement->base and flange->tool transforms.

A laser tracker stands metres from the robot at any orientation and the tool point sits an
unknown 100-300 mm from the flange, far outside the region where an iterative fit started at the
nominal (identity) transforms converges. With the nominal chain's flange poses
``T_base_flange(q_i) = (R_i, p_i)`` and the measured tool poses, the model

    T_meas_tool_i = X . T_base_flange(q_i) . Y,   X = T_meas_base, Y = T_flange_tool

is solved without iteration:

* full pose: ``R_meas_i R_Y^T = R_X R_i`` is linear and homogeneous in (R_X, R_Y^T); the null
  vector of the stacked 9x18 blocks (SVD) gives both up to scale, each then projected onto SO(3).
  The translations follow from the linear least squares ``t_X + R_X R_i t_Y = p_meas_i - R_X p_i``.
* position only: ``p_meas_i = A p_i + sum_jk R_i[j, k] C_jk + t_X`` is linear in A = R_X (9),
  C_jk = R_X[:, j] t_Y[k] (27) and t_X (3); R_X is A projected onto SO(3), then (t_X, t_Y) are
  solved by linear least squares with R_X fixed. R_Y cannot be observed.

The estimates carry the error of the nominal structure (millimetres), which the identification
then removes.
"""
from __future__ import annotations

import numpy as np

from .errors import DataError
from .kinematics import ChainKinematics
from .robot import RobotModel


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """The rotation matrix closest to M (Frobenius norm), via SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


#: Poses per chunk when accumulating the normal equations of the frame estimate.
CHUNK = 4096


def _solve_translations(R_X, R_f, p_f, p_meas):
    """(t_X, t_Y) minimising sum_n |t_X + R_X R_f_n t_Y - (p_meas_n - R_X p_f_n)|^2, by its 6x6
    normal equations accumulated over the poses (M_n = R_X R_f_n is a rotation: M_n^T M_n = I)."""
    N = len(p_f)
    A = np.zeros((6, 6))
    g = np.zeros(6)
    A[:3, :3] = A[3:, 3:] = N * np.eye(3)
    for a in range(0, N, CHUNK):
        M = R_X @ R_f[a:a + CHUNK]                       # (n, 3, 3)
        b = p_meas[a:a + CHUNK] - p_f[a:a + CHUNK] @ R_X.T
        S = M.sum(axis=0)
        A[:3, 3:] += S
        A[3:, :3] += S.T
        g[:3] += b.sum(axis=0)
        g[3:] += np.einsum("nji,nj->i", M, b)
    sol = np.linalg.solve(A, g)
    return sol[:3], sol[3:]


def estimate_frames(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                    R_meas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form (T_meas_base, T_flange_tool), 4x4 each, from measurements.

    Q : (N, n) joints; p_meas : (N, 3) metres, meas frame; R_meas : (N, 3, 3) or None.
    The structural parameters of ``robot`` are taken as they are. For position-only data the
    returned T_flange_tool has ``robot``'s rotation (it is not observable).
    Raises :class:`DataError` when the poses do not determine the frames (too few or too alike).
    """
    kin = ChainKinematics(robot)
    R_b, p_b = kin.frame_poses(Q, "base")
    R_fl, p_fl = kin.frame_poses(Q, "flange")
    # flange in the base frame (the base frame pose does not depend on q)
    Rb, pb = R_b[0], p_b[0]
    R_f = Rb.T @ R_fl
    p_f = (p_fl - pb) @ Rb
    N = len(Q)
    X = np.eye(4)
    Y = robot.T_flange_tool().copy()
    if R_meas is not None:
        if N < 3:
            raise DataError(f"at least 3 poses are needed to estimate the frames, got {N}")
        I3 = np.eye(3)
        # vec is column-major: vec(R_X R_i) = (R_i^T kron I) vec(R_X); vec(R_m Z) = (I kron R_m) vec(Z)
        # null vector of the blocks: eigenvector of the 18x18 normal matrix, accumulated in chunks
        normal = np.zeros((18, 18))
        for a in range(0, N, CHUNK):
            n = len(R_f[a:a + CHUNK])
            left = -np.einsum("nba,cd->nacbd", R_f[a:a + CHUNK], I3).reshape(n, 9, 9)
            right = np.einsum("ac,nbd->nabcd", I3, R_meas[a:a + CHUNK]).reshape(n, 9, 9)
            blocks = np.concatenate([left, right], axis=2).reshape(9 * n, 18)
            normal += blocks.T @ blocks
        w, V = np.linalg.eigh(normal)
        if w[1] < 1e-10 * w[-1]:
            raise DataError("the poses do not determine the measurement frame orientation "
                            "(too few distinct orientations)")
        v = V[:, 0]
        RX = v[:9].reshape(3, 3, order="F")
        Z = v[9:].reshape(3, 3, order="F")
        scale = np.sign(np.linalg.det(RX)) * np.cbrt(abs(np.linalg.det(RX)))
        R_X = project_to_so3(RX / scale)
        R_Y = project_to_so3(Z / scale).T
        t_X, t_Y = _solve_translations(R_X, R_f, p_f, p_meas)
        Y[:3, :3] = R_Y
    else:
        if N < 13:
            raise DataError(f"at least 13 position-only poses are needed to estimate the frames, got {N}")
        I3 = np.eye(3)
        A = np.concatenate([
            np.einsum("nj,ab->najb", p_f, I3).reshape(N, 3, 9),                   # A p_i (A column-major)
            np.einsum("nj,ab->najb", R_f.reshape(N, 9), I3).reshape(N, 3, 27),    # sum_jk R_i[j,k] C_jk
            np.broadcast_to(I3, (N, 3, 3))], axis=2).reshape(3 * N, 39)
        sol, _, rank, _ = np.linalg.lstsq(A, p_meas.reshape(-1), rcond=None)
        if rank < 39:
            raise DataError("the position-only poses do not determine the measurement frame "
                            "(too few distinct configurations)")
        # A = sol[:9] (column-major) estimates R_X; with R_X fixed, (t_X, t_Y) are linear again
        R_X = project_to_so3(sol[:9].reshape(3, 3, order="F"))
        t_X, t_Y = _solve_translations(R_X, R_f, p_f, p_meas)
    X[:3, :3], X[:3, 3] = R_X, t_X
    Y[:3, 3] = t_Y
    return X, Y
