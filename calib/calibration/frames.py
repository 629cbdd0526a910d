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
  solved by linear least squares with R_X fixed. R_Y cannot be observed. With three or more
  targets measured at the same configurations, when that system is not determined (it needs
  13 configurations whatever the number of targets), each configuration's three points define
  a frame on the tool, a full pose, and R_X follows as from full poses (three configurations).

Several targets on the tool share X and each have their own Y (:func:`estimate_target_frames`).

The estimates carry the error of the nominal structure (millimetres), which the identification
then removes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import DataError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """The rotation matrix closest to M (Frobenius norm), via SVD."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


#: Poses per chunk when accumulating the normal equations of the frame estimate.
CHUNK = 4096


def _solve_translations(R_X, R_f, p_f, p_meas, rows, K):
    """(t_X (3,), t_Y (K, 3)) minimising sum_n |t_X + R_X R_f_n t_Y[k_n] - (p_meas_n - R_X p_f_n)|^2
    with R_X fixed (rows: (N,) target index k_n), by the (3 + 3K) normal equations accumulated
    over chunks of poses (M_n = R_X R_f_n is a rotation: M_n^T M_n = I)."""
    N = len(p_f)
    A = np.zeros((3 + 3 * K, 3 + 3 * K))
    g = np.zeros(3 + 3 * K)
    A[:3, :3] = N * np.eye(3)
    for a in range(0, N, CHUNK):
        M = R_X @ R_f[a:a + CHUNK]                       # (n, 3, 3)
        b = p_meas[a:a + CHUNK] - p_f[a:a + CHUNK] @ R_X.T
        r = rows[a:a + CHUNK]
        g[:3] += b.sum(axis=0)
        for k in range(K):
            on = slice(None) if K == 1 else (r == k)    # (one target: every row, no copies)
            Mk, bk = M[on], b[on]
            S = Mk.sum(axis=0)
            blk = slice(3 + 3 * k, 6 + 3 * k)
            A[:3, blk] += S
            A[blk, :3] += S.T
            A[blk, blk] += len(Mk) * np.eye(3)
            g[blk] += Mk.reshape(-1, 3).T @ bk.reshape(-1)      # sum_n M_n^T b_n
    sol, *_ = np.linalg.lstsq(A, g, rcond=None)
    return sol[:3], sol[3:].reshape(K, 3)


def estimate_frames(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                    R_meas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form (T_meas_base, T_flange_tool), 4x4 each, from measurements of one target.

    Q : (N, n) joints; p_meas : (N, 3) metres, meas frame; R_meas : (N, 3, 3) or None.
    The structural parameters of ``robot`` are taken as they are. For position-only data the
    returned T_flange_tool has ``robot``'s rotation (it is not observable).
    Raises :class:`DataError` when the poses do not determine the frames (too few or too alike).
    See :func:`estimate_target_frames` for several targets.
    """
    X, Y = estimate_target_frames(robot.for_target(), Q, p_meas, R_meas)
    return X, Y[0]


def estimate_target_frames(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                           R_meas: np.ndarray | None = None,
                           targets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form T_meas_base (4, 4) and T_flange_tool of each target (K, 4, 4) from
    measurements of several targets on the tool (one shared measurement frame).

    Q : (N, n) joints; p_meas : (N, 3) metres, meas frame; R_meas : (N, 3, 3) or None;
    targets : (N,) int, each row's target index into ``robot.targets`` (None: all rows measure
    the first target; K = robot.n_targets). The unknowns of the module docstring get one
    flange->target block per target (R_Y, t_Y; C_jk for position-only data). For position-only
    data each returned T_flange_tool keeps ``robot``'s rotation of that target (a point has no
    orientation). Raises :class:`DataError` when the poses do not determine the frames.
    """
    rows = np.zeros(len(Q), int) if targets is None else np.asarray(targets, int)
    R_f, p_f = _flange_in_base(robot, Q)
    return _estimate(robot, R_f, p_f, p_meas, R_meas, rows)


def _flange_in_base(robot: RobotModel, Q: np.ndarray, kin: ChainKinematics | None = None):
    """(R_f (N, 3, 3), p_f (N, 3)): the flange in MDH frame 0 at Q (kin: ``robot``'s kinematics
    at its values, or None to build them)."""
    kin = kin or ChainKinematics(robot)
    R_fl, p_fl = kin.frame_poses(Q, "flange")
    # flange in the base frame (the base frame pose does not depend on q)
    Rb, pb = kin.base_placement[:3, :3], kin.base_placement[:3, 3]
    return Rb.T @ R_fl, (p_fl - pb) @ Rb


def _rotations(R_f, R_meas, rows, K):
    """(R_X (3, 3), R_Y (K, 3, 3)) from flange rotations R_f (N, 3, 3) in the base frame and
    measured rotations R_meas (N, 3, 3) of the rows' targets (rows (N,) target index): the null
    vector of the module docstring's homogeneous system, by the eigenvector of its normal matrix.
    Raises :class:`DataError` when the rotations do not determine it."""
    I3 = np.eye(3)
    N = len(R_f)
    # vec is column-major: vec(R_X R_i) = (R_i^T kron I) vec(R_X); vec(R_m Z) = (I kron R_m) vec(Z).
    # The null vector of the blocks [-(R_i^T kron I), I kron R_m_i] is the eigenvector of their
    # normal matrix, whose blocks are sums of 3x3 products, accumulated in chunks of poses:
    # (sum R_i R_i^T) kron I, -sum R_i kron R_m_i and I kron (sum R_m_i^T R_m_i), per target
    S_f, S_fm, S_m = np.zeros((3, 3)), np.zeros((K, 3, 3, 3, 3)), np.zeros((K, 3, 3))
    for a in range(0, N, CHUNK):
        Rf, Rm, r = R_f[a:a + CHUNK], R_meas[a:a + CHUNK], rows[a:a + CHUNK]
        # (the sums over the poses as matrix products: sum_n R_n R_n^T, sum_n R_n[a, c] Rm_n[b, d],
        # sum_n Rm_n^T Rm_n)
        Rt = np.ascontiguousarray(Rf.transpose(0, 2, 1)).reshape(-1, 3)
        S_f += Rt.T @ Rt
        for k in range(K):
            on = slice(None) if K == 1 else (r == k)    # (one target: every row, no copies)
            F, G = Rf[on].reshape(-1, 9), Rm[on].reshape(-1, 9)
            S_fm[k] += (F.T @ G).reshape(3, 3, 3, 3).transpose(0, 2, 1, 3)
            S_m[k] += G.reshape(-1, 3).T @ G.reshape(-1, 3)
    normal = np.zeros((9 + 9 * K, 9 + 9 * K))
    normal[:9, :9] = (S_f[:, None, :, None] * I3[None, :, None, :]).reshape(9, 9)     # S_f kron I
    for k in range(K):
        blk = slice(9 + 9 * k, 18 + 9 * k)
        normal[:9, blk] = -S_fm[k].reshape(9, 9)
        normal[blk, :9] = -S_fm[k].reshape(9, 9).T
        normal[blk, blk] = (I3[:, None, :, None] * S_m[k][None, :, None, :]).reshape(9, 9)   # I kron S_m
    w, V = np.linalg.eigh(normal)
    if w[1] < 1e-10 * w[-1]:
        raise DataError("the poses do not determine the measurement frame orientation "
                        "(too few distinct orientations)")
    v = V[:, 0]
    RX = v[:9].reshape(3, 3, order="F")
    scale = np.sign(np.linalg.det(RX)) * np.cbrt(abs(np.linalg.det(RX)))
    R_Y = np.array([project_to_so3(v[9 + 9 * k:18 + 9 * k].reshape(3, 3, order="F") / scale).T
                    for k in range(K)])
    return project_to_so3(RX / scale), R_Y


#: Three targets closer than this to a line (the distance of the third from the line through
#: the other two, metres) do not define an orientation.
TRIAD_MIN_M = 1e-3


def _triad_rotation(R_f, p_f, p_meas, rows, K) -> np.ndarray:
    """R_X (3, 3) from position-only rows of three or more targets measured at the same
    configurations: at each configuration where the three targets measured together most often
    were all measured (and are not collinear), their points define a frame rigidly attached to
    the flange (origin the first, x toward the second, z normal to the three), a full pose of a
    virtual tool; the rotations of those poses give R_X as full-pose data do (three such
    configurations suffice, where the linear position-only system needs 12 + 27 K / 3 rows).
    Raises :class:`DataError` when there are fewer than three such configurations."""
    from itertools import combinations

    N = len(R_f)
    key = np.round(np.hstack([R_f.reshape(N, 9), p_f]) / 1e-9) + 0.0      # rows of one configuration
    order = np.lexsort(key.T[::-1])
    new = np.concatenate([[True], np.any(key[order][1:] != key[order][:-1], axis=1)])
    group = np.empty(N, int)
    group[order] = np.cumsum(new) - 1
    G = int(group.max()) + 1
    seen = np.zeros((G, K), bool)
    seen[group, rows] = True
    triads = list(combinations(range(K), 3))
    if not triads:
        raise DataError("the position-only poses do not determine the measurement frame "
                        "(too few distinct configurations)")
    best = max(triads, key=lambda t: int(seen[:, list(t)].all(axis=1).sum()))
    at = np.flatnonzero(seen[:, list(best)].all(axis=1))
    # each target's point at each of those configurations (the mean of repeated rows)
    P = np.zeros((3, G, 3))
    for j, k in enumerate(best):
        on = rows == k
        np.add.at(P[j], group[on], p_meas[on])
        P[j] /= np.maximum(np.bincount(group[on], minlength=G), 1)[:, None]
    P = P[:, at]
    x = P[1] - P[0]
    n = np.cross(x, P[2] - P[0])
    ok = np.linalg.norm(n, axis=1) > TRIAD_MIN_M * np.linalg.norm(x, axis=1)
    if ok.sum() < 3:
        raise DataError("the position-only poses do not determine the measurement frame "
                        "(too few distinct configurations)")
    x = x[ok] / np.linalg.norm(x[ok], axis=1)[:, None]
    z = n[ok] / np.linalg.norm(n[ok], axis=1)[:, None]
    R_F = np.stack([x, np.cross(z, x), z], axis=2)                       # (M, 3, 3) columns x, y, z
    first = np.array([np.flatnonzero(group == g)[0] for g in at[ok]])
    R_X, _ = _rotations(R_f[first], R_F, np.zeros(len(first), int), 1)
    return R_X


def _estimate(robot: RobotModel, R_f, p_f, p_meas, R_meas, rows):
    K = robot.n_targets
    N = len(R_f)
    X = np.eye(4)
    Y = np.array([robot.T_flange_tool(k) for k in range(K)])
    I3 = np.eye(3)
    if R_meas is not None:
        if N < 3:
            raise DataError(f"at least 3 poses are needed to estimate the frames, got {N}")
        R_X, Y[:, :3, :3] = _rotations(R_f, R_meas, rows, K)
    else:
        n_unknown = 12 + 27 * K
        rank = 0
        if 3 * N >= n_unknown:
            A = np.zeros((N, 3, n_unknown))
            A[:, :, :9] = np.einsum("nj,ab->najb", p_f, I3).reshape(N, 3, 9)          # A p_i (A column-major)
            C = np.einsum("nj,ab->najb", R_f.reshape(N, 9), I3).reshape(N, 3, 27)     # sum_jk R_i[j,k] C_jk
            for k in range(K):
                A[rows == k, :, 9 + 27 * k:36 + 27 * k] = C[rows == k]
            A[:, :, -3:] = I3
            sol, _, rank, _ = np.linalg.lstsq(A.reshape(3 * N, -1), p_meas.reshape(-1), rcond=None)
        if rank == n_unknown:
            # A = sol[:9] (column-major) estimates R_X; with R_X fixed, (t_X, t_Y) are linear again
            R_X = project_to_so3(sol[:9].reshape(3, 3, order="F"))
        elif K >= 3:
            R_X = _triad_rotation(R_f, p_f, p_meas, rows, K)
        elif 3 * N < n_unknown:
            raise DataError(f"at least {-(-n_unknown // 3)} position-only poses are needed to estimate "
                            f"the frames, got {N}")
        else:
            raise DataError("the position-only poses do not determine the measurement frame "
                            "(too few distinct configurations)")
    t_X, t_Y = _solve_translations(R_X, R_f, p_f, p_meas, rows, K)
    X[:3, :3], X[:3, 3] = R_X, t_X
    Y[:, :3, 3] = t_Y
    return X, Y


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class FrameEstimate:
    """A robust closed-form frame estimate (:func:`estimate_frames_robust`).

    T_meas_base (4, 4); T_flange_targets (K, 4, 4), one per target (T_flange_tool: the first),
    metres. ``inliers`` : (N,) bool, the rows the final estimate was computed from;
    ``position_residual`` (N,) metres and ``rotation_residual`` (N,) radians (or None) of every
    row against it; ``threshold_position`` (m) and ``threshold_rotation`` (rad) the trimming
    thresholds of the last round.
    """

    T_meas_base: np.ndarray
    T_flange_targets: np.ndarray
    inliers: np.ndarray
    position_residual: np.ndarray
    rotation_residual: np.ndarray | None
    threshold_position: float
    threshold_rotation: float | None

    @property
    def T_flange_tool(self) -> np.ndarray:
        return self.T_flange_targets[0]


#: Trimming of :func:`estimate_frames_robust`: a row is left out when its residual exceeds the
#: median by more than TRIM_K robust standard deviations (1.4826 MAD), and at least the floors
#: (the estimate carries the nominal structure's error, millimetres, which must not be trimmed).
TRIM_K = 6.0
TRIM_FLOOR_M = 5e-3
TRIM_FLOOR_RAD = 0.02
TRIM_ROUNDS = 10


def median(x: np.ndarray) -> float:
    """The median of the values x (any shape), as np.median computes it (the middle value, or
    the mean of the two middle ones; nan when x holds a nan), without np.median's import of
    numpy.ma (20 ms of the command line's start)."""
    s = np.sort(np.asarray(x, float), axis=None)
    n = len(s)
    if n == 0 or np.isnan(s[-1]):
        return float("nan")
    return float(s[n // 2]) if n % 2 else float(np.mean(s[n // 2 - 1:n // 2 + 1]))


def _threshold(r: np.ndarray, floor: float) -> float:
    med = median(r)
    return max(med + TRIM_K * 1.4826 * median(np.abs(r - med)), floor)


def estimate_frames_robust(robot: RobotModel, Q: np.ndarray, p_meas: np.ndarray,
                           R_meas: np.ndarray | None = None, targets: np.ndarray | None = None, *,
                           kin: ChainKinematics | None = None) -> FrameEstimate:
    """:func:`estimate_target_frames` made robust to gross rows by residual-based trimming.

    The closed-form estimate is computed from all rows, every row's residual against it is
    taken (position: metres; orientation: radians), rows beyond the median by more than
    ``TRIM_K`` robust standard deviations (and beyond ``TRIM_FLOOR_M`` / ``TRIM_FLOOR_RAD``)
    are left out and the estimate is repeated, until the kept rows do not change. A single row
    a million kilometres off moves the least-squares translation of N rows by 1/N of that, all
    good rows then share about the same residual and the gross row stands out; it is left out
    in the first round. Arguments and errors as :func:`estimate_target_frames`; ``kin``:
    ``robot``'s kinematics at its values to reuse (default: built).
    """
    R_f, p_f = _flange_in_base(robot, Q, kin)
    N = len(Q)
    rows = np.zeros(N, int) if targets is None else np.asarray(targets, int)
    keep = np.ones(N, bool)
    minimum = 3 if R_meas is not None else 12 + 27 * robot.n_targets
    for _ in range(TRIM_ROUNDS):
        X, Y = _estimate(robot, R_f[keep], p_f[keep], p_meas[keep],
                         None if R_meas is None else R_meas[keep], rows[keep])
        Yr = Y[0][None] if len(Y) == 1 else Y[rows]      # (one target: broadcast, no copies)
        p_est = X[:3, 3] + (p_f + (R_f @ Yr[:, :3, 3, None])[..., 0]) @ X[:3, :3].T
        e_pos = np.linalg.norm(p_est - p_meas, axis=1)
        thr_p, thr_r, e_rot = _threshold(e_pos[keep], TRIM_FLOOR_M), None, None
        new = e_pos <= thr_p
        if R_meas is not None:
            R_est = X[:3, :3] @ R_f @ Yr[:, :3, :3]
            cos = (np.einsum("nij,nij->n", R_est, R_meas) - 1.0) / 2.0
            e_rot = np.arccos(np.clip(cos, -1.0, 1.0))
            thr_r = _threshold(e_rot[keep], TRIM_FLOOR_RAD)
            new &= e_rot <= thr_r
        if np.array_equal(new, keep) or 3 * new.sum() < minimum:
            break
        keep = new
    return FrameEstimate(X, Y, keep, e_pos, e_rot, thr_p, thr_r)
