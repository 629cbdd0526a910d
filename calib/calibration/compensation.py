"""Compensation, the fourth step of calibration: joint values that make the real robot reach its
targets.

A robot controller computes joint values with its nominal model. After calibration, the
calibrated model tells where the tool really goes; compensation finds, for each target, the joint
values with which the *calibrated* model puts the tool at the target pose. Sending those to the
controller instead of the nominal ones removes the calibrated part of the error.

Targets, all in the meas frame (the base frame of the nominal model, in which the tool poses were
measured):

* joint targets (:func:`compensate`): the joint values ``q_nominal`` the controller would use;
  the target is the nominal model's tool pose there, ``T_meas_tool = nominal FK(q_nominal)``;
* pose targets (:func:`compensate_poses`): tool poses ``T_meas_tool`` (N, 4, 4), or tool
  positions ``p_meas_tool`` (N, 3) for position-only targets.

Solver
------
Damped Gauss-Newton (Levenberg-Marquardt) on the 6-D pose error, all targets at once:

    e = (p_target - p(q),  log(R_target R(q)^T))         metres, radians, in the meas frame
    dq = J^T (J J^T + mu I)^-1 e

with ``J`` the calibrated model's (6, n) joint Jacobian of the tool frame (linear velocity of the
tool origin and angular velocity, both in the meas frame; Pinocchio's ``LOCAL_WORLD_ALIGNED``
frame Jacobian of :class:`calib.model.kinematics.ChainKinematics`). For position targets the 3-D problem
``e = p_target - p(q)`` with the three position rows is solved. With more joints than rows
(redundant arms, or 6 joints and a position target) the step is the least-norm joint change.
``mu`` starts at 1e-12 (plain Gauss-Newton: the start is close) and is raised tenfold whenever a
step does not reduce ``|e|``, lowered tenfold after each step that does; the iterations stop when
``|e_pos| < 1e-3 tol_pos`` and ``|e_rot| < 1e-3 tol_rot``, when a step no longer reduces the
error (rounding floor), when mu exceeds 1e6, or after ``max_iterations``. A start at the nominal
joints is millimetres away from the solution, and 3 to 5 iterations reach 1e-13 m.

Status of each target (never silently clipped: the joint values are returned as computed)
-------------------------------------------------------------------------------------------
* ``"singular"``: the smallest singular value of the joint Jacobian (position rows in metres
  per radian or metre per metre, rotation rows in radians per radian: the 6 x n matrix as it is)
  at the start or at the result is below ``singular_threshold`` (default
  :data:`SINGULAR_THRESHOLD` = 1e-2). A pose error e may then need a joint change up to
  ``|e| / sigma_min``: 0.1 rad (5.7 deg) for 1 mm or 1 mrad, and the calibration's own
  uncertainty is amplified as much. For a 6R arm this flags the wrist singularity (axes 4 and 6
  aligned) within about 1e-2 rad of joint 5, and the shoulder and elbow singularities likewise.
  The 3-row position Jacobian is used for position targets, so a wrist singularity does not
  matter there.
* ``"not_converged"``: the residual stayed above ``tol_pos`` (metres) or ``tol_rot`` (radians);
  e.g. a pose a 5-axis arm cannot reach.
* ``"limit"``: converged, but a joint is outside its limits (by more than 1e-12 rad or m);
  :attr:`CompensationResult.limit_excess` says which joint and by how much.
* ``"ok"``: converged within the joint limits away from singularities.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from calib.checks import check_int, check_rng
from calib.choices import SINGULAR_THRESHOLD
from calib.model.robot import check_robot
from calib.errors import CalibError, DataError, ParameterError
from calib.model.jacobian import MEASURES
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import finite_array
from calib.model.robot import RobotModel
from calib.io.urdf_reader import load_robot, read_urdf_chain, robot_from_chain, robot_path
from calib.io.urdf import UrdfDocument
from calib.model.spatial import log3_batch

__all__ = ["STATUSES", "SINGULAR_THRESHOLD", "CompensationResult", "compensate",
           "compensate_poses", "load_compensation_models", "check_joint_targets"]

#: Statuses of a target, from the most to the least severe (see the module docstring).
STATUSES = ("singular", "not_converged", "limit", "ok")
#: Default threshold on the smallest singular value of the joint Jacobian (see the module docstring).
#: Default residual tolerances: a target is reached when both errors are below them.
TOL_POS_M = 1e-10
TOL_ROT_RAD = 1e-10
#: Joint values further than this beyond a limit (rad or m) are reported (rounding allowance).
LIMIT_SLACK = 1e-12
#: Least-norm joint change of redundant problems: null-space passes at most, and the size
#: (rad or m) of the null-space part of ``q - q_start`` below which the passes stop.
NULL_SPACE_PASSES = 30
NULL_SPACE_TOL = 1e-12
#: Number of random starts (besides the middle of the joint ranges) of
#: :func:`compensate_poses` without ``q_start``.
RANDOM_STARTS = 16


# ====================================================================== result
@dataclass(frozen=True, eq=False)
class CompensationResult:
    """Corrected joint values for a batch of targets (compare scipy's ``OptimizeResult``).

    Attributes
    ----------
    q : (N, n) float, radians (metres for prismatic joints): corrected joint values, with which
        the calibrated model reaches the targets (when ``status`` is ``"ok"``). Never clipped.
    q_start : (N, n) float: the joint values the solver started from (the nominal joints).
    status : (N,) str, each one of :data:`STATUSES`.
    position_error : (N,) float, metres: ``|p_calibrated(q) - p_target|`` in the meas frame.
    rotation_error : (N,) float, radians: angle of ``R_target R_calibrated(q)^T``; None for
        position targets.
    limit_excess : (N, n) float, rad / m: how far each joint is beyond its limits (positive above
        the upper limit, negative below the lower one, 0 within).
    min_singular_value : (N,) float: smallest singular value of the joint Jacobian, the smaller of
        the start and the result (see the module docstring for its units).
    iterations : (N,) int: solver iterations per target.
    measure : "pose" or "position".
    target_position : (N, 3) metres; target_rotation : (N, 3, 3) or None; both in the meas frame.
    joint_names : (n,) the joint names; prismatic : (n,) bool, which joints are prismatic.
    singular_threshold, tol_pos, tol_rot : the thresholds used.
    """

    q: np.ndarray
    q_start: np.ndarray
    status: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray | None
    limit_excess: np.ndarray
    min_singular_value: np.ndarray
    iterations: np.ndarray
    measure: str
    target_position: np.ndarray = field(repr=False)
    target_rotation: np.ndarray | None = field(repr=False)
    joint_names: tuple[str, ...]
    prismatic: np.ndarray = field(repr=False)
    singular_threshold: float = SINGULAR_THRESHOLD
    tol_pos: float = TOL_POS_M
    tol_rot: float = TOL_ROT_RAD

    @property
    def n_targets(self) -> int:
        return self.q.shape[0]

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: targets with status ``"ok"``."""
        return self.status == "ok"

    @property
    def success(self) -> bool:
        """True when every target is ``"ok"``."""
        return bool(self.ok.all())

    def counts(self) -> dict[str, int]:
        """Number of targets per status (every status present as a key)."""
        return {s: int((self.status == s).sum()) for s in STATUSES}

    def describe(self, k: int) -> str:
        """Why target k (0-based) is not ok, in one line ("ok" if it is); joint excesses in
        degrees (mm for prismatic joints), residuals in mm and rad."""
        k = check_int(k, "k", maximum=self.n_targets - 1)
        parts = []
        if self.min_singular_value[k] < self.singular_threshold:
            parts.append(f"near a singularity: smallest singular value of the joint Jacobian "
                         f"{self.min_singular_value[k]:.3g} < {self.singular_threshold:g}")
        if self.position_error[k] >= self.tol_pos or (
                self.rotation_error is not None and self.rotation_error[k] >= self.tol_rot):
            rot = "" if self.rotation_error is None else f", {self.rotation_error[k]:.3g} rad"
            parts.append(f"target not reached: residual {self.position_error[k] * 1e3:.3g} mm{rot}")
        for i in np.flatnonzero(self.limit_excess[k]):
            x = self.limit_excess[k, i]
            unit, scale = ("mm", 1e3) if self.prismatic[i] else ("deg", 180.0 / math.pi)
            side = "upper" if x > 0 else "lower"
            parts.append(f"{self.joint_names[i]} beyond its {side} limit by {abs(x) * scale:.6g} {unit}")
        return "; ".join(parts) if parts else "ok"

    def format(self) -> str:
        """A summary for a person: counts per status, the largest residuals and joint changes of
        the ok targets, and the first ten targets that are not ok (numbered from 1)."""
        c = self.counts()
        lines = [f"Compensated {self.n_targets} {self.measure} targets: "
                 + ", ".join(f"{v} {k}" for k, v in c.items())]
        ok = self.ok
        if ok.any():
            rot = "" if self.rotation_error is None else \
                f", orientation {self.rotation_error[ok].max():.3g} rad"
            change = np.abs(self.q[ok] - self.q_start[ok])
            scale = np.where(self.prismatic, 1e3, 180.0 / math.pi)
            lines.append(f"  ok targets: largest residual position {self.position_error[ok].max() * 1e3:.3g} "
                         f"mm{rot}; largest joint change "
                         + ", ".join(f"{n} {v:.4g} {'mm' if p else 'deg'}" for n, v, p in
                                     zip(self.joint_names, (change * scale).max(axis=0), self.prismatic)))
        for k in np.flatnonzero(~ok)[:10]:
            lines.append(f"  target {k + 1}: {self.status[k]}: {self.describe(int(k))}")
        if (~ok).sum() > 10:
            lines.append(f"  ... and {int((~ok).sum()) - 10} more targets that are not ok")
        return "\n".join(lines)


# ====================================================================== public API
def compensate(calibrated: RobotModel, nominal: RobotModel, q_nominal: np.ndarray, *,
               measure: str = "pose", singular_threshold: float = SINGULAR_THRESHOLD,
               tol_pos: float = TOL_POS_M, tol_rot: float = TOL_ROT_RAD,
               max_iterations: int = 100) -> CompensationResult:
    """Corrected joint values for targets given as the nominal controller's joint values.

    Parameters
    ----------
    calibrated : the calibrated model; nominal : the nominal model. Same joints (names, order),
        and their tool poses in the same meas frame (their ``base_frame``).
    q_nominal : (N, n) float, radians (metres for prismatic joints): the joint values the
        controller would use; the targets are the nominal tool poses there. They are also the
        start of the solver.
    measure : "pose" (reach the tool position and orientation) or "position" (the position only:
        the least-norm joint change).
    singular_threshold : see the module docstring; tol_pos (m), tol_rot (rad): residual
        tolerances of a reached target; max_iterations : per target.

    Returns a :class:`CompensationResult` with a status per target. Raises
    :class:`calib.CalibError` subclasses for incompatible models or bad arrays.
    """
    _check_models(calibrated, nominal)
    _check_options(measure, singular_threshold, tol_pos, tol_rot, max_iterations)
    q0 = _joint_array(q_nominal, nominal, "q_nominal")
    R_t, p_t = ChainKinematics(nominal).frame_poses(q0)
    if measure == "position":
        R_t = None
    return _solve(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)


def compensate_poses(calibrated: RobotModel, *, T_meas_tool: np.ndarray | None = None,
                     p_meas_tool: np.ndarray | None = None, q_start: np.ndarray | None = None,
                     singular_threshold: float = SINGULAR_THRESHOLD, tol_pos: float = TOL_POS_M,
                     tol_rot: float = TOL_ROT_RAD, max_iterations: int = 100,
                     seed: int = 0) -> CompensationResult:
    """Joint values with which the calibrated model reaches given tool poses or positions.

    Parameters
    ----------
    calibrated : the calibrated model.
    T_meas_tool : (N, 4, 4) float, metres: target tool poses in the meas frame; or
    p_meas_tool : (N, 3) float, metres: target tool positions in the meas frame (position-only
        targets). Give exactly one.
    q_start : (N, n) float, rad / m: the starting joint values, which choose the solution
        branch (e.g. the nominal controller's joints for the pose). Default: every target is
        solved from the middle of the joint ranges and from 16 random configurations (drawn with
        ``seed``); the result is the ``"ok"`` solution closest to the middle of the joint
        ranges (largest joint distance, scaled by the ranges), or, if none is ok, the one with the
        least severe status.
    Other parameters as :func:`compensate`.
    """
    check_robot(calibrated, "calibrated")
    check_rng(seed, "seed")
    _check_options("pose", singular_threshold, tol_pos, tol_rot, max_iterations)
    if (T_meas_tool is None) == (p_meas_tool is None):
        raise ParameterError("give exactly one of T_meas_tool (N, 4, 4) and p_meas_tool (N, 3)")
    if T_meas_tool is not None:
        T = finite_array(T_meas_tool, "T_meas_tool")
        if T.ndim == 2:
            T = T[None]
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise DataError(f"T_meas_tool must be (N, 4, 4), got shape {T.shape}")
        R_t, p_t = T[:, :3, :3], T[:, :3, 3]
        err = np.abs(R_t @ np.transpose(R_t, (0, 2, 1)) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero((err > 1e-6) | (np.linalg.det(R_t) <= 0))
        if len(bad):
            raise DataError(f"T_meas_tool[{bad[0]}] has no rotation matrix in its upper left 3 x 3 "
                            f"block (orthonormal with determinant +1 to 1e-6)")
    else:
        p_t = finite_array(p_meas_tool, "p_meas_tool")
        if p_t.ndim == 1:
            p_t = p_t[None]
        if p_t.ndim != 2 or p_t.shape[1] != 3:
            raise DataError(f"p_meas_tool must be (N, 3), got shape {p_t.shape}")
        R_t = None
    N = len(p_t)
    if q_start is not None:
        q0 = _joint_array(q_start, calibrated, "q_start")
        if len(q0) != N:
            raise DataError(f"q_start has {len(q0)} rows for {N} targets")
        return _solve(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)

    lo, hi = _finite_limits(calibrated)
    mid, half = (lo + hi) / 2, np.where(hi > lo, (hi - lo) / 2, 1.0)
    starts = np.vstack([mid[None], calibrated.random_configurations(RANDOM_STARTS, seed)])
    S = len(starts)
    q0 = np.tile(starts, (N, 1))                       # target k, start s at row k S + s
    res = _solve(calibrated, q0, np.repeat(p_t, S, axis=0),
                 None if R_t is None else np.repeat(R_t, S, axis=0), singular_threshold, tol_pos,
                 tol_rot, max_iterations)
    severity = np.array([STATUSES.index(s) for s in res.status]).reshape(N, S)
    distance = (np.abs(res.q - mid) / half).max(axis=1).reshape(N, S)
    # per target: the least severe status first, then the smallest distance from the middle
    choice = np.lexsort((distance, -severity), axis=-1)[:, 0]
    pick = np.arange(N) * S + choice
    return _take(res, pick)


# ====================================================================== models and checks
def load_compensation_models(calibrated_urdf: str | Path, nominal_urdf: str | Path, *,
                             base_frame: str | None = None,
                             tool_frame: str | None = None) -> tuple[RobotModel, RobotModel]:
    """(calibrated, nominal) models whose tool poses are expressed in the same meas frame.

    ``base_frame`` and ``tool_frame`` name frames of the nominal URDF (default: the nominal
    frames the calibrated URDF records, else as :func:`calib.load_robot`). The calibrated URDF written by calib
    (:func:`calib.io.urdf_writer.write_calibrated_urdf`) records which of its links stand for the
    nominal base and tool frames (it may have added a link ``tool``); :func:`calib.load_robot`
    maps the nominal frames to them (:meth:`calib.io.urdf.UrdfDocument.resolve_frames`). A URDF
    without that record is read with the same frame names.

    Raises :class:`calib.CalibError` when the two chains have different joints.
    """
    document = UrdfDocument.read(robot_path(calibrated_urdf))     # read once, parsed below
    base_frame, tool_frame = nominal_frames(document, base_frame=base_frame, tool_frame=tool_frame)
    nominal = load_robot(nominal_urdf, base_frame=base_frame, tool_frame=tool_frame)
    calibrated = robot_from_chain(read_urdf_chain(calibrated_urdf, nominal.base_frame, nominal.tool_frame,
                                                  document=document))
    _check_models(calibrated, nominal)
    return calibrated, nominal


def _calibrated_document(calibrated: str | Path | UrdfDocument | RobotModel) -> UrdfDocument | None:
    """The document of a calibrated URDF: read from a path, as given, or the one a model read
    from it carries (None for a model built in code)."""
    if isinstance(calibrated, RobotModel):
        return None if calibrated.source is None else calibrated.source.document
    if isinstance(calibrated, UrdfDocument):
        return calibrated
    return UrdfDocument.read(robot_path(calibrated))


def nominal_frames(calibrated_urdf: str | Path | UrdfDocument | RobotModel, *, base_frame: str | None = None,
                   tool_frame: str | None = None) -> tuple[str | None, str | None]:
    """(base_frame, tool_frame) of the nominal URDF for a calibrated one (a path, its document,
    or the model read from it): the given names, else the nominal frames the calibrated URDF
    records (``<calib:frames>``), else None (the defaults of :func:`calib.load_robot`)."""
    document = _calibrated_document(calibrated_urdf)
    recorded = None if document is None else document.frames
    if recorded is not None:      # default: the nominal frames the calibration was made for
        base_frame = base_frame or recorded.nominal_base_frame
        tool_frame = tool_frame or recorded.nominal_tool_frame
    return base_frame, tool_frame


def check_joint_targets(calibrated_urdf: str | Path | UrdfDocument | RobotModel) -> None:
    """Refuse joint targets for a calibrated URDF whose measurement or tool frame the calibration
    estimated from the data (its ``<calib:frames>`` record): a joint target stands for the nominal
    tool's pose in the nominal base frame, and that model's base frame is the instrument's, its
    tool the measured point (compensating the nominal tool with it moves the measured point onto
    the tool's poses: joint changes of tens of degrees, each one "ok"). Pose targets, given in
    the measurement frame for the measured point, apply."""
    document = _calibrated_document(calibrated_urdf)
    rec = None if document is None else document.frames
    path = None if document is None else document.path
    if rec is None or not (rec.measurement_estimated or rec.tool_estimated):
        return
    what = [w for w, flag in (("the measurement frame (the instrument's, not the robot's base)",
                               rec.measurement_estimated),
                              ("the tool frame (the measured point, not the nominal tool)", rec.tool_estimated))
            if flag]
    raise CalibError(f"{path}: the calibration estimated {' and '.join(what)} from the data: joint targets "
                     f"stand for poses of the nominal tool in the nominal base frame, which this model does "
                     f"not hold; give pose targets of the measured point in the measurement frame, or give "
                     f"the URDF the frames that were measured (the instrument, the measured point) and "
                     f"calibrate with --base-frame / --tool-frame naming them")


def _check_models(calibrated: RobotModel, nominal: RobotModel) -> None:
    check_robot(calibrated, "calibrated")
    check_robot(nominal, "nominal")
    if calibrated.targets:
        raise CalibError(f"the calibrated model holds {calibrated.n_targets} targets "
                         f"({', '.join(calibrated.targets)}) and no tool frame of its own: compensation "
                         f"needs the nominal tool, which a calibration of several targets does not "
                         f"identify")
    if calibrated.joint_names != nominal.joint_names:
        raise CalibError(f"the calibrated model's joints {list(calibrated.joint_names)} differ from "
                         f"the nominal model's {list(nominal.joint_names)}: compensation needs the "
                         f"same chain")
    if not np.array_equal(calibrated.prismatic, nominal.prismatic):
        raise CalibError("the calibrated and nominal models differ in which joints are prismatic")


def _check_options(measure, singular_threshold, tol_pos, tol_rot, max_iterations) -> None:
    if not isinstance(measure, str) or measure not in MEASURES:
        raise ParameterError(f"unknown measure {measure!r}: expected one of {', '.join(MEASURES)}")
    for name, value in (("singular_threshold", singular_threshold), ("tol_pos", tol_pos),
                        ("tol_rot", tol_rot)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    if tol_pos <= 0 or tol_rot <= 0:
        raise ParameterError("tol_pos and tol_rot must be positive")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise ParameterError(f"max_iterations must be a positive integer, got {max_iterations!r}")


def _joint_array(q, robot: RobotModel, name: str) -> np.ndarray:
    """(N, n) joint values from an array-like (one configuration may be given as (n,))."""
    q = finite_array(q, name)
    if q.ndim == 1:
        q = q[None]
    if q.ndim != 2 or q.shape[1] != robot.n_joints:
        raise DataError(f"{name} must be (N, {robot.n_joints}) joint values, got shape {q.shape}")
    return q


def _finite_limits(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    lo = np.where(np.isfinite(robot.lower), robot.lower, -math.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, math.pi)
    return lo, hi


# ====================================================================== solver
def tool_poses_and_joint_jacobians(kin: ChainKinematics, Q: np.ndarray):
    """Tool poses and joint Jacobians of a chain at configurations Q (N, n), rad / m.

    Returns (R (N, 3, 3), p (N, 3) metres, J (N, 6, n)): rows of J are the derivative of the
    tool position (metres per rad or m) then the tool's angular velocity (radians per rad or m),
    both in the meas frame (Pinocchio's LOCAL_WORLD_ALIGNED frame Jacobian).
    """
    model, data, fid = kin.model, kin.data, kin.tool_frame_id
    Q = kin.effective(Q)    # with compliance: the deflected joints (J neglects d tau / d q)
    N, n = Q.shape
    H = np.empty((N, 4, 4))
    J = np.empty((N, 6, n))
    qp = np.zeros(model.nq)
    for k in range(N):
        qp[:n] = Q[k]
        pin.computeJointJacobians(model, data, qp)
        H[k] = pin.updateFramePlacement(model, data, fid).homogeneous
        J[k] = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:, :n]
    return H[:, :3, :3], H[:, :3, 3], J


def _errors(R, p, R_t, p_t) -> np.ndarray:
    """(N, 6) or (N, 3) pose errors target - current: position (m), rotation vector (rad)."""
    e_p = p_t - p
    if R_t is None:
        return e_p
    return np.hstack([e_p, log3_batch(R_t @ np.transpose(R, (0, 2, 1)))])


class _Newton:
    """Damped Gauss-Newton iterations on a batch of targets (scratch state, see the module
    docstring): joint values ``q`` (N, n), Jacobians ``J`` (N, m, n) and errors ``e`` (N, m) at
    them, damping ``mu`` and iteration counts, updated in place."""

    def __init__(self, kin: ChainKinematics, q: np.ndarray, p_t, R_t, tol_pos, tol_rot):
        self.kin, self.p_t, self.R_t = kin, p_t, R_t
        self.m = 3 if R_t is None else 6
        self.tol = (tol_pos, tol_rot)
        self.stop = (1e-3 * tol_pos, 1e-3 * tol_rot)
        self.q = q.copy()
        self.J, self.e = self.evaluate(self.q, np.arange(len(q)))
        self.cost = np.sum(self.e ** 2, axis=1)
        self.mu = np.full(len(q), 1e-12)
        self.iterations = np.zeros(len(q), int)

    def evaluate(self, q, idx):
        R, p, J = tool_poses_and_joint_jacobians(self.kin, q)
        e = _errors(R, p, None if self.R_t is None else self.R_t[idx], self.p_t[idx])
        return J[:, :self.m], e

    def run(self, idx: np.ndarray, max_iterations: int) -> None:
        """Iterate targets ``idx`` until reached (to 1e-3 tol), stalled, or until a target has
        made ``max_iterations`` iterations in all."""
        m = self.m
        active = np.zeros(len(self.q), bool)
        active[idx] = ~_reached(self.e[idx], *self.stop)
        while True:
            active &= self.iterations < max_iterations
            idx = np.flatnonzero(active)
            if not len(idx):
                break
            Ja, ea = self.J[idx], self.e[idx]
            A = Ja @ np.transpose(Ja, (0, 2, 1)) + self.mu[idx, None, None] * np.eye(m)
            dq = np.einsum("nmk,nm->nk", Ja, np.linalg.solve(A, ea[..., None])[..., 0])
            qn = self.q[idx] + dq
            Jn, en = self.evaluate(qn, idx)
            cn = np.sum(en ** 2, axis=1)
            self.iterations[idx] += 1
            better = cn < self.cost[idx]
            acc, rej = idx[better], idx[~better]
            self.q[acc], self.J[acc], self.e[acc], self.cost[acc] = qn[better], Jn[better], \
                en[better], cn[better]
            self.mu[acc] = np.maximum(self.mu[acc] / 10, 1e-15)
            self.mu[rej] *= 10
            # stop: reached, or no progress at the rounding floor, or damping blown up
            active[acc] = ~_reached(self.e[acc], *self.stop)
            active[rej[(self.mu[rej] > 1e6) | _reached(self.e[rej], *self.tol)]] = False

    def null_component(self, q0: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(len(idx), n): the part of ``q0 - q`` in the null space of J (exact projector)."""
        _, s, Vt = np.linalg.svd(self.J[idx])              # Vt (k, n, n), s (k, min(m, n))
        keep = np.zeros(Vt.shape[:2])
        keep[:, :s.shape[1]] = s > 1e-12 * s[:, :1]         # the row space of J
        w = q0[idx] - self.q[idx]
        coef = np.einsum("kij,kj->ki", Vt, w) * keep
        return w - np.einsum("kij,ki->kj", Vt, coef)


def _solve(robot: RobotModel, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot,
           max_iterations) -> CompensationResult:
    kin = ChainKinematics(robot)
    kin.set_values(robot.values, twists=False)
    newton = _Newton(kin, q0, p_t, R_t, tol_pos, tol_rot)
    sv_start = _min_singular_values(newton.J)
    everyone = np.arange(len(q0))
    newton.run(everyone, max_iterations)
    if robot.n_joints > newton.m:
        # redundant: move to the least-norm joint change. Alternate a step along the null
        # space of J back towards the start with Gauss-Newton steps back onto the target; at
        # the fixed point q - q0 lies in the row space of J (the first-order condition of
        # min |q - q0| subject to reaching the target).
        for _ in range(NULL_SPACE_PASSES):
            idx = everyone[_reached(newton.e, tol_pos, tol_rot)
                           & (newton.iterations < max_iterations)]
            if not len(idx):
                break
            step = newton.null_component(q0, idx)
            big = np.linalg.norm(step, axis=1) > NULL_SPACE_TOL
            idx, step = idx[big], step[big]
            if not len(idx):
                break
            newton.q[idx] += step
            newton.J[idx], newton.e[idx] = newton.evaluate(newton.q[idx], idx)
            newton.cost[idx] = np.sum(newton.e[idx] ** 2, axis=1)
            newton.mu[idx] = 1e-12
            newton.run(idx, max_iterations)
    q, J, e, iterations = newton.q, newton.J, newton.e, newton.iterations

    sv = np.minimum(sv_start, _min_singular_values(J))
    e_pos = np.linalg.norm(e[:, :3], axis=1)
    e_rot = None if R_t is None else np.linalg.norm(e[:, 3:], axis=1)
    reached = _reached(e, tol_pos, tol_rot)
    lo, hi = robot.lower, robot.upper
    excess = np.where(q > hi + LIMIT_SLACK, q - hi, 0.0) + np.where(q < lo - LIMIT_SLACK, q - lo, 0.0)
    status = np.where(sv < singular_threshold, "singular",
                      np.where(~reached, "not_converged",
                               np.where((excess != 0).any(axis=1), "limit", "ok"))).astype("<U13")
    for arr in (q, q0, status, e_pos, e_rot, excess, sv, iterations, p_t, R_t):
        if arr is not None:
            arr.setflags(write=False)
    return CompensationResult(
        q=q, q_start=q0, status=status, position_error=e_pos, rotation_error=e_rot,
        limit_excess=excess, min_singular_value=sv, iterations=iterations,
        measure="position" if R_t is None else "pose", target_position=p_t,
        target_rotation=R_t, joint_names=robot.joint_names,
        prismatic=robot.prismatic, singular_threshold=singular_threshold, tol_pos=tol_pos,
        tol_rot=tol_rot)


def _reached(e: np.ndarray, tol_pos: float, tol_rot: float) -> np.ndarray:
    ok = np.linalg.norm(e[:, :3], axis=1) < tol_pos
    if e.shape[1] == 6:
        ok &= np.linalg.norm(e[:, 3:], axis=1) < tol_rot
    return ok


def _min_singular_values(J: np.ndarray) -> np.ndarray:
    """Smallest of the min(rows, n) singular values of each Jacobian (N, rows, n)."""
    return np.linalg.svd(J, compute_uv=False)[:, -1]


def _take(res: CompensationResult, pick: np.ndarray) -> CompensationResult:
    """The targets ``pick`` of a result (a new result, arrays read-only)."""
    def sub(a):
        if a is None:
            return None
        out = np.array(a[pick])
        out.setflags(write=False)
        return out
    return CompensationResult(
        q=sub(res.q), q_start=sub(res.q_start), status=sub(res.status),
        position_error=sub(res.position_error), rotation_error=sub(res.rotation_error),
        limit_excess=sub(res.limit_excess), min_singular_value=sub(res.min_singular_value),
        iterations=sub(res.iterations), measure=res.measure,
        target_position=sub(res.target_position), target_rotation=sub(res.target_rotation),
        joint_names=res.joint_names, prismatic=res.prismatic,
        singular_threshold=res.singular_threshold, tol_pos=res.tol_pos, tol_rot=res.tol_rot)
