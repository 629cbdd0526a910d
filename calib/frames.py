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

from dataclasses import dataclass

import numpy as np

from .errors import DataError
from .kinematics import ChainKinematics
from .robot import RobotModel
from .solvers import CHUNK_POSES


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """The rotation matrix closest to M (Frobenius norm), via SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _solve_translations(R_X, R_f, p_f, p_meas):
    N = len(p_f)
    A = np.zeros((3 * N, 6))
    A[:, :3] = np.tile(np.eye(3), (N, 1))
    A[:, 3:] = (R_X @ R_f).reshape(3 * N, 3)
    b = (p_meas - p_f @ R_X.T).reshape(-1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return sol[:3], sol[3:]


@dataclass(frozen=True)
class FrameEstimate:
    """A robust closed-form frame estimate (:func:`estimate_frames_robust`).

    T_meas_base, T_flange_tool : (4, 4), metres. ``inliers`` : (N,) bool, the rows the final
    estimate was computed from; ``position_residual`` (N,) metres and ``rotation_residual`` (N,)
    radians (or None) of every row against it; ``threshold_position`` (m) and
    ``threshold_rotation`` (rad) the trimming thresholds of the last round.
    """

    T_meas_base: np.ndarray
    T_flange_tool: np.ndarray
    inliers: np.ndarray
    position_residual: np.ndarray
    rotation_residual: np.ndarray | None
    threshold_position: float
    threshold_rotation: float | None


#: Trimming of :func:`estimate_frames_robust`: a row is left out when its residual exceeds the
#: median by more than TRIM_K robust standard deviations (1.4826 MAD), and at least the floors
#: (the estimate carries the nominal structure's error, millimetres, which must not be trimmed).
TRIM_K = 6.0
TRIM_FLOOR_M = 5e-3
TRIM_FLOOR_RAD = 0.02
TRIM_ROUNDS = 10


def _flange_in_base(robot: RobotModel, Q: np.ndarray):
    kin = ChainKinematics(robot)
    R_b, p_b = kin.frame_poses(Q, "base")
    R_fl, p_fl = kin.frame_poses(Q, "flange")
    # flange in the base frame (the base frame pose does not depend on q)
    Rb, pb = R_b[0], p_b[0]
    return Rb.T @ R_fl, (p_fl - pb) @ Rb


def _threshold(r: np.ndarray, floor: float) -> float:
    med = float(np.median(r))
    return max(med + TRIM_K * 1.4826 * float(np.median(np.abs(r - med))), floor)


def estimate_frames_robust(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                           R_meas: np.ndarray | None = None) -> FrameEstimate:
    """:func:`estimate_frames` made robust to gross rows by residual-based trimming.

    The closed-form estimate is computed from all rows, every row's residual against it is
    taken (position: metres; orientation: radians), rows beyond the median by more than
    ``TRIM_K`` robust standard deviations (and beyond ``TRIM_FLOOR_M`` / ``TRIM_FLOOR_RAD``)
    are left out and the estimate is repeated, until the kept rows do not change. A single row
    a million kilometres off moves the least-squares translation of N rows by 1/N of that, all
    good rows then share about the same residual and the gross row stands out; it is left out
    in the first round. Arguments and errors as :func:`estimate_frames`.
    """
    R_f, p_f = _flange_in_base(robot, Q)
    N = len(Q)
    keep = np.ones(N, bool)
    minimum = 3 if R_meas is not None else 13
    for _ in range(TRIM_ROUNDS):
        X, Y = _estimate(robot, R_f[keep], p_f[keep], p_meas[keep],
                         None if R_meas is None else R_meas[keep])
        p_est = X[:3, 3] + (p_f + R_f @ Y[:3, 3]) @ X[:3, :3].T
        e_pos = np.linalg.norm(p_est - p_meas, axis=1)
        thr_p, thr_r, e_rot = _threshold(e_pos[keep], TRIM_FLOOR_M), None, None
        new = e_pos <= thr_p
        if R_meas is not None:
            R_est = X[:3, :3] @ R_f @ Y[:3, :3]
            cos = (np.einsum("nij,nij->n", R_est, R_meas) - 1.0) / 2.0
            e_rot = np.arccos(np.clip(cos, -1.0, 1.0))
            thr_r = _threshold(e_rot[keep], TRIM_FLOOR_RAD)
            new &= e_rot <= thr_r
        if np.array_equal(new, keep) or new.sum() < minimum:
            break
        keep = new
    return FrameEstimate(X, Y, keep, e_pos, e_rot, thr_p, thr_r)


def estimate_frames(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                    R_meas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form (T_meas_base, T_flange_tool), 4x4 each, from measurements (least squares
    over all rows; :func:`estimate_frames_robust` leaves gross rows out).

    Q : (N, n) joints; p_meas : (N, 3) metres, meas frame; R_meas : (N, 3, 3) or None.
    The structural parameters of ``robot`` are taken as they are. For position-only data the
    returned T_flange_tool has ``robot``'s rotation (it is not observable).
    Raises :class:`DataError` when the poses do not determine the frames (too few or too alike).
    """
    R_f, p_f = _flange_in_base(robot, Q)
    return _estimate(robot, R_f, p_f, p_meas, R_meas)


def _estimate(robot: RobotModel, R_f, p_f, p_meas, R_meas):
    N = len(R_f)
    X = np.eye(4)
    Y = robot.T_flange_tool().copy()
    if R_meas is not None:
        if N < 3:
            raise DataError(f"at least 3 poses are needed to estimate the frames, got {N}")
        I3 = np.eye(3)
        # vec is column-major: vec(R_X R_i) = (R_i^T kron I) vec(R_X); vec(R_m Z) = (I kron R_m) vec(Z)
        # null vector of the blocks: eigenvector of the 18x18 normal matrix, accumulated over
        # chunks of poses (memory independent of N)
        normal = np.zeros((18, 18))
        for start in range(0, N, CHUNK_POSES):
            sl = slice(start, start + CHUNK_POSES)
            n = len(R_f[sl])
            left = -np.einsum("nba,cd->nacbd", R_f[sl], I3).reshape(n, 9, 9)
            right = np.einsum("ac,nbd->nabcd", I3, R_meas[sl]).reshape(n, 9, 9)
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
