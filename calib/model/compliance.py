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
* :func:`calib.model.jacobian.pose_jacobian` fills the compliance columns with
  :meth:`ComplianceTerm.fill_columns`.

A calibrated URDF holds the geometry only; the compliances travel in a small JSON sidecar
(:func:`write_sidecar`, the same object as the ``"compliance"`` entry of the JSON report) that
:func:`read_compliance` reads back for compensation.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pinocchio as pin

from calib.errors import CalibError, ParameterError
from calib.model.robot import RobotModel
from calib.io.urdf_reader import read_urdf_chain

#: Standard gravity, m/s^2, along -z of the URDF root frame by default.
STANDARD_GRAVITY = 9.80665
#: Format tag of the compliance sidecar file.
SIDECAR_FORMAT = "calib-compliance/1"
URDF_NOTE = ("the calibrated URDF holds the geometry only (URDF cannot hold joint compliance); "
             "the compliances are in this report and in the sidecar JSON written beside the URDF, "
             "which 'calib compensate --compliance' reads")
#: Torque cache entries kept per model (the calibration rows' chunks are re-evaluated each step).
_CACHE_SIZE = 16


def _finite_vector(value, name: str, size: int = 3) -> np.ndarray:
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
        c = _finite_vector(self.com_tool, "payload centre of mass")
        c.setflags(write=False)
        object.__setattr__(self, "com_tool", c)

    def to_dict(self) -> dict:
        return {"mass_kg": self.mass, "com_mm": [float(x) * 1e3 for x in self.com_tool]}


@dataclass(frozen=True, eq=False)
class GravityModel:
    """Gravity torques on the joints of a URDF chain (a constant model; see the module docstring).

    model : Pinocchio model of the whole URDF with the payload added to the tool frame's body
    and ``model.gravity`` set; joint_ids : Pinocchio ids of the chain's joints (base to tool);
    chain : the :class:`calib.io.urdf_reader.UrdfChain`; payload : the :class:`Payload` or None;
    gravity : (3,) m/s^2 in the URDF root frame; link_mass : kg of the links the chain moves
    (0 for a URDF without inertias).
    """

    model: pin.Model = field(repr=False)
    chain: object = field(repr=False)
    payload: Payload | None
    gravity: np.ndarray
    link_mass: float

    @classmethod
    def from_urdf(cls, urdf_path: str | Path, *, base_frame: str | None = None,
                  tool_frame: str | None = None, payload: Payload | None = None,
                  gravity: Sequence[float] | None = None) -> "GravityModel":
        """The gravity model of the chain between ``base_frame`` and ``tool_frame`` of a URDF.

        payload : carried at ``tool_frame``; gravity : (3,) m/s^2 in the URDF root frame
        (default (0, 0, -9.80665)). Raises :class:`calib.CalibError` subclasses.
        """
        if payload is not None and not isinstance(payload, Payload):
            raise ParameterError(f"payload must be a calib.model.compliance.Payload, got {type(payload).__name__}")
        g = np.array([0.0, 0.0, -STANDARD_GRAVITY]) if gravity is None else _finite_vector(gravity, "gravity")
        chain = read_urdf_chain(urdf_path, base_frame, tool_frame)
        model = pin.Model(chain.model)
        first = chain.joint_ids[0]
        link_mass = float(sum(model.inertias[j].mass for j in model.subtrees[first]))
        if payload is not None and payload.mass > 0:
            frame = model.frames[chain.tool_frame_id]
            inertia = pin.Inertia(payload.mass, np.array(payload.com_tool), np.zeros((3, 3)))
            jid = frame.parentJoint
            model.inertias[jid] = model.inertias[jid] + frame.placement.act(inertia)
        model.gravity = pin.Motion(g.copy(), np.zeros(3))
        g.setflags(write=False)
        return cls(model=model, chain=chain, payload=payload, gravity=g, link_mass=link_mass)

    @classmethod
    def for_robot(cls, robot: RobotModel, *, payload: Payload | None = None,
                  gravity: Sequence[float] | None = None) -> "GravityModel":
        """The gravity model of ``robot``'s chain in the URDF it was read from."""
        if robot.urdf_path is None:
            raise ParameterError("compliance needs the robot's URDF (its inertias and tool frame): "
                                 "load the robot with calib.load_robot")
        gm = cls.from_urdf(robot.urdf_path, base_frame=robot.base_frame, tool_frame=robot.tool_frame,
                           payload=payload, gravity=gravity)
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
        Q = np.atleast_2d(np.asarray(Q, float))
        data = self.model.createData()
        idx_v = [self.model.joints[j].idx_v for j in self.chain.joint_ids]
        out = np.empty(Q.shape)
        for k, q in enumerate(Q):
            out[k] = -pin.computeGeneralizedGravity(self.model, data, self.chain.configuration(q))[idx_v]
        return out


class ComplianceTerm:
    """Scratch helper of :class:`calib.model.kinematics.ChainKinematics` for a model with compliance:
    effective joint values and the compliance columns of the Jacobian (torques cached per Q)."""

    def __init__(self, robot: RobotModel):
        self.gravity_model: GravityModel = robot.gravity
        self.c_idx = robot.indices(robot.compliance_names)
        self.q_cols = robot.indices([f"d{i}" if j.is_prismatic else f"theta{i}"
                                     for i, j in enumerate(robot.joints, start=1)])
        self._cache: dict = {}

    def torques(self, Q: np.ndarray) -> np.ndarray:
        Q = np.ascontiguousarray(Q, dtype=float)
        key = (Q.shape, hash(Q.tobytes()))
        tau = self._cache.get(key)
        if tau is None:
            tau = self.gravity_model.torques(Q)
            if len(self._cache) >= _CACHE_SIZE:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = tau
        return tau

    def effective(self, Q: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(N, n) q + C tau(q) for Q (N, n) at parameter ``values`` (full vector)."""
        return Q + self.torques(Q) * values[self.c_idx]

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


# ====================================================================== sidecar
def compliance_record(robot: RobotModel, std: dict[str, float] | None = None) -> dict:
    """The JSON-ready compliance record of a model with compliance: values in SI units
    (rad/(N m), m/N), their std (SI, None when fixed), the payload and gravity it was identified
    with, and the note that the URDF holds the geometry only."""
    gm: GravityModel = robot.gravity
    std = std or {}
    return {"format": SIDECAR_FORMAT,
            "joints": list(robot.joint_names),
            "units": {n: robot.parameters[robot.index(n)].unit for n in robot.compliance_names},
            "compliance": {n: float(v) for n, v in zip(robot.compliance_names, robot.compliances())},
            "std": {n: (None if n not in std or not math.isfinite(std[n]) else float(std[n]))
                    for n in robot.compliance_names},
            "payload": None if gm.payload is None else gm.payload.to_dict(),
            "gravity_m_s2": [float(x) for x in gm.gravity],
            "note": URDF_NOTE}


def sidecar_path(urdf_path: str | Path) -> Path:
    """The sidecar beside a calibrated URDF: ``NAME.urdf`` -> ``NAME.compliance.json``."""
    p = Path(urdf_path)
    return p.with_name(p.stem + ".compliance.json")


def write_sidecar(path: str | Path, record: dict) -> None:
    """Write a compliance record (:func:`compliance_record`) as JSON, atomically."""
    from calib.io.fileio import atomic_write_text

    atomic_write_text(path, json.dumps(record, indent=2, allow_nan=False) + "\n")


@dataclass(frozen=True)
class ComplianceRecord:
    """Compliances read from a sidecar or a JSON report: values (n,) SI, in joint order, the
    joint names, and the payload and gravity of the calibration (None / (3,) m/s^2)."""

    joints: tuple[str, ...]
    values: np.ndarray
    payload: Payload | None
    gravity: np.ndarray


def read_compliance(path: str | Path) -> ComplianceRecord:
    """Read compliances from a sidecar JSON (:func:`write_sidecar`) or a ``calib calibrate
    --report`` JSON (its ``"compliance"`` entry). Raises :class:`ParameterError` naming the file
    and what was expected."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParameterError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParameterError(f"{path}: not a JSON file ({exc})") from None
    rec = doc.get("compliance") if isinstance(doc, dict) and doc.get("format") != SIDECAR_FORMAT else doc
    if not isinstance(rec, dict) or rec.get("format") != SIDECAR_FORMAT:
        raise ParameterError(f"{path}: no compliance record (expected a {SIDECAR_FORMAT!r} sidecar or a "
                             f"calibration report made with --compliance)")
    try:
        joints = tuple(str(j) for j in rec["joints"])
        vals = [rec["compliance"][f"c{i}"] for i in range(1, len(joints) + 1)]
        values = np.array([float(v) for v in vals])
        pl = rec.get("payload")
        payload = None if pl is None else Payload(pl["mass_kg"], np.asarray(pl["com_mm"], float) * 1e-3)
        gravity = _finite_vector(rec["gravity_m_s2"], "gravity_m_s2")
    except (KeyError, TypeError, ValueError) as exc:
        raise ParameterError(f"{path}: malformed compliance record: {exc!r}") from None
    except ParameterError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    if not np.all(np.isfinite(values)):
        raise ParameterError(f"{path}: compliance values must be finite numbers")
    return ComplianceRecord(joints, values, payload, gravity)


def apply_record(robot: RobotModel, record: ComplianceRecord, *, payload: Payload | None = None,
                 gravity: Sequence[float] | None = None, torques_from: RobotModel | None = None,
                 source: str | Path = "compliance") -> RobotModel:
    """``robot`` (geometry) with the record's compliances, and the record's payload and gravity
    unless others are given (the payload may differ between calibration and use).

    torques_from : the model whose URDF gives the torques (default ``robot``). Calibration
    computes them on the nominal URDF; pass the nominal model to reproduce the calibrated model
    exactly (the calibrated URDF's slightly different geometry changes the torques by ~1e-3 of
    themselves, sub-micrometre at the tool)."""
    if tuple(record.joints) != robot.joint_names:
        raise ParameterError(f"{source}: the compliances are for joints {list(record.joints)}, the "
                             f"robot has {list(robot.joint_names)}")
    src = robot if torques_from is None else torques_from
    gm = GravityModel.for_robot(src, payload=record.payload if payload is None else payload,
                                gravity=record.gravity if gravity is None else gravity)
    return robot.with_compliance(gm, record.values)


def parse_triple(text: str, option: str, scale: float = 1.0) -> np.ndarray:
    """(3,) from "X,Y,Z" (times ``scale``); ParameterError naming ``option`` otherwise."""
    parts = [s.strip() for s in str(text).split(",")]
    try:
        v = np.array([float(s) for s in parts])
    except ValueError:
        raise ParameterError(f"{option} {text!r}: expected three numbers X,Y,Z") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ParameterError(f"{option} {text!r}: expected three finite numbers X,Y,Z")
    return v * scale
