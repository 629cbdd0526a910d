"""The serial chain's vocabulary: its moving joints (:class:`ChainJoint`), the TM-MDH parameter
list in the order of the paper's Eq. (23) (:class:`Parameter`, :func:`make_parameters`), and what
a model read from a URDF carries (:class:`UrdfSource`, declared here so that the model wing needs
no import of the reader). :class:`calib.model.robot.RobotModel` is built from them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Protocol, Sequence, runtime_checkable

import numpy as np


JOINT_KINDS = ("revolute", "continuous", "prismatic")
_STRUCTURAL_KINDS = ("theta", "d", "a", "alpha", "beta")
_FRAME_KINDS = ("x", "y", "z", "alpha", "beta", "gamma")


@dataclass(frozen=True)
class ChainJoint:
    """One moving joint of the chain: URDF name, kind, limits (rad or m; +-inf if unlimited)."""

    name: str
    kind: str
    lower: float
    upper: float

    @property
    def is_prismatic(self) -> bool:
        return self.kind == "prismatic"


@dataclass(frozen=True)
class Parameter:
    """One TM-MDH parameter.

    ``group`` is ``"joint"`` (structural, of joint ``joint``, 1-based), ``"u"`` (meas->base),
    ``"v"`` (flange->tool), ``"compliance"`` (``c<i>`` of joint ``joint``, only in a model made
    by :meth:`RobotModel.with_compliance`) or ``"periodic"`` (``q<i>_sin1`` ... ``q<i>_cos2``,
    :meth:`RobotModel.with_periodic`); ``kind`` is theta, d, a, alpha, beta for joints, x, y,
    z, alpha, beta, gamma for u and v, ``c`` for compliance, sin1, cos1, sin2, cos2 for periodic
    terms; ``unit`` is ``"m"``, ``"rad"``, or
    ``"rad/(N m)"`` / ``"m/N"`` for the compliance of a revolute / prismatic joint; ``target`` the
    target id of a v parameter of a multi-target model (None otherwise).
    """

    name: str
    group: str
    kind: str
    joint: int | None
    unit: str
    target: str | None = None

    @property
    def is_angular(self) -> bool:
        return self.unit == "rad"

    @property
    def symbol(self) -> str:
        """The paper's symbol: theta1, d2, x, alpha, x', gamma' ..."""
        if self.group == "joint":
            return self.name
        return self.kind + ("'" if self.group == "v" else "") + \
            ("" if self.target is None else f"@{self.target}")


#: Names of the six measurement->base parameters (as :func:`v_names` for the tool's).
U_NAMES = tuple(f"u_{k}" for k in _FRAME_KINDS)


def v_names(target: str | None = None) -> tuple[str, ...]:
    """Names of the six flange->tool parameters: ``v_x`` ... or ``v_x@<target>`` ..."""
    suffix = "" if target is None else f"@{target}"
    return tuple(f"v_{k}{suffix}" for k in _FRAME_KINDS)


def joint_variable_names(joints: Sequence[ChainJoint]) -> list[str]:
    """The parameter each joint variable adds to, in chain order: ``theta<i>``, or ``d<i>`` for a
    prismatic joint (a parameter Jacobian's columns there are the joint Jacobian's)."""
    return [f"d{i}" if j.is_prismatic else f"theta{i}" for i, j in enumerate(joints, start=1)]


def make_parameters(n_joints: int, beta_joints: Iterable[int],
                    targets: Sequence[str] = ()) -> tuple[Parameter, ...]:
    """The parameter list in the order of Eq. (23): theta, d, a, alpha, beta, u, v.

    ``beta_joints`` are the 1-based joints that carry a beta parameter. ``targets``: two or more
    target ids give one v block per target (``v_x@<id>`` ...), in that order; () one block ``v_x``.
    """
    params: list[Parameter] = []
    for kind in ("theta", "d", "a", "alpha"):
        unit = "m" if kind in ("d", "a") else "rad"
        params += [Parameter(f"{kind}{i}", "joint", kind, i, unit) for i in range(1, n_joints + 1)]
    params += [Parameter(f"beta{i}", "joint", "beta", i, "rad") for i in sorted(beta_joints)]
    for kind in _FRAME_KINDS:
        params.append(Parameter(f"u_{kind}", "u", kind, None, "m" if kind in "xyz" else "rad"))
    for target in (tuple(targets) or (None,)):
        for kind, name in zip(_FRAME_KINDS, v_names(target)):
            params.append(Parameter(name, "v", kind, None, "m" if kind in "xyz" else "rad", target))
    return tuple(params)


@runtime_checkable
class UrdfSource(Protocol):
    """What a model read from a URDF carries: the parse (:class:`calib.io.urdf.reader.UrdfChain`).

    ``path`` the URDF file; ``document`` its XML document (:class:`calib.io.urdf.document.UrdfDocument`);
    ``model`` Pinocchio's model of the whole file (built once, never modified: copy it);
    ``joints`` the chain's :class:`ChainJoint`; ``joint_ids`` their Pinocchio joint ids;
    ``base_frame`` / ``tool_frame`` the frame names and ``base_frame_id`` / ``tool_frame_id``
    their Pinocchio frame ids; ``link_masses`` the moving links' masses. Declared here so that
    the model needs no import of the reader.
    """

    path: Path
    document: Any
    model: Any
    joints: tuple
    joint_ids: tuple
    base_frame: str
    tool_frame: str
    base_frame_id: int
    tool_frame_id: int

    @property
    def link_masses(self) -> np.ndarray:
        """(n,) kg: the masses the URDF gives the chain's moving links."""

    @property
    def gravity_models(self) -> dict:
        """The gravity models kept with the chain (payload and gravity -> model)."""

    def configuration(self, q: np.ndarray) -> np.ndarray: ...
