"""The compliance sidecar file: joint compliances beside a calibrated URDF, as JSON.

A URDF cannot hold joint compliance (:mod:`calib.model.compliance`), so ``calib calibrate
--compliance`` writes them to ``NAME.compliance.json`` beside ``NAME.urdf`` (:func:`sidecar_path`,
:func:`write_sidecar`); the record (:func:`compliance_record`) is also the ``"compliance"`` entry
of the JSON report. :func:`read_compliance` reads either back, :func:`apply_record` gives a model
its compliances. Values in SI units (rad/(N m), m/N); the payload's centre of mass in mm.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from calib.errors import ParameterError
from calib.io.fileio import atomic_write_text
from calib.model.compliance import URDF_NOTE, GravityModel, Payload, _finite_vector
from calib.model.robot import RobotModel

#: Format tag of the compliance sidecar file.
SIDECAR_FORMAT = "calib-compliance/1"


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
