"""Predictions over the workspace: the error of a calibrated model expected at random
configurations within the joint limits, from the covariance of its free parameters
(:func:`predict_workspace`), how much of each joint's range the calibration poses span
(:func:`joint_coverage`), and the note when the workspace figure is far above the one at the
calibration configurations (:func:`workspace_notes`).

The figures at the calibration configurations (:func:`calib.calibration.accuracy.statistics.statistics_stage`)
say how well the model predicts poses like the measured ones; 40 rows bunched near a wrist
singularity predict themselves to 0.1 mm while random configurations err by millimetres. The
same covariance propagated through the pose Jacobian at random configurations says so.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from calib.errors import DataError
from calib.memo import Memo
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.solvers.problem import CHUNK_POSES

__all__ = ["WORKSPACE_CONFIGURATIONS", "WORKSPACE_SEED", "WORKSPACE_RATIO", "POOR_COVERAGE",
           "propagate_covariance", "workspace_configurations", "joint_coverage", "predict_workspace",
           "workspace_notes", "predicted_tool_error", "workspace_dict"]

#: Random configurations of the workspace prediction: the RMS over them has a relative sampling
#: error of about 1/sqrt(2 n) for a smooth error field (7 % at 100, 4 % at 300), far inside the
#: factor 2 its note is about; 300 cost 2 ms of the 100-pose calibrate() (8.5 -> 11.3 ms CPU),
#: 100 cost 0.7 ms (scripts/bench_workspace.py).
WORKSPACE_CONFIGURATIONS = 100
#: Configurations per Jacobian chunk of the workspace prediction: small chunks stay in the cache
#: (300 configurations of a 6-axis arm: 0.65 ms in chunks of 100, 1.3 ms in one).
WORKSPACE_CHUNK = 100
#: Seed of the random configurations: the same model and covariance give the same figure.
WORKSPACE_SEED = 0
#: A note when the predicted error on new rows over the workspace exceeds the one at the
#: calibration configurations by more than this factor.
WORKSPACE_RATIO = 2.0
#: A joint whose calibration angles span less than this fraction of its range is named in the note.
POOR_COVERAGE = 0.5

_FULL_TURN = 2.0 * math.pi


def propagate_covariance(model: RobotModel, Q: np.ndarray, free: Sequence[str], C: np.ndarray,
                         kin: ChainKinematics | None = None,
                         targets: np.ndarray | None = None, chunk: int = CHUNK_POSES) -> tuple[float, float]:
    """(position, rotation) RMS over configurations Q (N, n_joints; rad, m) of the pose error
    that a parameter error of covariance C (free parameters, SI) causes: sqrt of the mean trace
    of J C J^T over the position (m) and the rotation (rad) block of the pose Jacobian J (meas
    frame); targets : (N,) each row's target index for a multi-target model. The Jacobian is
    computed in chunks of ``chunk`` configurations (memory bounded by the chunk)."""
    kin = kin or ChainKinematics(model)
    kin.set_values(model.values)
    idx = model.indices(free)
    jacobians = (pose_jacobian(kin, Q[s:s + chunk], idx, targets=None if targets is None else targets[s:s + chunk])[2]
                 for s in range(0, len(Q), chunk))
    return propagated(jacobians, len(Q), C)


def propagated(jacobians, n: int, C: np.ndarray) -> tuple[float, float]:
    """(position, rotation) RMS over n poses of J C J^T, from their pose Jacobians (an iterable
    of chunks of shape (k, 6, m); m the rows of C)."""
    tr_p = tr_r = 0.0
    for Jf in jacobians:
        # (one (6 k, m) x (m, m) product: a stack of k products calls BLAS k times)
        JC = (Jf.reshape(-1, Jf.shape[2]) @ C).reshape(Jf.shape)
        tr_p += float(np.einsum("nij,nij->", JC[:, :3], Jf[:, :3]))
        tr_r += float(np.einsum("nij,nij->", JC[:, 3:], Jf[:, 3:]))
    n = max(n, 1)
    return math.sqrt(max(tr_p, 0.0) / n), math.sqrt(max(tr_r, 0.0) / n)


def _circular(robot: RobotModel) -> np.ndarray:
    """(n,) bool: revolute joints whose range is a full turn or more (continuous joints included):
    every angle is reachable, so their range is the circle."""
    span = robot.upper - robot.lower
    return ~robot.prismatic & ~(span < _FULL_TURN)


def workspace_configurations(robot: RobotModel, n: int = WORKSPACE_CONFIGURATIONS, seed: int = WORKSPACE_SEED,
                             calibration_q: np.ndarray | None = None) -> np.ndarray:
    """(n, n_joints) configurations drawn uniformly within the joint limits (radians, metres).

    A revolute joint whose range is a full turn or more (a continuous joint, a UR joint of
    +-2 pi) is drawn over one turn, [-pi, pi): further turns give the same poses. A prismatic
    joint without limits is drawn over the span of its values in ``calibration_q`` ((N, n_joints),
    the calibration configurations); without them it is a :class:`DataError`.
    """
    lo, hi = robot.lower.astype(float).copy(), robot.upper.astype(float).copy()
    circ = _circular(robot)
    lo[circ], hi[circ] = -math.pi, math.pi
    open_ = robot.prismatic & ~(np.isfinite(lo) & np.isfinite(hi))
    if open_.any():
        if calibration_q is None or len(calibration_q) == 0:
            names = ", ".join(np.asarray(robot.joint_names)[open_])
            raise DataError(f"prismatic joint(s) {names} have no limits: the workspace prediction needs "
                            f"limits in the URDF or calibration configurations to take the range from")
        q = np.asarray(calibration_q, float)
        lo[open_], hi[open_] = q[:, open_].min(axis=0), q[:, open_].max(axis=0)
    # (the same draw for the same ranges: kept for the next calibrations)
    def draw():
        Q = np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))
        Q.setflags(write=False)
        return Q

    return DRAWS.kept((lo.tobytes(), hi.tobytes(), int(n), int(seed)), draw).copy()


DRAWS = Memo("workspace draws", 8)


#: Bins of the circle when measuring the arc that angles cover (in O(N), not a sort: a 1M-row
#: calibration would spend 0.7 s sorting); the arc is exact to 2 bins, 3e-5 of a turn.
_ARC_BINS = 1 << 16


#: Below this many angles the covered arc is computed by sorting them (exact), above by binning.
_ARC_SORT_BELOW = 20_000


def _arc_covered(q: np.ndarray) -> float:
    """The fraction of the circle that angles q (rad) span: a full turn less the largest gap
    between neighbouring angles, to 2 / _ARC_BINS of a turn."""
    if len(q) == 0:
        return 0.0
    if len(q) < _ARC_SORT_BELOW:
        # few angles: sorted, exact (the bins cost 0.45 ms of a 100-row calibration)
        a = np.sort(np.mod(q, _FULL_TURN))
        gaps = np.diff(np.concatenate([a, a[:1] + _FULL_TURN]))
        return float(1.0 - gaps.max() / _FULL_TURN) if len(a) > 1 else 0.0
    k = np.minimum((np.mod(q, _FULL_TURN) * (_ARC_BINS / _FULL_TURN)).astype(np.int64), _ARC_BINS - 1)
    occupied = np.flatnonzero(np.bincount(k, minlength=_ARC_BINS))
    # gaps between occupied bins, the wrap-around one included, counted in empty bins between them
    gaps = np.diff(np.concatenate([occupied, occupied[:1] + _ARC_BINS])) - 1
    if len(occupied) < 2:
        return 0.0
    # the extreme angles lie within the first and last occupied bins: their arc, to +-1 bin
    return float(_ARC_BINS - gaps.max() - 1) / _ARC_BINS


def joint_coverage(robot: RobotModel, Q: np.ndarray) -> dict[str, float | None]:
    """The fraction (0..1) of each joint's range that the configurations Q (N, n_joints; rad, m)
    span, by joint name: (max - min) / (upper - lower), and for a joint with a full turn of range
    the arc the angles cover (a full turn less the largest gap between neighbouring angles on the
    circle). None for a prismatic joint without limits (its range is not known)."""
    Q = np.asarray(Q, float)
    circ = _circular(robot)
    lower, upper = robot.lower.tolist(), robot.upper.tolist()
    spans = (Q.max(axis=0) - Q.min(axis=0)).tolist() if len(Q) else [0.0] * robot.n_joints
    out: dict[str, float | None] = {}
    for j, name in enumerate(robot.joint_names):
        if circ[j]:
            out[name] = _arc_covered(Q[:, j])
        elif math.isfinite(lower[j]) and math.isfinite(upper[j]) and upper[j] > lower[j]:
            out[name] = float(min(spans[j] / (upper[j] - lower[j]), 1.0))
        else:
            out[name] = None
    return out


def predict_workspace(robot: RobotModel, free: Sequence[str], covariance: np.ndarray, sigma_pos: float,
                      sigma_rot: float | None, *, calibration_q: np.ndarray | None = None,
                      n: int = WORKSPACE_CONFIGURATIONS, seed: int = WORKSPACE_SEED,
                      kin: ChainKinematics | None = None) -> dict:
    """The predicted RMS error of ``robot`` over random configurations within its joint limits.

    Parameters
    ----------
    robot : the calibrated model (linearised at its values).
    free : names of the free parameters, the order of ``covariance``'s rows.
    covariance : (m, m) covariance of the free parameters (SI units): least squares' or the
        posterior of a MAP estimate.
    sigma_pos : position noise of a new measured row per axis, metres; sigma_rot : orientation
        noise per axis, radians (None for position-only data: no rotation figures).
    calibration_q : (N, n_joints) the calibration configurations (rad, m): the coverage of each
        joint's range is reported, and an unlimited prismatic joint is drawn over their span.
    n, seed : how many random configurations (:func:`workspace_configurations`) and their seed.
    kin : a kinematics workspace of ``robot``'s structure (reused; its values are set).

    A multi-target model's configurations take its targets in turn (row k: target k mod the
    number of targets).

    Returns a dict: ``position_rms`` (m) / ``rotation_rms`` (rad, None position only): RMS
    error of a new measured row, sqrt(mean_q tr(J C J^T) + 3 sigma^2) over the position (or
    rotation) block of the pose Jacobian J at the configurations; ``model_position_rms`` /
    ``model_rotation_rms``: the parameter uncertainty alone (the calibrated model against the
    true poses); ``configurations``, ``seed``; ``joint_coverage`` (:func:`joint_coverage` of
    ``calibration_q``, {} without); ``where``.
    """
    Q = workspace_configurations(robot, n, seed, calibration_q)
    targets = np.arange(n) % robot.n_targets if robot.targets else None
    pos, rot = propagate_covariance(robot, Q, tuple(free), np.asarray(covariance, float), kin, targets,
                                    WORKSPACE_CHUNK)
    has_rot = sigma_rot is not None
    return {"position_rms": math.sqrt(pos ** 2 + 3.0 * sigma_pos ** 2),
            "rotation_rms": math.sqrt(rot ** 2 + 3.0 * sigma_rot ** 2) if has_rot else None,
            "model_position_rms": pos, "model_rotation_rms": rot if has_rot else None,
            "configurations": int(n), "seed": int(seed),
            "joint_coverage": {} if calibration_q is None else joint_coverage(robot, calibration_q),
            "where": "random configurations within the joint limits"}


def workspace_notes(at_calibration: Mapping | None, workspace: Mapping | None,
                    ratio: float = WORKSPACE_RATIO) -> list[str]:
    """A note when the predicted error on new rows over the workspace (``workspace``, from
    :func:`predict_workspace`) exceeds the one at the calibration configurations
    (``at_calibration``: position_rms m, rotation_rms rad, where) by more than ``ratio``, in
    position or in orientation: what to add, naming the joints whose range the calibration
    poses span poorly (under :data:`POOR_COVERAGE` of it)."""
    if not at_calibration or not workspace:
        return []
    worse = []
    for key, label, unit, scale in (("position_rms", "position", "mm", 1e3), ("rotation_rms", "orientation", "rad", 1.0)):
        a, w = at_calibration.get(key), workspace.get(key)
        if a is not None and w is not None and a > 0 and w > ratio * a:
            worse.append(f"{label} {w * scale:.3g} {unit}, {w / a:.1f}x the {a * scale:.3g} {unit}")
    if not worse:
        return []
    where = at_calibration.get("where", "calibration configurations")
    poor = sorted(((c, j) for j, c in (workspace.get("joint_coverage") or {}).items()
                   if c is not None and c < POOR_COVERAGE))
    if poor:
        what = ("add poses spread over the joint ranges: the poses span only " +
                ", ".join(f"{100 * c:.0f}% of the range of {j}" if k == 0 else f"{100 * c:.0f}% of {j}"
                          for k, (c, j) in enumerate(poor)))
    else:
        what = ("the poses span at least half of each joint's range, so they sit near a singular "
                "configuration or in a corner of the workspace: add poses spread over the joint ranges "
                "and away from singular configurations")
    return [f"the predicted error on new rows over the workspace ({workspace.get('where')}) is "
            f"{'; '.join(worse)} predicted at the {where}: the calibrated model is known well only "
            f"near the measured poses; {what}"]


def predicted_tool_error(model: RobotModel, free: Sequence[str], covariance: np.ndarray, Q: np.ndarray,
                         registration: str = "rigid") -> float:
    """The Cramer-Rao prediction of the RMS error of ``model``'s tool positions at Q (N, n) after
    a best-fit rigid (or similarity) registration (``"none"``: in the meas frame, for a fit whose
    measured rows identified it): sqrt(trace(P Jt C Jt^T P) / N), Jt the tool positions' Jacobian
    in the free parameters ``free`` (3 N, m), C their covariance (m, m), P the projection off the
    rigid motions (and the scaling) of the N points, linearised. It covers the noise only: the
    parameters held at their nominal values (a gauge such as the scale of point-only data) add
    their own errors."""
    kin = ChainKinematics(model)
    idx = model.indices(free)
    _, p, J = pose_jacobian(kin, Q, idx)
    Jt = J[:, :3].reshape(-1, len(idx))
    N = len(Q)
    if registration == "none":
        PJ = Jt
    else:
        G = np.zeros((N, 3, 7))
        G[:, :, :3] = np.eye(3)
        c = p - p.mean(axis=0)
        G[:, 0, 4], G[:, 0, 5] = c[:, 2], -c[:, 1]          # w x c: the columns of -[c]x
        G[:, 1, 3], G[:, 1, 5] = -c[:, 2], c[:, 0]
        G[:, 2, 3], G[:, 2, 4] = c[:, 1], -c[:, 0]
        G[:, :, 6] = c                                     # a scaling about the centroid
        Qg = np.linalg.qr(G[:, :, :7 if registration == "similarity" else 6].reshape(3 * N, -1))[0]
        PJ = Jt - Qg @ (Qg.T @ Jt)
    return float(np.sqrt(max(np.einsum("ij,jk,ik->", PJ, np.asarray(covariance, float), PJ), 0.0) / N))


def workspace_dict(pw: dict | None) -> dict | None:
    """The JSON form of :func:`calib.calibration.accuracy.workspace.predict_workspace`'s figures (mm, rad)."""
    if pw is None:
        return None
    return {"position_mm": pw["position_rms"] * 1e3, "rotation_rad": pw.get("rotation_rms"),
            "model_position_mm": pw["model_position_rms"] * 1e3, "model_rotation_rad": pw.get("model_rotation_rms"),
            "configurations": pw["configurations"], "seed": pw["seed"], "where": pw["where"],
            "joint_coverage": dict(pw.get("joint_coverage") or {})}
