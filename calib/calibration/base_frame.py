"""The robot's own base frame after a calibration whose measurement frame was estimated.

A laser tracker measures in its own frame (``meas``), metres from the robot and turned. The
calibrated model predicts ``T_meas_tool(q)``; how that product is split between "where the
tracker stands" and "the robot's geometry" is a convention, since a rigid motion of the base
frame trades against the base and joint-1 parameters (the identifiability analysis ties them).
calib states one convention, built from the predictions alone, so it is well defined whichever
parameters were identifiable:

    The robot's base frame is the frame of the nominal URDF's base link (``nominal.base_frame``)
    placed where the **nominal** model, with a flange->tool transform of its own, best matches the
    **calibrated** model's tool poses over the workspace: the rigid transform ``T_meas_base``
    (and a tool ``Y``) minimising

        sum_k sum_s | T_meas_base . T_base_flange_nom(q_k) . Y . s  -  T_meas_tool_cal(q_k) . s |^2

    over ``WORKSPACE_CONFIGURATIONS`` configurations q_k drawn uniformly within the joint limits
    (seed ``WORKSPACE_SEED``; continuous joints in [-pi, pi]) and the points s of the tool frame
    at its origin and ``AXIS_POINT_M`` along each of its axes (the origin only for a
    position-only calibration, whose tool orientation is not observed).

The calibrated predictions are what the data identify, so non-identifiable parameter
combinations (u_z against d1, u_gamma against theta1, ...) do not move this frame; the nominal
model is fixed. The robot's errors then stay in the robot: joint 1's origin in the calibrated
URDF differs from the nominal one by the part of the robot's errors that a rigid motion of the
whole nominal robot does not explain (compare ISO 9283's best-fit base), and the tracker pose is
``T_meas_base``, reported with its covariance (the parameter covariance propagated through the
predictions and this fit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from calib.checks import check_array, check_names
from calib.errors import ParameterError
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel, check_robot
from calib.model.spatial import inverse, rotation_from_rotvec, skew, zyx_parameters

__all__ = ["MeasurementFrame", "robot_base_frame", "in_base_frame", "WORKSPACE_CONFIGURATIONS",
           "WORKSPACE_SEED", "AXIS_POINT_M"]

#: The workspace of the base-frame convention (see the module docstring).
WORKSPACE_CONFIGURATIONS = 256
WORKSPACE_SEED = 0
#: Points of the tool frame matched besides its origin: this far along each axis (metres).
AXIS_POINT_M = 0.1
#: Gauss-Newton iterations of the fit at most, and the step (m, rad) below which it stops.
MAX_ITERATIONS = 30
STEP_TOL = 1e-13


@dataclass(frozen=True, eq=False)
class MeasurementFrame:
    """The measurement->base transform of a calibration (see the module docstring).

    T_meas_base : (4, 4) pose of the robot's base frame (``base_frame``, the nominal URDF's base
        link) in the meas frame, metres.
    covariance : (6, 6) covariance of its error (dx, dy, dz in metres, then the rotation vector in
        radians), both expressed in the meas frame (left perturbation ``exp(d) T_meas_base``).
    base_frame : the URDF link that is the robot's base frame.
    fit_rms : RMS distance (m) of the fit's points: how far the nominal robot, rigidly placed,
        stays from the calibrated one (the robot's errors that remain in the URDF).
    position_only : True when the tool orientation was not observed (positions matched only).
    """

    T_meas_base: np.ndarray
    covariance: np.ndarray
    base_frame: str
    fit_rms: float
    position_only: bool = False

    @property
    def std(self) -> np.ndarray:
        """(6,) standard deviations: of the x, y, z (m) of ``T_meas_base[:3, 3]`` (the base's
        origin in the meas frame, the numbers printed beside them), then of the rotation about x,
        y, z of meas (rad). The origin moves by ``d_t + d_w x t`` under the left perturbation of
        :attr:`covariance`, so its covariance is ``[I, -skew(t)] C [I, -skew(t)]^T``: the
        diagonal of C alone (the std of ``d_t``, the motion of the meas frame's origin) overstated
        it 4-7 times for a tracker 3 m away (Monte Carlo: 15-20 um printed, 3-4 um seen)."""
        G = np.hstack([np.eye(3), -skew(self.T_meas_base[:3, 3])])
        var_t = np.einsum("ij,jk,ik->i", G, self.covariance, G)
        return np.sqrt(np.maximum(np.r_[var_t, np.diag(self.covariance)[3:]], 0.0))

    def xyz_rpy(self) -> np.ndarray:
        """(6,) x, y, z (m) and roll, pitch, yaw (rad) of T_meas_base (URDF convention:
        R = Rz(yaw) Ry(pitch) Rx(roll))."""
        x = zyx_parameters(self.T_meas_base)        # x, y, z, alpha (yaw), beta (pitch), gamma (roll)
        return np.array([x[0], x[1], x[2], x[5], x[4], x[3]])

    def to_dict(self) -> dict:
        """JSON form: millimetres and degrees, 1-sigma standard deviations."""
        v, s = self.xyz_rpy(), self.std
        return {"base_frame": self.base_frame, "xyz_mm": [float(t * 1e3) for t in v[:3]],
                "rpy_deg": [float(math.degrees(t)) for t in v[3:]],
                "std_xyz_mm": [float(t * 1e3) for t in s[:3]],
                "std_rotation_deg": [float(math.degrees(t)) for t in s[3:]],
                "fit_rms_mm": self.fit_rms * 1e3, "position_only": self.position_only,
                "matrix": [[float(x) for x in row] for row in self.T_meas_base],
                "covariance_si": [[float(x) for x in row] for row in self.covariance],
                "convention": "best fit of the nominal model to the calibrated tool poses over "
                              f"{WORKSPACE_CONFIGURATIONS} configurations within the joint limits "
                              f"(seed {WORKSPACE_SEED})"}

    def format(self) -> str:
        """One line for a person (mm, deg, 1 sigma)."""
        v, s = self.xyz_rpy(), self.std
        return (f"measurement->base ({self.base_frame}): xyz {v[0] * 1e3:.4f}, {v[1] * 1e3:.4f}, "
                f"{v[2] * 1e3:.4f} mm (std {s[0] * 1e3:.3g}, {s[1] * 1e3:.3g}, {s[2] * 1e3:.3g}); "
                f"rpy {math.degrees(v[3]):.6f}, {math.degrees(v[4]):.6f}, {math.degrees(v[5]):.6f} deg "
                f"(rotation std {math.degrees(s[3]):.3g}, {math.degrees(s[4]):.3g}, "
                f"{math.degrees(s[5]):.3g} deg); nominal robot fits the calibrated one to "
                f"{self.fit_rms * 1e3:.3g} mm RMS")


def in_base_frame(robot: RobotModel, frame: MeasurementFrame | np.ndarray) -> RobotModel:
    """``robot`` (tool poses in the meas frame) with its tool poses in the robot's base frame:
    ``T_base_tool(q) = T_meas_base^-1 . T_meas_tool(q)`` (a new model; ``frame`` a
    :class:`MeasurementFrame` or the (4, 4) T_meas_base)."""
    check_robot(robot)
    T = frame.T_meas_base if isinstance(frame, MeasurementFrame) else \
        check_array(frame, "frame (T_meas_base)", (4, 4), unit="metres")
    if np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-9 or np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
        raise ParameterError("frame must be a MeasurementFrame or a rigid (4, 4) T_meas_base")
    return replace(robot, T_meas_base_ref=inverse(T) @ robot.T_meas_base_ref)


def robot_base_frame(calibrated: RobotModel, nominal: RobotModel, *, covariance: np.ndarray | None = None,
                     free: Sequence[str] = (), position_only: bool = False) -> MeasurementFrame:
    """The robot's base frame in the meas frame by the convention of the module docstring.

    calibrated : the calibrated model (tool poses in the meas frame); nominal : the model it was
    calibrated from (its base frame is the URDF's). covariance : (m, m) covariance of the free
    parameters ``free`` (SI), propagated to :attr:`MeasurementFrame.covariance` (zeros without).
    position_only : match the tool origins only (a position-only calibration).
    """
    check_robot(calibrated, "calibrated")
    check_robot(nominal, "nominal")
    free = check_names(free, "free")
    if covariance is not None:
        covariance = check_array(covariance, "covariance", (len(free), len(free)), unit="SI units")
    if not isinstance(position_only, (bool, np.bool_)):
        raise ParameterError(f"position_only must be True or False, got {position_only!r:.60}")
    if calibrated.joint_names != nominal.joint_names:
        raise ParameterError("calibrated and nominal models must have the same joints")
    cal = calibrated.geometry().for_target(0)
    nom = nominal.geometry().for_target(0)
    Q = nom.random_configurations(WORKSPACE_CONFIGURATIONS, WORKSPACE_SEED)
    kin_c = ChainKinematics(cal)
    R_c, p_c = kin_c.frame_poses(Q)
    R_f, p_f = ChainKinematics(nom).frame_poses(Q, "flange")
    S = np.zeros((1, 3)) if position_only else np.vstack([np.zeros(3), AXIS_POINT_M * np.eye(3)])
    target = p_c[:, None, :] + np.einsum("nij,sj->nsi", R_c, S)          # (N, P, 3)

    # start: the calibrated tool on the nominal flange, the base by a point registration
    Y = cal.T_flange_tool()
    B = _kabsch(p_f + np.einsum("nij,j->ni", R_f, Y[:3, 3]), p_c)
    n_y = 3 if position_only else 6
    for _ in range(MAX_ITERATIONS):
        pts, A = _residual_jacobian(B, Y, R_f, p_f, S, n_y)
        r = (pts - target).reshape(-1)
        step = -np.linalg.lstsq(A, r, rcond=None)[0]
        B = _left(step[:6]) @ B
        Y = Y @ _right(step[6:], n_y)
        if np.abs(step).max() < STEP_TOL:
            break
    pts, A = _residual_jacobian(B, Y, R_f, p_f, S, n_y)
    fit_rms = float(np.sqrt(np.mean(np.sum((pts - target) ** 2, axis=2))))
    C6 = np.zeros((6, 6))
    if covariance is not None and len(free):
        C6 = _propagate(calibrated, cal, kin_c, Q, R_c, S, A, covariance, free)
    B.setflags(write=False)
    C6.setflags(write=False)
    return MeasurementFrame(B, C6, nominal.base_frame, fit_rms, position_only)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(4, 4) rigid T minimising sum |T a_k - b_k|^2 (points (N, 3))."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((b - cb).T @ (a - ca))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    T = np.eye(4)
    T[:3, :3] = U @ D @ Vt
    T[:3, 3] = cb - T[:3, :3] @ ca
    return T


def _left(d: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation_from_rotvec(d[3:]), d[:3]
    return T


def _right(d: np.ndarray, n_y: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = d[:3]
    if n_y == 6:
        T[:3, :3] = rotation_from_rotvec(d[3:])
    return T


def _residual_jacobian(B, Y, R_f, p_f, S, n_y):
    """Points B F_k Y s (N, P, 3) and the Jacobian (3 N P, 6 + n_y) of their stacked coordinates
    with respect to a left perturbation of B (meas frame) and a right one of Y (tool frame)."""
    N, P = len(p_f), len(S)
    ys = S @ Y[:3, :3].T + Y[:3, 3]                                      # (P, 3) in the flange
    fl = p_f[:, None, :] + np.einsum("nij,sj->nsi", R_f, ys)             # (N, P, 3) in base
    pts = fl @ B[:3, :3].T + B[:3, 3]
    A = np.zeros((N, P, 3, 6 + n_y))
    A[..., :3] = np.eye(3)
    A[..., 3:6] = -skew(pts)
    M = np.einsum("ij,njk->nik", B[:3, :3], R_f) @ Y[:3, :3]             # (N, 3, 3) meas <- tool
    A[..., 6:9] = M[:, None]
    if n_y == 6:
        A[..., 9:12] = -np.einsum("nij,sjk->nsik", M, skew(S))
    return pts, A.reshape(N * P * 3, 6 + n_y)


def _propagate(calibrated, cal, kin_c, Q, R_c, S, A, covariance, free):
    """(6, 6) covariance of the base frame: the free parameters' covariance through the
    calibrated tool points' Jacobian and the fit's normal equations (first order)."""
    cov = np.asarray(covariance, float)
    names = list(free)
    if cov.shape != (len(names), len(names)):
        raise ParameterError(f"covariance must be ({len(names)}, {len(names)}) for the free parameters")
    rename = {}
    if calibrated.targets:       # for_target(0) names the first target's v parameters v_x ...
        rename = dict(zip(calibrated.v_names(0), cal.v_names()))
    keep = [k for k, n in enumerate(names) if rename.get(n, n) in cal.names]
    if not keep:
        return np.zeros((6, 6))
    cols = cal.indices([rename.get(names[k], names[k]) for k in keep])
    _, _, J = kin_c.poses_and_jacobian(Q, cols)                          # (N, 6, m)
    arm = np.einsum("nij,sj->nsi", R_c, S)                               # (N, P, 3)
    G = J[:, None, :3] - np.einsum("nsij,njm->nsim", skew(arm), J[:, 3:])
    G = G.reshape(-1, len(cols))                                         # d points / d params
    M = np.linalg.lstsq(A, G, rcond=None)[0][:6]                         # d (B pert.) / d params
    C = cov[np.ix_(keep, keep)]
    out = M @ C @ M.T
    return (out + out.T) / 2
