"""The accuracy of a touch calibration (:mod:`calib.calibration.touch`): the Cramer-Rao
prediction of the calibrated tool positions' error over configurations, and the error to a known
truth, both after one best-fit rigid (or similarity) registration of the tool positions.

Touch data leave the base frame nominal (a rigid motion of the cell is not seen), and, without a
known length, the scale: what a robot located by touching its work needs is its tool positions
up to that motion, which the registration removes.
"""
from __future__ import annotations

import numpy as np

from calib.calibration.touch import TouchResult
from calib.checks import check_configurations
from calib.errors import ParameterError
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel
from calib.model.spatial import best_fit_motion

#: "none": the tool positions as they are, in the meas frame (meaningful when measured rows
#: identified the meas frame).
REGISTRATIONS = ("rigid", "similarity", "none")


def registered_residuals(p: np.ndarray, p_ref: np.ndarray, registration: str = "rigid") -> np.ndarray:
    """(N, 3) what is left of p - p_ref (both (N, 3) metres) after the best-fit rigid motion
    (``"similarity"``: and scale; ``"none"``: nothing) of p onto p_ref (Kabsch / Umeyama)."""
    if registration not in REGISTRATIONS:
        raise ParameterError(f"registration must be one of {', '.join(REGISTRATIONS)}, got {registration!r}")
    if registration == "none":
        return p - p_ref
    R, t, scale = best_fit_motion(p, p_ref, registration)
    return scale * p @ R.T + t - p_ref


def registered_error(model: RobotModel, truth: RobotModel, Q: np.ndarray, registration: str = "rigid") -> float:
    """RMS distance (metres) between ``model``'s and ``truth``'s tool positions at Q (N, n) after
    one best-fit rigid (or similarity) registration of the former onto the latter."""
    p = ChainKinematics(model).frame_poses(Q)[1]
    p_ref = ChainKinematics(truth).frame_poses(Q)[1]
    return float(np.sqrt(np.mean(np.sum(registered_residuals(p, p_ref, registration) ** 2, axis=1))))


def predicted_tool_error(result: TouchResult, Q: np.ndarray, registration: str = "rigid") -> float:
    """The Cramer-Rao prediction (at the noise levels of ``result``) of the RMS error of the
    calibrated tool positions at Q (N, n) after a best-fit rigid (or similarity) registration
    (``"none"``: in the meas frame, for a fit whose measured rows identified it):
    sqrt(trace(P Jt C Jt^T P) / N), Jt the tool positions' Jacobian in the fitted robot
    parameters (3 N, m), C their covariance, P the projection off the rigid motions (and the
    scaling) of the N points, linearised. It covers the noise only: the parameters held at their
    nominal values (a gauge such as the scale of point-only data) add their own errors."""
    if registration not in REGISTRATIONS:
        raise ParameterError(f"registration must be one of {', '.join(REGISTRATIONS)}, got {registration!r}")
    if registration == "none" and not result.n_measured:
        raise ParameterError("registration 'none' needs a fit whose measured rows identified the meas frame; "
                             "touch rows alone leave it nominal")
    robot = result.robot
    Q = check_configurations(Q, robot.n_joints)
    kin = ChainKinematics(robot)
    free = robot.indices(result.free)
    _, p, J = pose_jacobian(kin, Q, free)
    Jt = J[:, :3].reshape(-1, len(free))
    N = len(Q)
    G = np.zeros((N, 3, 7))
    G[:, :, :3] = np.eye(3)
    c = p - p.mean(axis=0)
    G[:, 0, 4], G[:, 0, 5] = c[:, 2], -c[:, 1]          # w x c: the columns of -[c]x
    G[:, 1, 3], G[:, 1, 5] = -c[:, 2], c[:, 0]
    G[:, 2, 3], G[:, 2, 4] = c[:, 1], -c[:, 0]
    G[:, :, 6] = c                                     # a scaling about the centroid
    if registration == "none":
        PJ = Jt
    else:
        Qg = np.linalg.qr(G[:, :, :7 if registration == "similarity" else 6].reshape(3 * N, -1))[0]
        PJ = Jt - Qg @ (Qg.T @ Jt)
    C = result.covariance[:len(free), :len(free)]
    return float(np.sqrt(np.einsum("ij,jk,ik->", PJ, C, PJ) / N))
