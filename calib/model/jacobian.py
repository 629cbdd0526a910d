"""The TM-MDH identification Jacobian (Eq. 19-25).

For each pose, the derivative of the tool placement (expressed LOCAL_WORLD_ALIGNED) with respect
to a right perturbation ``M_i exp(xi_i)`` of every joint placement is Pinocchio's kinematic
regressor; :class:`calib.model.kinematics.ChainKinematics` gives each parameter's twist ``xi`` in its
placement, a constant matrix over all poses, and maps it to the tool for all poses at once
(vectorised; the tests compare with Pinocchio's ``computeFrameKinematicRegressor``). Its rows:

* ``dp`` (3 rows): derivative of the tool position in the meas frame (metres per unit).
* ``dw`` (3 rows): the differential rotation of the tool, in the meas frame (radians per unit):
  ``R(p + dp) = exp([dw]) R(p)``.

The paper's Eq. (22) uses the differential translation of ``dT T^-1`` instead of ``dp``; the two
differ by ``dw x p`` (the paper's remark that "Delta p and d differ by a rotation"). ``dp`` is
what a position measurement compares with, so it is used throughout.
"""
from __future__ import annotations

import numpy as np

from calib.model.kinematics import ChainKinematics
from calib.model.robot import RobotModel

MEASURES = ("pose", "position")


#: A column of a Jacobian whose norm is at most this times the largest column's is zero up to
#: rounding: the parameter has no effect on these data (LM does not move it).
NO_EFFECT_RTOL = 1e-10

def pose_jacobian(kin: ChainKinematics, Q: np.ndarray, columns: np.ndarray | None = None, *,
                  transposed: bool = False, targets: np.ndarray | None = None):
    """Tool poses and the pose Jacobian at the kinematics' current parameter values.

    Q : (N, n) joint values (rad / m). columns : parameter indices of the wanted columns, in
    that order (default all): asking only for the free parameters avoids computing and copying
    the others. The cost is linear in N and the memory that of the outputs, so a caller that
    accumulates normal equations can pass chunks of Q. targets : (N,) int, each row's target
    index of a multi-target model (None: the first; a target's v columns are zero on the other
    targets' rows).
    Returns (R (N, 3, 3), p (N, 3) metres, J (N, 6, m)) with J[:, :3] = dp and J[:, 3:] = dw,
    both in the meas frame. ``transposed``: J as (m, 6, N) instead, see
    :meth:`calib.model.kinematics.ChainKinematics.poses_and_jacobian`.
    """
    return kin.poses_and_jacobian(Q, columns, transposed=transposed, targets=targets)


def identification_jacobian(robot: RobotModel, Q: np.ndarray, measure: str = "pose",
                            targets: np.ndarray | None = None) -> np.ndarray:
    """The identification Jacobian of ``robot`` at configurations Q.

    Parameters
    ----------
    robot : the model, linearised at its current parameter values.
    Q : (N, n) joint values, radians (metres for prismatic joints).
    measure : "pose" for 6 rows per pose (dp, dw) or "position" for 3 rows (dp).
    targets : (N,) int, the target index of each row for a multi-target ``robot`` (None: the
        first target).

    Returns
    -------
    (6 N, n_params) or (3 N, n_params) float: rows per pose in the order dx, dy, dz (metres per
    unit of the parameter) then dwx, dwy, dwz (radians per unit), in the meas frame; columns in
    the order of ``robot.parameters``.
    """
    from calib.checks import check_choice, check_configurations
    from calib.model.robot import check_robot

    check_robot(robot)
    check_choice(measure, "measure", MEASURES)
    Q = check_configurations(Q, robot.n_joints)
    _, _, J = pose_jacobian(ChainKinematics(robot), Q, targets=targets)
    if measure == "position":
        J = J[:, :3]
    return J.reshape(-1, J.shape[2])


def damped_step(J: np.ndarray, e: np.ndarray, damping: float) -> np.ndarray:
    """The damped least-squares step dq (N, n) = J^T (J J^T + damping^2 I)^-1 e of N problems at
    once, J (N, m, n), e (N, m): the iterations of the inverse kinematics (touch rows, aiming a
    target, reaching a feature) take it."""
    JJ = J @ J.transpose(0, 2, 1) + damping ** 2 * np.eye(J.shape[1])
    return np.einsum("nji,nj->ni", J, np.linalg.solve(JJ, e[:, :, None])[:, :, 0])
