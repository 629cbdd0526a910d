"""The tool frame of a model of several targets (reflectors): where the flange is when only the
targets were measured.

A model with targets (:meth:`calib.RobotModel.with_targets`) places each target k on the flange
(MDH frame n) by its own transform ``T(v_k) . T_flange_tool_ref_k`` after the last link

    L_n(q) = Rot(z, theta_n + q) Trans(z, d_n) Trans(x, a_n) Rot(x, alpha_n) [Rot(y, beta_n)]

(``d_n + q`` for a prismatic joint). The joint's own motion factors out on the left
(``L_n(q) = Rot(z, q) L_n(0)``, or ``Trans(z, q) L_n(0)``), so for two values of the last link's
parameters the change ``G = L_n(0)^-1 L'_n(0)`` is one constant transform at every configuration,
and targets moved by ``G`` predict the same poses: measurements of targets cannot tell the
flange's place on the last axis (d_n), its turn about it (theta_n) or its offset and tilt from it
(a_n, alpha_n, beta_n) from the targets' offsets. :func:`with_nominal_last_link` moves that
difference into the targets and leaves the last link at the nominal values, so that the flange is
where the nominal model and the identifiable corrections put it; :func:`flange_robot` is then
the one-tool-frame model of the tool frame itself (the nominal flange->tool transform of the
URDF's tool frame, no offset of its own): what a calibrated URDF holds as its tool frame, and
what compensation aims at.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.checks import check_array
from calib.errors import ParameterError
from calib.model.mdh import link_transform
from calib.model.robot import RobotModel, check_robot
from calib.model.spatial import inverse, zyx_parameters

__all__ = ["flange_robot", "last_link_names", "with_nominal_last_link"]


def last_link_names(robot: RobotModel) -> tuple[str, ...]:
    """Names of the last joint's structural parameters (theta_n, d_n, a_n, alpha_n and beta_n
    where the model has it), in parameter order."""
    check_robot(robot)
    n = robot.n_joints
    return tuple(p.name for p in robot.parameters if p.group == "joint" and p.joint == n)


def _last_link(robot: RobotModel) -> np.ndarray:
    """(4, 4) L_n at q = 0 of ``robot`` (see the module docstring)."""
    n = robot.n_joints
    beta = robot.value(f"beta{n}") if robot.has_beta(n) else 0.0
    return link_transform(robot.value(f"theta{n}"), robot.value(f"d{n}"), robot.value(f"a{n}"),
                          robot.value(f"alpha{n}"), beta)


def with_nominal_last_link(robot: RobotModel, nominal: RobotModel) -> RobotModel:
    """``robot`` (two or more targets) with its last joint's structural parameters at
    ``nominal``'s values and each target's v changed so that every target's pose is the same at
    every configuration (to rounding, ~1e-16 m / rad): the part of the last link that the
    targets' measurements cannot separate from the targets' offsets goes into the offsets.

    nominal : a model of the same joints (with or without targets; only its last joint's
    parameters are read). Returns a new model; ``robot`` itself when nothing changes.
    Raises :class:`calib.ParameterError` for a model without targets or other joints.
    """
    check_robot(robot)
    check_robot(nominal, "nominal")
    if not robot.targets:
        raise ParameterError("with_nominal_last_link: the model has one tool frame, no targets (its tool "
                             "frame is what was measured)")
    if nominal.joint_names != robot.joint_names or last_link_names(nominal) != last_link_names(robot):
        raise ParameterError(f"nominal: expected a model of the joints {list(robot.joint_names)} with the "
                             f"last-link parameters {', '.join(last_link_names(robot))}")
    names = last_link_names(robot)
    G = inverse(_last_link(nominal)) @ _last_link(robot)
    if np.array_equal(nominal.values[nominal.indices(names)], robot.values[robot.indices(names)]):
        return robot
    values = robot.values.copy()
    values[robot.indices(names)] = nominal.values[nominal.indices(names)]
    for k in range(robot.n_targets):
        T = G @ robot.T_flange_tool(k)
        values[robot.indices(robot.v_names(k))] = zyx_parameters(T @ inverse(robot.T_flange_tool_ref_of(k)))
    return robot.with_values(values)


def flange_robot(robot: RobotModel, T_flange_tool_ref) -> RobotModel:
    """The one-tool-frame model of the tool frame that carries ``robot``'s targets: ``robot``'s
    chain and joint terms, with the reference flange->tool transform ``T_flange_tool_ref``
    (4, 4), metres (the nominal one of the URDF's tool frame; the identity for the flange, MDH
    frame n, itself) and v = 0 (the tool frame has no offset of its own that the targets could
    measure). For a model of one tool frame, that tool frame moved to ``T_flange_tool_ref``.

    Give ``robot`` with its last link at the nominal values (:func:`with_nominal_last_link`) for
    the flange where the nominal model and the identifiable corrections put it.
    """
    check_robot(robot)
    T = check_array(T_flange_tool_ref, "T_flange_tool_ref", (4, 4), unit="metres")
    one = robot.for_target(0)
    values = one.values.copy()
    values[one.indices(one.v_names())] = 0.0
    return replace(one.with_values(values), T_flange_tool_ref=T)
