"""The compliance sidecar file: the joint terms of a calibrated model beside its URDF, as JSON.

A URDF cannot hold joint compliance (:mod:`calib.model.compliance`) nor periodic joint errors
(:mod:`calib.model.periodic`), so ``calib calibrate --compliance`` / ``--periodic`` writes them
to ``NAME.compliance.json`` beside ``NAME.urdf`` (:func:`sidecar_path`, :func:`write_sidecar`);
the record (:func:`compliance_record`) is also the ``"compliance"`` entry of the JSON report.
:func:`read_compliance` reads either back, :func:`apply_record` gives a model its joint terms.
Values in SI units (rad/(N m), m/N; periodic coefficients rad); the payload's centre of mass in
mm. A record with periodic terms has the format ``calib-compliance/2`` (``"periodic"``: name ->
rad; ``"compliance"`` null without compliance); one with compliance alone keeps
``calib-compliance/1``, which earlier readers read.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from calib.errors import ParameterError
from calib.io.fileio import atomic_write_text
from calib.model.robot import RobotModel

if TYPE_CHECKING:       # (calib.model.compliance loads where a record is made, read or applied)
    from calib.io.compliance_record import ComplianceRecord
    from calib.model.compliance import GravityModel, Payload

#: Format tag of the compliance sidecar file (compliance only), and of one with periodic terms.
SIDECAR_FORMAT = "calib-compliance/1"
SIDECAR_FORMAT_PERIODIC = "calib-compliance/2"
_FORMATS = (SIDECAR_FORMAT, SIDECAR_FORMAT_PERIODIC)
PERIODIC_NOTE = ("the calibrated URDF holds the geometry only (URDF cannot hold periodic joint errors); "
                 "they are in this report and in the sidecar JSON written beside the URDF, which "
                 "'calib compensate --compliance' and 'calib evaluate --compliance' read")


def compliance_record(robot: RobotModel, std: dict[str, float] | None = None) -> dict:
    """The JSON-ready record of a model's joint terms (compliance, periodic): values in SI units
    (rad/(N m), m/N; rad), their std (SI, None when fixed), the payload and gravity the
    compliances were identified with, and the note that the URDF holds the geometry only."""
    from calib.model.compliance import URDF_NOTE

    gm: GravityModel | None = robot.gravity
    std = std or {}

    def sd(names):
        return {n: (None if n not in std or not math.isfinite(std[n]) else float(std[n])) for n in names}

    comp = robot.compliance_names
    rec = {"format": SIDECAR_FORMAT_PERIODIC if robot.has_periodic else SIDECAR_FORMAT,
           "joints": list(robot.joint_names),
           "units": {n: robot.parameters[robot.index(n)].unit for n in comp},
           "compliance": {n: float(v) for n, v in zip(comp, robot.compliances())} if comp else None,
           "std": sd(comp),
           "payload": None if gm is None or gm.payload is None else gm.payload.to_dict(),
           "gravity_m_s2": None if gm is None else [float(x) for x in gm.gravity],
           "note": URDF_NOTE}
    if robot.has_periodic:
        rec["periodic"] = {n: float(v) for n, v in zip(robot.periodic_names, robot.periodic_values())}
        rec["periodic_std"] = sd(robot.periodic_names)
        rec["note"] = (URDF_NOTE + "; the periodic joint errors likewise") if comp else PERIODIC_NOTE
    return rec


def sidecar_path(urdf_path: str | Path) -> Path:
    """The sidecar beside a calibrated URDF: ``NAME.urdf`` -> ``NAME.compliance.json``."""
    p = Path(urdf_path)
    return p.with_name(p.stem + ".compliance.json")


def write_sidecar(path: str | Path, record: dict) -> None:
    """Write a compliance record (:func:`compliance_record`) as JSON, atomically."""
    import json

    atomic_write_text(path, json.dumps(record, indent=2, allow_nan=False) + "\n")


def read_compliance(path: str | Path) -> ComplianceRecord:
    """Read compliances from a sidecar JSON (:func:`write_sidecar`) or a ``calib calibrate
    --report`` JSON (its ``"compliance"`` entry). Raises :class:`ParameterError` naming the file
    and what was expected."""
    import json

    from calib.model.compliance import Payload, finite_vector

    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ParameterError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParameterError(f"{path}: not a JSON file ({exc})") from None
    rec = doc.get("compliance") if isinstance(doc, dict) and doc.get("format") not in _FORMATS else doc
    if not isinstance(rec, dict) or rec.get("format") not in _FORMATS:
        raise ParameterError(f"{path}: no compliance record (expected a {SIDECAR_FORMAT!r} or "
                             f"{SIDECAR_FORMAT_PERIODIC!r} sidecar or a calibration report made with "
                             f"--compliance or --periodic)")
    try:
        joints = tuple(str(j) for j in rec["joints"])
        values = payload = gravity = periodic = None
        if rec["compliance"] is not None or rec["format"] == SIDECAR_FORMAT:
            vals = [rec["compliance"][f"c{i}"] for i in range(1, len(joints) + 1)]
            values = np.array([float(v) for v in vals])
            pl = rec.get("payload")
            payload = None if pl is None else Payload(pl["mass_kg"], np.asarray(pl["com_mm"], float) * 1e-3)
            gravity = finite_vector(rec["gravity_m_s2"], "gravity_m_s2")
        if rec["format"] == SIDECAR_FORMAT_PERIODIC:
            periodic = {str(k): float(v) for k, v in rec["periodic"].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ParameterError(f"{path}: malformed compliance record: {exc!r}") from None
    except ParameterError as exc:
        raise ParameterError(f"{path}: {exc}") from None
    if (values is not None and not np.all(np.isfinite(values))) or \
            (periodic is not None and not all(math.isfinite(v) for v in periodic.values())):
        raise ParameterError(f"{path}: compliance and periodic values must be finite numbers")
    if values is None and periodic is None:
        raise ParameterError(f"{path}: the record holds neither compliances nor periodic terms")
    from calib.io.compliance_record import ComplianceRecord

    return ComplianceRecord(joints, values, payload, gravity, periodic)


def apply_record(robot: RobotModel, record: ComplianceRecord, *, payload: Payload | None = None,
                 gravity: Sequence[float] | None = None, torques_from: RobotModel | None = None,
                 source: str | Path = "compliance") -> RobotModel:
    """``robot`` (geometry) with the record's joint terms: its compliances, with the record's
    payload and gravity unless others are given (the payload may differ between calibration and
    use), and its periodic coefficients.

    torques_from : the model whose URDF gives the torques (default ``robot``). Calibration
    computes them on the nominal URDF; pass the nominal model to reproduce the calibrated model
    exactly (the calibrated URDF's slightly different geometry changes the torques by ~1e-3 of
    themselves, sub-micrometre at the tool)."""
    from calib.model.compliance import GravityModel

    if tuple(record.joints) != robot.joint_names:
        raise ParameterError(f"{source}: the compliances are for joints {list(record.joints)}, the "
                             f"robot has {list(robot.joint_names)}")
    if record.values is None:
        if payload is not None or gravity is not None:
            raise ParameterError(f"{source}: holds no compliances: a payload or gravity does not apply")
    else:
        src = robot if torques_from is None else torques_from
        gm = GravityModel.for_robot(src, payload=record.payload if payload is None else payload,
                                    gravity=record.gravity if gravity is None else gravity)
        robot = robot.with_compliance(gm, record.values)
    if record.periodic is not None:
        names = robot.with_periodic().periodic_names
        if set(names) != set(record.periodic):
            raise ParameterError(f"{source}: periodic terms {sorted(record.periodic)} do not match the "
                                 f"robot's revolute joints ({', '.join(names)})")
        robot = robot.with_periodic([record.periodic[n] for n in names])
    return robot
