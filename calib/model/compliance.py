"""Joint compliance under gravity: the joints deflect by the gravity torque they carry.

Model (one compliance ``c_i`` per joint, rad/(N m), or m/N for a prismatic joint)::

    q_eff = q + C tau(q),      C = diag(c_1 ... c_n)

``q`` (N, n) are the commanded (measured) joint values, ``q_eff`` the values the chain really
takes, and ``tau(q)`` (N m, or N) the torque that gravity exerts on each joint (in the joint's
positive direction: minus Pinocchio's generalized gravity, the torque the motors must supply),
from the link inertias of the URDF and a payload (mass, centre of mass in the tool frame) added
to the tool frame's body. Gravity is ``(0, 0, -9.81)`` m/s^2 in the URDF's root frame unless
given. With c_i >= 0, a joint sags in the direction gravity pulls it.

What is neglected: ``tau`` is evaluated at the commanded ``q`` with the URDF's nominal geometry,
not at the deflected configuration of the identified geometry. The deflection changes ``tau`` by
``(d tau / d q) C tau``, relative size ~|C tau| (1e-4 for 1e-6 rad/(N m) under 100 N m), so the
neglected deflection is second order in the compliance (~1e-8 rad); geometric deviations of a
few mm on a link of ~1 m change the torque by ~1e-3 of itself. Within this model the
identification Jacobian is exact: ``q_eff`` is linear in ``c``, and

    d pose / d c_i = (d pose / d q_i)(q_eff) * tau_i(q)

where ``d pose / d q_i`` is the column of the joint offset theta_i (d_i for a prismatic joint),
because theta_i and q_i enter the chain only as their sum (Eq. 1). Tests check it against finite
differences of :func:`effective_configurations` + forward kinematics.

Hooks into the geometric model (everything else is unchanged; a :class:`calib.RobotModel` without
compliance has no ``c<i>`` parameters and behaves exactly as before):

* :meth:`calib.RobotModel.with_compliance` appends the ``c<i>`` parameters and this module's
  :class:`GravityModel`; :meth:`calib.RobotModel.geometry` strips them again.
* :class:`calib.model.kinematics.ChainKinematics` maps the joint values through
  :meth:`ComplianceTerm.effective` before forward kinematics (``ChainKinematics.effective``).
* :func:`calib.model.jacobian.pose_jacobian` fills the compliance columns (theta_i's column times
  :meth:`ComplianceTerm.factors`), as it does those of the periodic terms (:mod:`calib.model.periodic`).
* :meth:`calib.RobotModel.T_meas_tool` (the public, reference kinematics) applies
  :meth:`calib.RobotModel.joint_errors` (the deflection, and the periodic errors) to the
  commanded joints: a calibrated model's public kinematics are the fitted ones.

A calibrated URDF holds the geometry only; the compliances travel in a small JSON sidecar
(:mod:`calib.io.compliance_file`, the same object as the ``"compliance"`` entry of the JSON
report) that is read back for compensation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np
import pinocchio as pin

from calib.checks import check_configurations
from calib.errors import CalibError, ParameterError
from calib.model.chain import UrdfSource, joint_variable_names
from calib.model.robot import RobotModel, check_robot

#: Standard gravity, m/s^2, along -z of the URDF root frame by default.
STANDARD_GRAVITY = 9.80665
URDF_NOTE = ("the calibrated URDF holds the geometry only (URDF cannot hold joint compliance); "
             "the compliances are in this report and in the sidecar JSON written beside the URDF, "
             "which 'calib compensate --compliance' reads")
#: Whole-array torque cache entries kept per gravity model (the calibration rows, their subsets
#: and chunks are re-evaluated at every step of every fit).
_CACHE_SIZE = 16
#: Rows of the per-configuration torque memo of a gravity model (cleared when full: about
#: 0.3 KB a row).
_ROW_MEMO_SIZE = 200_000
#: Gravity models kept for the next request of the same chain, payload and gravity (with their
#: torque caches): the joint-term candidates and the final fit of one calibration, and the next
#: calibrations of the same arm, compute the torques of a data set once. Kept with the chain itself
#: (its ``gravity_models``, :class:`calib.model.chain.UrdfSource`), so that they go with it: a
#: process-wide table held every data set's torque memo (~0.24 KB a row: 95 MB for 400k rows)
#: after the caller had dropped the robot and the result.
_MODELS_KEPT = 8


def _kept_models(chain) -> dict | None:
    """The gravity models kept with ``chain`` (payload and gravity -> model); None for a source
    that keeps none (then nothing is kept)."""
    kept = getattr(chain, "gravity_models", None)
    return kept if isinstance(kept, dict) else None


def finite_vector(value, name: str, size: int = 3) -> np.ndarray:
    try:
        v = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be {size} numbers, got {value!r}") from None
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise ParameterError(f"{name} must be {size} finite numbers, got {value!r}")
    return v


@dataclass(frozen=True)
class Payload:
    """A load carried by the tool: mass (kg, >= 0) and its centre of mass ``com_tool`` (3,),
    metres, in the tool frame (a point mass: its own rotational inertia does not matter for the
    static torques)."""

    mass: float
    com_tool: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        m = self.mass
        if isinstance(m, bool) or not isinstance(m, (int, float, np.floating, np.integer)) \
                or not math.isfinite(m) or m < 0:
            raise ParameterError(f"payload mass must be a finite number of kg >= 0, got {m!r}")
        object.__setattr__(self, "mass", float(m))
        c = finite_vector(self.com_tool, "payload centre of mass")
        c.setflags(write=False)
        object.__setattr__(self, "com_tool", c)

    def to_dict(self) -> dict:
        return {"mass_kg": self.mass, "com_mm": [float(x) * 1e3 for x in self.com_tool]}


#: Bounds of physically meaningful options: no industrial robot carries more than a few tonnes
#: (the largest, 2.3 t), nor a load more than MAX_PAYLOAD_TO_ARM times the mass of the links it
#: moves (a payload in grams read as kg is 1000 times too heavy); a centre of mass farther than
#: MAX_PAYLOAD_COM_M from the tool is no tool's load; gravity between these magnitudes (m/s^2:
#: the Moon's 1.62 to three times the Earth's) in any direction (a robot on a ceiling or wall
#: sees it along +z or sideways of its root frame).
MAX_PAYLOAD_KG = 5000.0
MAX_PAYLOAD_TO_ARM = 10.0
MAX_PAYLOAD_COM_M = 5.0
GRAVITY_RANGE = (1.0, 30.0)


def _check_physical(payload: Payload | None, gravity: np.ndarray, link_mass: float) -> None:
    """Refuse a payload or gravity that no calibration set-up has (ParameterError naming it)."""
    g = float(np.linalg.norm(gravity))
    if not GRAVITY_RANGE[0] <= g <= GRAVITY_RANGE[1]:
        raise ParameterError(f"gravity of {g:.4g} m/s^2: expected {GRAVITY_RANGE[0]:g} to {GRAVITY_RANGE[1]:g} "
                             f"m/s^2 (the Earth's is {STANDARD_GRAVITY}; the vector is in m/s^2, not g)")
    if payload is None:
        return
    # (the ratio only where the URDF's link masses are real: placeholder inertias of 1 g weigh nothing)
    if payload.mass > MAX_PAYLOAD_KG or (link_mass >= 1.0 and payload.mass > MAX_PAYLOAD_TO_ARM * link_mass):
        raise ParameterError(f"payload of {payload.mass:.6g} kg: more than any robot carries"
                             + (f" ({MAX_PAYLOAD_TO_ARM:g} times the {link_mass:.3g} kg of the links it moves)"
                                if link_mass >= 1.0 and payload.mass <= MAX_PAYLOAD_KG else f" ({MAX_PAYLOAD_KG:g} kg)")
                             + "; the mass is in kg (grams read as kg?)")
    d = float(np.linalg.norm(payload.com_tool))
    if d > MAX_PAYLOAD_COM_M:
        raise ParameterError(f"payload centre of mass {d:.4g} m from the tool frame: no tool's load is farther "
                             f"than {MAX_PAYLOAD_COM_M:g} m (--payload-com-mm is in mm, Payload.com_tool in metres)")


@dataclass(frozen=True, eq=False)
class GravityModel:
    """Gravity torques on the joints of a URDF chain (a constant model; see the module docstring).

    model : Pinocchio model of the whole URDF with the payload added to the tool frame's body
    and ``model.gravity`` set; joint_ids : Pinocchio ids of the chain's joints (base to tool);
    chain : the parsed URDF chain (:class:`calib.model.robot.UrdfSource`); payload : the :class:`Payload` or None;
    gravity : (3,) m/s^2 in the URDF root frame; link_mass : kg of the links the chain moves
    (0 for a URDF without inertias).
    """

    model: pin.Model = field(repr=False)
    chain: UrdfSource = field(repr=False)
    payload: Payload | None
    gravity: np.ndarray
    link_mass: float
    #: Torques already computed, by content: whole arrays (shape, hash of the bytes) and single
    #: configurations (their bytes). A model's torques depend on the configurations only, so
    #: every kinematics object, fit, fold and subset of a data set shares them.
    _arrays: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _rows: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def from_chain(cls, chain: UrdfSource, *, payload: Payload | None = None,
                   gravity: Sequence[float] | None = None) -> "GravityModel":
        """The gravity model of a URDF chain already parsed (a model's ``source``,
        :class:`calib.io.urdf.reader.UrdfChain`), from a copy of its Pinocchio model.

        payload : carried at the chain's tool frame; gravity : (3,) m/s^2 in the URDF root frame
        (default (0, 0, -9.80665)). Raises :class:`calib.CalibError` subclasses.
        """
        if not isinstance(chain, UrdfSource):
            raise ParameterError(f"chain must be a parsed URDF chain (a model's source, from calib.load_robot), "
                                 f"got {type(chain).__name__}")
        if payload is not None and not isinstance(payload, Payload):
            raise ParameterError(f"payload must be a calib.model.compliance.Payload, got {type(payload).__name__}")
        g = np.array([0.0, 0.0, -STANDARD_GRAVITY]) if gravity is None else finite_vector(gravity, "gravity")
        first = chain.joint_ids[0]
        link_mass = float(sum(chain.model.inertias[j].mass for j in chain.model.subtrees[first]))
        _check_physical(payload, g, link_mass)
        load = None if payload is None else (float(payload.mass), np.asarray(payload.com_tool, float).tobytes())
        key = (load, g.tobytes())
        models = _kept_models(chain)
        kept = None if models is None else models.get(key)
        if kept is not None:
            return kept
        model = pin.Model(chain.model)
        if payload is not None and payload.mass > 0:
            frame = model.frames[chain.tool_frame_id]
            inertia = pin.Inertia(payload.mass, np.array(payload.com_tool), np.zeros((3, 3)))
            jid = frame.parentJoint
            model.inertias[jid] = model.inertias[jid] + frame.placement.act(inertia)
        model.gravity = pin.Motion(g.copy(), np.zeros(3))
        g.setflags(write=False)
        gm = cls(model=model, chain=chain, payload=payload, gravity=g, link_mass=link_mass)
        if models is not None:
            models[key] = gm
            while len(models) > _MODELS_KEPT:
                models.pop(next(iter(models)))
        return gm

    @cached_property
    def content_key(self) -> tuple:
        """What the torques depend on beyond the configurations and the URDF's joint placements,
        as a hashable tuple for cache keys: the payload, the gravity vector and the URDF's inertias
        (mass and centre of mass of every body: two URDFs of one kinematics may weigh
        differently). The placements are the model's: the keys it joins hold its values."""
        load = None if self.payload is None else (self.payload.mass, self.payload.com_tool.tobytes())
        bodies = np.array([[i.mass, *np.asarray(i.lever, float)] for i in self.model.inertias], float)
        return load, np.asarray(self.gravity, float).tobytes(), bodies.tobytes()

    @classmethod
    def for_robot(cls, robot: RobotModel, *, payload: Payload | None = None,
                  gravity: Sequence[float] | None = None) -> "GravityModel":
        """The gravity model of ``robot``'s chain in the URDF it was read from (the parse it
        carries, ``robot.source``: the file is not read again)."""
        check_robot(robot)
        if robot.source is None:
            raise ParameterError("compliance needs the robot's URDF (its inertias and tool frame): "
                                 "load the robot with calib.load_robot")
        gm = cls.from_chain(robot.source, payload=payload, gravity=gravity)
        names = tuple(j.name for j in gm.chain.joints)
        if names != robot.joint_names:
            raise CalibError(f"{robot.urdf_path}: the chain's joints {list(names)} differ from the "
                             f"robot's {list(robot.joint_names)}")
        return gm

    @property
    def note(self) -> str | None:
        """A note for the user when the torques come from the payload alone, else None."""
        if self.link_mass > 0:
            return None
        load = "the payload alone" if self.payload is not None and self.payload.mass > 0 else "nothing (no payload)"
        return f"the URDF has no link inertias: the compliance torques come from {load}"

    def torques(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) torque of gravity on each chain joint (N m; N for prismatic), at joint values
        Q (N, n) rad / m: minus Pinocchio's generalized gravity."""
        Q = np.ascontiguousarray(check_configurations(Q, len(self.chain.joint_ids)), dtype=float)
        key = (Q.shape, hash(Q.tobytes()))
        tau = self._arrays.get(key)
        if tau is not None:
            return tau
        rows = self._rows
        keys = [q.tobytes() for q in Q]
        missing = [k for k, b in enumerate(keys) if b not in rows]
        if missing:
            if len(rows) + len(missing) > _ROW_MEMO_SIZE:
                rows.clear()
            for k, t in zip(missing, self._compute(Q[missing])):
                rows[keys[k]] = t
        tau = np.array([rows[b] for b in keys]).reshape(Q.shape)
        tau.setflags(write=False)
        if len(self._arrays) >= _CACHE_SIZE:
            self._arrays.pop(next(iter(self._arrays)))
        self._arrays[key] = tau
        return tau

    def _compute(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) torques at Q (N, n) by Pinocchio, one configuration at a time."""
        model = self.model
        data = model.createData()
        idx_v = [model.joints[j].idx_v for j in self.chain.joint_ids]
        # the whole model's configurations at once (joints off the chain at their neutral value)
        full = np.tile(pin.neutral(model), (len(Q), 1))
        for k, jid in enumerate(self.chain.joint_ids):
            jm = model.joints[jid]
            if jm.nq == 2:
                full[:, jm.idx_q], full[:, jm.idx_q + 1] = np.cos(Q[:, k]), np.sin(Q[:, k])
            else:
                full[:, jm.idx_q] = Q[:, k]
        out = np.empty(Q.shape)
        for k, qf in enumerate(full):
            out[k] = -pin.computeGeneralizedGravity(model, data, qf)[idx_v]
        return out


class ComplianceTerm:
    """Scratch helper of :class:`calib.model.kinematics.ChainKinematics` for a model with compliance:
    effective joint values and the compliance columns of the Jacobian (torques cached per Q).

    The joint-term interface (shared with :class:`calib.model.periodic.PeriodicTerm`): ``idx``
    (k,) the parameters' indices, ``q_cols`` (k,) the theta_i (d_i) column each multiplies,
    :meth:`offsets` the joint deviations, :meth:`factors` the multipliers (here tau_i(q))."""

    def __init__(self, robot: RobotModel):
        self.gravity_model: GravityModel = robot.gravity
        self.c_idx = self.idx = robot.indices(robot.compliance_names)
        self.q_cols = robot.indices(joint_variable_names(robot.joints))

    def torques(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) gravity torques at Q (N, n), cached by content in the gravity model."""
        return self.gravity_model.torques(Q)

    def effective(self, Q: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(N, n) q + C tau(q) for Q (N, n) at parameter ``values`` (full vector)."""
        return Q + self.offsets(Q, values)

    def offsets(self, Q: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(N, n) the deflection C tau(q) at Q (N, n), parameter ``values`` (full vector)."""
        return self.torques(Q) * values[self.c_idx]

    def factors(self, Q: np.ndarray) -> np.ndarray:
        """(N, n) tau(q): the factor of each compliance's column."""
        return self.torques(Q)

    def fill_columns(self, J: np.ndarray, Q: np.ndarray) -> None:
        """Set the compliance columns of J (N, rows, n_params), computed at the effective joint
        values of Q (N, n): column c_i = column of theta_i (d_i) times tau_i(q)."""
        J[:, :, self.c_idx] = J[:, :, self.q_cols] * self.torques(Q)[:, None, :]


def compliance_term(robot: RobotModel) -> ComplianceTerm | None:
    """The :class:`ComplianceTerm` of a model with compliance, else None."""
    return ComplianceTerm(robot) if robot.has_compliance else None


def effective_configurations(robot: RobotModel, Q: np.ndarray) -> np.ndarray:
    """(N, n) joint values the chain really takes at commanded Q (N, n): q + C tau(q)
    (Q itself for a model without compliance)."""
    Q = np.atleast_2d(np.asarray(Q, float))
    if not robot.has_compliance:
        return Q
    return Q + robot.gravity.torques(Q) * robot.compliances()


def with_gravity(robot: RobotModel, *, payload: Payload | None = None,
                 gravity: Sequence[float] | None = None,
                 values: Sequence[float] | None = None) -> RobotModel:
    """``robot`` with compliance parameters (kept if it has them, else zeros, or ``values``) and
    the gravity model of its URDF with this payload and gravity."""
    return robot.with_compliance(GravityModel.for_robot(robot, payload=payload, gravity=gravity), values)
