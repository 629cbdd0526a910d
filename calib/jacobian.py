"""The TM-MDH identification Jacobian (Eq. 19-25), built on Pinocchio's kinematic regressor.

For each pose, Pinocchio's ``computeFrameKinematicRegressor`` gives the derivative of the tool
placement (expressed LOCAL_WORLD_ALIGNED) with respect to a right perturbation ``M_i exp(xi_i)``
of every joint placement; :class:`calib.kinematics.ChainKinematics` gives each parameter's twist
``xi`` in its placement, a constant matrix over all poses. The Jacobian of all poses is one
matrix product of the stacked regressors with that matrix. Its rows:

* ``dp`` (3 rows): derivative of the tool position in the meas frame (metres per unit).
* ``dw`` (3 rows): the differential rotation of the tool, in the meas frame (radians per unit):
  ``R(p + dp) = exp([dw]) R(p)``.

The paper's Eq. (22) uses the differential translation of ``dT T^-1`` instead of ``dp``; the two
differ by ``dw x p`` (the paper's remark that "Delta p and d differ by a rotation"). ``dp`` is
what a position measurement compares with, so it is used throughout.
"""
from __future__ import annotations

import numpy as np

from .kinematics import ChainKinematics
from .robot import RobotModel

MEASURES = ("pose", "position")


def pose_jacobian(kin: ChainKinematics, Q: np.ndarray):
    """Tool poses and the pose Jacobian at the kinematics' current parameter values.

    Q : (N, n) joint values (rad / m).
    Returns (R (N, 3, 3), p (N, 3) metres, J (N, 6, n_params)) with J[:, :3] = dp and
    J[:, 3:] = dw, both in the meas frame.
    """
    if kin.placement_twists is None:
        kin.set_values(kin.values)
    R, p, reg = kin.tool_poses_and_regressors(Q)
    N, _, n6 = reg.shape
    J = (reg.reshape(N * 6, n6) @ kin.placement_twists).reshape(N, 6, -1)
    return R, p, J


def identification_jacobian(robot: RobotModel, Q: np.ndarray, measure: str = "pose") -> np.ndarray:
    """The identification Jacobian of ``robot`` at configurations Q.

    Parameters
    ----------
    robot : the model, linearised at its current parameter values.
    Q : (N, n) joint values, radians (metres for prismatic joints).
    measure : "pose" for 6 rows per pose (dp, dw) or "position" for 3 rows (dp).

    Returns
    -------
    (6 N, n_params) or (3 N, n_params) float: rows per pose in the order dx, dy, dz (metres per
    unit of the parameter) then dwx, dwy, dwz (radians per unit), in the meas frame; columns in
    the order of ``robot.parameters``.
    """
    from .checks import check_choice, check_configurations, check_robot

    check_robot(robot)
    check_choice(measure, "measure", MEASURES)
    Q = check_configurations(Q, robot.n_joints)
    _, _, J = pose_jacobian(ChainKinematics(robot), Q)
    if measure == "position":
        J = J[:, :3]
    return J.reshape(-1, J.shape[2])
