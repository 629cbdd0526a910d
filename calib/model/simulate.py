"""Synthetic measurements from a perturbed ("true") model, as in Section 4.1 of the paper.

Noise model (Section 4.3): each measured position is the true tool position plus Gaussian noise
of ``sigma_pos`` per axis; each measured orientation is the true one turned by a rotation vector
with Gaussian components of ``sigma_rot`` per axis, applied in the meas frame:
``R_meas = exp([n]) R_true``.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from calib.errors import ParameterError
from calib.checks import check_configurations, check_deviations, check_number, check_rng, check_target_ids
from calib.model.robot import check_robot
from calib.model.kinematics import ChainKinematics
from calib.model.measurements import Measurements
from calib.model.robot import RobotModel
from calib.model.spatial import rotation_from_rotvec

#: Tables 4 and 5 of the paper: preset deviations of the BRTIRUS0707A parameters (SI units).
PAPER_DEVIATIONS: dict[str, float] = {
    "theta1": -0.0035, "theta2": 0.002, "theta3": 0.001, "theta4": 0.004, "theta5": 0.0035, "theta6": -0.008,
    "d1": 0.02e-3, "d2": -0.05e-3, "d3": 0.03e-3, "d4": -0.04e-3, "d5": 0.01e-3, "d6": -0.06e-3,
    "a1": -0.7e-3, "a2": -0.4e-3, "a3": 0.5e-3, "a4": 0.5e-3, "a5": -0.1e-3, "a6": -0.2e-3,
    "alpha1": 0.0, "alpha2": 0.0035, "alpha3": 0.0014, "alpha4": -0.0014, "alpha5": 0.0087, "alpha6": -0.001,
    "beta2": 0.001,
    "u_x": 0.05e-3, "u_y": 0.07e-3, "u_z": 0.0, "u_alpha": 0.0, "u_beta": 0.001, "u_gamma": 0.005,
    "v_x": 0.0, "v_y": 0.02e-3, "v_z": 0.0, "v_alpha": 0.0, "v_beta": 0.006, "v_gamma": 0.0,
}


def apply_deviations(robot: RobotModel, deviations: Mapping[str, float]) -> RobotModel:
    """The model with each named parameter changed by its deviation (SI units, finite)."""
    check_robot(robot)
    return robot.with_changes(**check_deviations(deviations, robot.names))


def random_deviations(robot: RobotModel, scale: float, rng=None) -> dict[str, float]:
    """Gaussian deviations of every parameter (SI units): lengths with standard deviation
    ``scale`` metres, angles ``scale / 0.5`` radians (an angle error then moves a point 0.5 m
    away by about ``scale``). Joint terms (compliance, periodic) are left out (give them by name)."""
    check_robot(robot)
    check_number(scale, "scale", minimum=0.0)
    rng = check_rng(rng)
    return {p.name: float(rng.normal(0.0, scale if p.unit == "m" else scale / 0.5)) for p in robot.parameters
            if p.group not in ("compliance", "periodic")}


def unmodelled_joint_error(robot: RobotModel, Q: np.ndarray, amplitude: float, rng=None) -> np.ndarray:
    """Joint values as the arm really moves with an error no TM-MDH parameter can absorb:
    each revolute joint turns by ``q_i + a_i sin(q_i + phi_i)`` (a gear's once-per-turn
    eccentricity), with a_i uniform in [amplitude / 2, amplitude] radians and phi_i uniform.
    Prismatic joints are left as they are. Q : (N, n); returns (N, n)."""
    rng = np.random.default_rng(rng)
    Q = np.asarray(Q, float)
    n = Q.shape[1]
    a = rng.uniform(0.5 * amplitude, amplitude, n) * ~np.asarray(robot.prismatic, bool)
    phi = rng.uniform(-np.pi, np.pi, n)
    return Q + a * np.sin(Q + phi)


def simulate_measurements(true_robot: RobotModel, Q: np.ndarray, *, sigma_pos: float = 0.02e-3,
                          sigma_rot: float = 0.002, position_only: bool = False, rng=None,
                          sets=None, unmodelled: float = 0.0, targets=None) -> Measurements:
    """Measurements of ``true_robot``'s tool at configurations Q (N, n), with Gaussian noise.

    sigma_pos : metres per axis; sigma_rot : radians per axis (0 for noise-free data).
    unmodelled : amplitude (rad) of a joint-angle-dependent error that the model cannot describe
    (:func:`unmodelled_joint_error`, phases drawn from ``rng``; 0 for none). The measurements
    record the commanded joint values Q. targets : (N,) target ids, one per row, for a
    multi-target ``true_robot`` (each row measures that target; recorded in ``target``).
    """
    check_robot(true_robot, "true_robot")
    Q = check_configurations(Q, true_robot.n_joints)
    check_number(sigma_pos, "sigma_pos", minimum=0.0)
    check_number(sigma_rot, "sigma_rot", minimum=0.0, maximum=math.pi)   # radians: a rotation noise past pi is none
    targets = check_target_ids(targets, len(Q))
    check_number(unmodelled, "unmodelled", minimum=0.0, maximum=math.pi)   # radians: at most half a turn
    rng = check_rng(rng)
    if not isinstance(position_only, (bool, np.bool_)):
        raise ParameterError(f"position_only must be True or False, got {position_only!r:.60}")
    Q_moved = unmodelled_joint_error(true_robot, Q, unmodelled, rng) if unmodelled > 0 else Q
    R, p = ChainKinematics(true_robot).frame_poses(Q_moved, targets=true_robot.target_rows(targets))
    p = p + rng.normal(0.0, sigma_pos, p.shape) if sigma_pos > 0 else p
    rot = None
    if not position_only:
        rot = R
        if sigma_rot > 0:
            rot = rotation_from_rotvec(rng.normal(0.0, sigma_rot, (len(Q), 3))) @ R
    return Measurements(q=np.asarray(Q, float), position=p, rotation=rot, sets=sets,
                        joint_names=true_robot.joint_names, prismatic=true_robot.prismatic,
                        target=None if targets is None else tuple(targets))
