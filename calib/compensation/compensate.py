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
error (rounding floor), when mu exceeds 1e6, or after ``max_iterations``. A step moves no joint by
more than 0.5 rad (m) (a start on another branch; a calibration's corrections are far smaller). A
start at the nominal joints is millimetres away from the solution, and 3 to 5 iterations reach
1e-13 m. Tool poses and joint Jacobians are computed for the whole batch at once in numpy
(:func:`calib.compensation.solver.tool_poses_and_joint_jacobians`), and pose targets
without starting joints start from the nearest of a set of seed configurations
(:func:`compensate_poses`).

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
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib.checks import check_instance, check_rng
from calib.choices import SINGULAR_THRESHOLD
from calib.model.robot import check_robot
from calib.threads import api_call
from calib.errors import CalibError, DataError, ParameterError
from calib.model.jacobian import MEASURES
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import finite_array
from calib.model.robot import RobotModel
from calib.io.urdf.reader import load_robot, read_urdf_chain, recorded_targets, robot_from_chain, robot_path
from calib.io.urdf.document import UrdfDocument
from calib.compensation.solver import (  # noqa: F401  (re-exported)
    LIMIT_SLACK, RANDOM_STARTS, STATUSES, TOL_POS_M, TOL_ROT_RAD, CompensationResult, finite_limits,
    solve_from, solve_from_seeds, tool_poses_and_joint_jacobians)

__all__ = ["STATUSES", "SINGULAR_THRESHOLD", "CompensationResult", "compensate",
           "compensate_poses", "load_compensation_models", "check_joint_targets",
           "with_frame_uncertainty", "pose_targets_in_base", "pose_targets_from_frame", "flange_link",
           "with_tool_offset"]

# ====================================================================== public API
@api_call
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
    from calib.compensation.branch import check_branch

    res = solve_from(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)
    return replace(check_branch(res, calibrated, q0, "the nominal joints"), targets="joint")


@api_call
def compensate_poses(calibrated: RobotModel, *, T_meas_tool: np.ndarray | None = None,
                     p_meas_tool: np.ndarray | None = None, q_start: np.ndarray | None = None,
                     singular_threshold: float = SINGULAR_THRESHOLD, tol_pos: float = TOL_POS_M,
                     tol_rot: float = TOL_ROT_RAD, max_iterations: int = 100,
                     seed: int = 0, nominal: RobotModel | None = None,
                     configurations=None) -> CompensationResult:
    """Joint values with which the calibrated model reaches given tool poses or positions.

    Parameters
    ----------
    calibrated : the calibrated model.
    T_meas_tool : (N, 4, 4) float, metres: target tool poses in the meas frame; or
    p_meas_tool : (N, 3) float, metres: target tool positions in the meas frame (position-only
        targets). Give exactly one.
    q_start : (N, n) float, rad / m: the starting joint values, which choose the solution
        branch (e.g. the nominal controller's joints for the pose). Default: each target is
        solved from the seed configuration (of 512 drawn within the joint limits with ``seed``,
        and the middle of the ranges) whose calibrated tool pose is nearest the target (seeds
        near the middle of the ranges preferred); the targets not ok from there are solved again
        from their next nearest seeds (17 in all; a singular one from 4), and keep the least
        severe status met, then the solution closest to the middle of the joint ranges. Which
        branch a target ends on is the one its seed leads to: give ``q_start`` to choose it, or
        ``nominal``. With ``q_start``, a target whose joints leave the start's branch is refused
        (status "branch": :mod:`calib.compensation.branch`).
    nominal : the nominal model (the controller's): without ``q_start``, each target is solved
        first on it (its own solution, seeded as above), and the calibrated model from there; a
        target leaving that branch is refused.
    configurations : :class:`calib.compensation.configuration.Configurations`, with ``nominal``:
        the configuration (KUKA Status/Turn, ABB confdata, FANUC configuration string) each
        target is to be reached with; the nominal solution with it is the start, and a target
        without one or leaving it is refused.
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
    from calib.compensation import branch

    if nominal is not None:
        _check_models(calibrated, nominal)
    if configurations is not None:
        from calib.compensation.configuration import Configurations

        check_instance(configurations, "configurations", Configurations, "calib.compensation.configuration")
        if nominal is None or q_start is not None:
            raise ParameterError("configurations need the nominal model (nominal=) and no q_start")
        if len(configurations.values) != N:
            raise DataError(f"{len(configurations.values)} configurations for {N} targets")
    if q_start is not None:
        q0 = _joint_array(q_start, calibrated, "q_start")
        if len(q0) != N:
            raise DataError(f"q_start has {len(q0)} rows for {N} targets")
        res = solve_from(calibrated, q0, p_t, R_t, singular_threshold, tol_pos, tol_rot, max_iterations)
        return branch.check_branch(res, calibrated, q0, "the starting joints")
    if configurations is not None:
        return branch.from_configurations(calibrated, nominal, p_t, R_t, configurations, seed, singular_threshold,
                                          tol_pos, tol_rot, max_iterations)
    if nominal is not None:
        return branch.from_nominal_solution(calibrated, nominal, p_t, R_t, seed, singular_threshold, tol_pos,
                                            tol_rot, max_iterations)
    return solve_from_seeds(calibrated, p_t, R_t, seed, singular_threshold, tol_pos, tol_rot,
                             max_iterations)


def with_frame_uncertainty(result: CompensationResult, *, T_meas_base: np.ndarray,
                           covariance: np.ndarray) -> CompensationResult:
    """``result`` (targets in the robot's base frame) with the error of each reached pose that
    the uncertainty of the base frame causes (:attr:`CompensationResult.frame_position_std`).

    T_meas_base : (4, 4) the robot's base frame in the measurement frame; covariance : (6, 6) of
    its error (x, y, z metres, rotation vector radians, in the meas frame), as a calibration
    records it (:class:`calib.calibration.base_frame.MeasurementFrame`). An error ``d`` moves a
    target point p (base frame) by ``d_t + d_w x (T_meas_base p)`` in the meas frame and turns it
    by ``d_w``: position std sqrt(trace(A C A^T)), ``A = [I, -[T p]x]``; rotation std
    sqrt(trace(C_ww)).
    """
    from calib.model.spatial import skew

    check_instance(result, "result", CompensationResult, "from calib.compensate or calib.compensate_poses")
    T = finite_array(T_meas_base, "T_meas_base")
    C = finite_array(covariance, "covariance")
    if T.shape != (4, 4) or C.shape != (6, 6):
        raise ParameterError(f"T_meas_base must be (4, 4) and covariance (6, 6), got {T.shape} and {C.shape}")
    p = result.target_position @ T[:3, :3].T + T[:3, 3]
    A = np.zeros((len(p), 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -skew(p)
    pos = np.sqrt(np.maximum(np.einsum("nij,jk,nik->n", A, C, A), 0.0))
    rot = np.full(len(p), math.sqrt(max(float(np.trace(C[3:, 3:])), 0.0)))
    pos.setflags(write=False)
    rot.setflags(write=False)
    return replace(result, frame_position_std=pos, frame_rotation_std=rot)


def pose_targets_in_base(*, T_meas_base: np.ndarray, T_meas_tool: np.ndarray | None = None,
                         p_meas_tool: np.ndarray | None = None) -> np.ndarray:
    """Pose targets (N, 4, 4) or positions (N, 3) given in the measurement frame, in the robot's
    base frame: ``T_base_tool = T_meas_base^-1 T_meas_tool`` (metres). Give exactly one."""
    T = finite_array(T_meas_base, "T_meas_base")
    if T.shape != (4, 4):
        raise ParameterError(f"T_meas_base must be (4, 4), got {T.shape}")
    if (T_meas_tool is None) == (p_meas_tool is None):
        raise ParameterError("give exactly one of T_meas_tool (N, 4, 4) and p_meas_tool (N, 3)")
    Ti = np.eye(4)
    Ti[:3, :3], Ti[:3, 3] = T[:3, :3].T, -T[:3, :3].T @ T[:3, 3]
    if T_meas_tool is not None:
        X = finite_array(T_meas_tool, "T_meas_tool")
        if X.ndim != 3 or X.shape[1:] != (4, 4):
            raise DataError(f"T_meas_tool must be (N, 4, 4), got shape {X.shape}")
        return Ti @ X
    P = finite_array(p_meas_tool, "p_meas_tool")
    if P.ndim != 2 or P.shape[1] != 3:
        raise DataError(f"p_meas_tool must be (N, 3), got shape {P.shape}")
    return P @ Ti[:3, :3].T + Ti[:3, 3]


def pose_targets_from_frame(*, T_base_frame: np.ndarray, T_frame_tool: np.ndarray | None = None,
                            p_frame_tool: np.ndarray | None = None) -> np.ndarray:
    """Pose targets (N, 4, 4) or positions (N, 3) given in a frame fixed to the robot's base (a
    controller's base frame, a link of the URDF: :func:`calib.io.urdf.controller_frame.targets_frame`),
    in the robot's base frame: ``T_base_tool = T_base_frame T_frame_tool`` (metres). Give
    exactly one of ``T_frame_tool`` and ``p_frame_tool``."""
    T = finite_array(T_base_frame, "T_base_frame")
    if T.shape != (4, 4):
        raise ParameterError(f"T_base_frame must be (4, 4), got {T.shape}")
    Ti = np.eye(4)
    Ti[:3, :3], Ti[:3, 3] = T[:3, :3].T, -T[:3, :3].T @ T[:3, 3]
    if (T_frame_tool is None) == (p_frame_tool is None):
        raise ParameterError("give exactly one of T_frame_tool (N, 4, 4) and p_frame_tool (N, 3)")
    if T_frame_tool is not None:
        return pose_targets_in_base(T_meas_base=Ti, T_meas_tool=T_frame_tool)
    return pose_targets_in_base(T_meas_base=Ti, p_meas_tool=p_frame_tool)


# ====================================================================== models and checks
def load_compensation_models(calibrated_urdf: str | Path, nominal_urdf: str | Path, *,
                             base_frame: str | None = None,
                             tool_frame: str | None = None) -> tuple[RobotModel, RobotModel]:
    """(calibrated, nominal) models whose tool poses are expressed in the same meas frame.

    ``base_frame`` and ``tool_frame`` name frames of the nominal URDF (default: the nominal
    frames the calibrated URDF records, else as :func:`calib.load_robot`). The calibrated URDF written by calib
    (:func:`calib.io.urdf.writer.write_calibrated_urdf`) records which of its links stand for the
    nominal base and tool frames (it may have added a link ``tool``); :func:`calib.load_robot`
    maps the nominal frames to them (:meth:`calib.io.urdf.document.UrdfDocument.resolve_frames`). A URDF
    without that record is read with the same frame names. A calibration of several targets
    (reflectors) keeps the tool frame at the flange with the targets as links under it
    (``tool_kept``): the calibrated model is that tool frame's (the targets are not compensated).
    A ``tool_frame`` of the nominal URDF that the calibrated one lacks (a tool link added to the
    robot's description after the calibration), fixed to the recorded nominal tool frame, is the
    calibrated tool frame moved by the nominal URDF's transform between the two
    (:func:`with_tool_offset`).

    Raises :class:`calib.CalibError` when the two chains have different joints, or for a URDF of
    several targets written by an earlier calib (its tool frame is the first target).
    """
    document = UrdfDocument.read(robot_path(calibrated_urdf))     # read once, parsed below
    base_frame, tool_frame = nominal_frames(document, base_frame=base_frame, tool_frame=tool_frame)
    nominal = load_robot(nominal_urdf, base_frame=base_frame, tool_frame=tool_frame)
    rec = document.frames
    offset = None
    if rec is not None and document.link_of(nominal.tool_frame) not in document.links:
        offset = _fixed_offset(nominal_urdf, nominal, rec.nominal_tool_frame)   # a tool added since
    chain = read_urdf_chain(calibrated_urdf, nominal.base_frame,
                            nominal.tool_frame if offset is None else rec.nominal_tool_frame, document=document)
    targets = recorded_targets(chain)
    if targets and not document.frames.tool_kept:
        raise CalibError(f"{document.path}: written by an earlier version of calib, whose tool frame "
                         f"{chain.tool_frame!r} is the calibration's first target ({targets[0][0]!r}), not the "
                         f"flange: calibrate again (the tool frame then stays at the flange, the targets "
                         f"links under it)")
    calibrated = robot_from_chain(chain, targets=False)      # (with targets: the tool frame, at the flange)
    if offset is not None:
        calibrated = replace(with_tool_offset(calibrated, offset), tool_frame=nominal.tool_frame)
    _check_models(calibrated, nominal)
    return calibrated, nominal


def _fixed_offset(nominal_urdf, nominal: RobotModel, tool_frame: str) -> np.ndarray | None:
    """(4, 4) T_tool_link: where ``nominal``'s tool frame (a link of the nominal URDF) sits on the
    frame ``tool_frame`` of the same URDF when both ride on the last link (the same transform at
    every configuration, to 1e-12 m / rad); None when ``tool_frame`` is ``nominal``'s own, or
    for a frame that moves with respect to it (the calibrated URDF's error then names it)."""
    if nominal.tool_frame == tool_frame:
        return None
    tool = load_robot(nominal_urdf, base_frame=nominal.base_frame, tool_frame=tool_frame)
    if tool.joint_names != nominal.joint_names:
        return None
    Q = nominal.random_configurations(3, 0)
    T = [np.linalg.inv(tool.T_meas_tool(q)) @ nominal.T_meas_tool(q) for q in Q]
    return T[0] if max(np.abs(t - T[0]).max() for t in T) < 1e-12 else None


def with_tool_offset(robot: RobotModel, T_tool_tcp: np.ndarray) -> RobotModel:
    """``robot`` (one tool frame) with its tool frame moved to a point fixed to it: a tool's
    centre point at ``T_tool_tcp`` (4, 4), metres, in the tool frame (a rigid transform).
    Compensating the result aims that point at the targets. A new model; every other field
    as ``robot``'s."""
    check_robot(robot)
    T = finite_array(T_tool_tcp, "T_tool_tcp")
    if T.shape != (4, 4) or np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-9 or \
            np.linalg.det(T[:3, :3]) <= 0 or np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
        raise ParameterError("T_tool_tcp must be a rigid (4, 4) transform (metres)")
    if robot.targets:
        raise ParameterError(f"with_tool_offset: the model holds {robot.n_targets} targets; give the model of "
                             f"its tool frame (CalibrationResult.flange_robot())")
    return replace(robot, T_flange_tool_ref=robot.T_flange_tool_ref @ T)


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
    """Refuse joint targets for a calibrated URDF whose base frame is a measuring instrument's:
    one an earlier calib wrote with the estimated measurement frame in joint 1
    (``measurement_estimated`` in its ``<calib:frames>`` record). A joint target stands for the
    nominal tool's pose in the nominal base frame, which that model does not hold. Calibrated
    URDFs written now stay rooted at the robot's base (:mod:`calib.calibration.base_frame`) and
    take joint targets; when their tool frame was estimated (a measured point, not the nominal
    tool) joint targets are compensated for the last link's pose (:func:`flange_link`)."""
    document = _calibrated_document(calibrated_urdf)
    rec = None if document is None else document.frames
    path = None if document is None else document.path
    if rec is None or not rec.measurement_estimated:
        return
    raise CalibError(f"{path}: the calibration estimated the measurement frame (the instrument's, not the "
                     f"robot's base) from the data and this URDF holds it in its base: joint targets stand "
                     f"for poses of the nominal tool in the nominal base frame; calibrate again with this "
                     f"version of calib (its URDF stays rooted at the robot's base), or give pose targets "
                     f"in the measurement frame")


def flange_link(robot: RobotModel) -> str:
    """The child link of the last joint of ``robot``'s chain (a model read from a URDF): the
    link every tool rides on. Compensating its pose moves any tool fixed to it onto the tool's
    nominal pose, which is how joint targets are compensated after a calibration that measured a
    point other than the nominal tool (the tool's own error is then not corrected)."""
    check_robot(robot)
    if robot.source is None:
        raise CalibError("the robot model was not read from a URDF: it has no last link")
    return robot.source.document.joints[robot.joints[-1].name].child


def _check_models(calibrated: RobotModel, nominal: RobotModel) -> None:
    check_robot(calibrated, "calibrated")
    check_robot(nominal, "nominal")
    if calibrated.targets:
        raise CalibError(f"the calibrated model holds {calibrated.n_targets} targets "
                         f"({', '.join(calibrated.targets)}): compensate the model of its tool frame at the "
                         f"flange (CalibrationResult.flange_robot(), or the URDF calib calibrate writes), or "
                         f"of one target (RobotModel.for_target)")
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
