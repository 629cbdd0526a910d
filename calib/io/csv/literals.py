"""Literals in one cell of a CSV file: a whole pose or all joints of a row as a URScript or RAPID
controller prints them (:mod:`calib.io.csv.layer` reads the columns that hold them).

- pose: URScript ``p[x,y,z,rx,ry,rz]`` (m, rotation vector in rad) or RAPID robtarget
  ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a,...]]`` (mm, quaternion w first);
- joints: URScript ``[q1,...,qn]`` (rad; m for prismatic joints) or RAPID jointtarget
  ``[[j1,...,j6],[eax_a,...]]`` (deg; mm for prismatic joints).

Errors are :class:`calib.MeasurementFormatError` naming the file, row and column.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError

__all__ = ["literal_groups", "pose_literals", "joint_literals"]

_POSE_FORMS = ("URScript pose p[x,y,z,rx,ry,rz] (m, rotation vector in rad) or RAPID robtarget "
               "[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a,...,eax_f]] (mm, quaternion w first)")
_JOINT_FORMS = ("URScript joint list [q1,...,qn] (rad; m for prismatic joints) or RAPID jointtarget "
                "[[j1,...,j6],[eax_a,...,eax_f]] (deg; mm for prismatic joints)")


def literal_groups(text: str) -> tuple[str, list[list[str]]] | None:
    """("p", [[6 fields]]) for ``p[...]``, ("flat", [[fields]]) for ``[...]``, ("nested",
    [[fields], ...]) for ``[[...],[...],...]``; None for anything else."""
    t = text.strip()
    if t[:1] in "pP" and t[1:].lstrip().startswith("["):
        inner = t[1:].strip()
        if not inner.endswith("]") or "[" in inner[1:-1] or "]" in inner[1:-1]:
            return None
        return "p", [inner[1:-1].split(",")]
    if not (t.startswith("[") and t.endswith("]")):
        return None
    inner = t[1:-1].strip()
    if "[" not in inner:
        return ("flat", [inner.split(",")]) if "]" not in inner else None
    groups, rest = [], inner
    while rest:
        if not rest.startswith("["):
            return None
        end = rest.find("]")
        if end < 0 or "[" in rest[1:end]:
            return None
        groups.append(rest[1:end].split(","))
        rest = rest[end + 1:].lstrip()
        if rest.startswith(","):
            rest = rest[1:].lstrip()
            if not rest:
                return None
        elif rest:
            return None
    return "nested", groups


def _literal_numbers(path, row, column, text, fields, forms) -> list[float]:
    out = []
    for f in fields:
        try:
            v = float(f) if "_" not in f else math.nan
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise MeasurementFormatError(path, f"{f.strip()!r} in {text.strip()!r:.80} is not a finite "
                                               f"number; expected a {forms}", row=row, column=column)
        out.append(v)
    return out


def pose_literals(path: Path, column: str, texts, rows: np.ndarray) -> tuple[str, np.ndarray]:
    """(orientation kind, (N, 6 or 7) SI values x, y, z then the orientation) of the cells of a
    pose column: all URScript poses (rotation vector) or all RAPID robtargets (quaternion)."""
    out, first = [], None
    for text, row in zip(texts, rows.tolist()):
        parsed = literal_groups(text)
        form = None
        if parsed is not None:
            kind, groups = parsed
            if kind == "p" and len(groups[0]) == 6:
                form = "urscript"
            elif kind == "nested" and len(groups) == 4 and len(groups[0]) == 3 and len(groups[1]) == 4:
                form = "robtarget"
        if form is None:
            raise MeasurementFormatError(path, f"{text.strip()!r:.80} is not a pose literal; expected a "
                                               f"{_POSE_FORMS}", row=row, column=column)
        if first is None:
            first = (form, row)
        elif form != first[0]:
            raise MeasurementFormatError(path, f"a {form} literal, but row {first[1]} holds a {first[0]} "
                                               f"one; expected one form per column", row=row, column=column)
        if form == "urscript":
            out.append(_literal_numbers(path, row, column, text, groups[0], _POSE_FORMS))
        else:
            xyz = _literal_numbers(path, row, column, text, groups[0], _POSE_FORMS)
            wxyz = _literal_numbers(path, row, column, text, groups[1], _POSE_FORMS)
            out.append([v * 1e-3 for v in xyz] + wxyz)
    return ("rotvec" if first[0] == "urscript" else "quaternion"), np.array(out, dtype=float)


def joint_literals(path: Path, robot, column: str, texts, rows: np.ndarray) -> np.ndarray:
    """(N, n) SI joint values of the cells of a joints column: URScript lists (rad, m) or RAPID
    jointtargets (deg, mm; the first n of the six robot axes, the others must be 0 or 9E9)."""
    n = robot.n_joints
    scale_rapid = np.where(robot.prismatic, 1e-3, math.pi / 180.0)
    out = np.empty((len(texts), n))
    for k, (text, row) in enumerate(zip(texts, rows.tolist())):
        parsed = literal_groups(text)
        values = None
        if parsed is not None:
            kind, groups = parsed
            if kind == "flat":
                values = _literal_numbers(path, row, column, text, groups[0], _JOINT_FORMS)
                if len(values) != n:
                    raise MeasurementFormatError(path, f"{text.strip()!r:.80} holds {len(values)} joint values, "
                                                       f"expected {n} (the robot's joints "
                                                       f"{', '.join(robot.joint_names)})", row=row, column=column)
                out[k] = values
                continue
            if kind == "nested" and len(groups) == 2 and len(groups[0]) == 6 and n <= 6:
                values = _literal_numbers(path, row, column, text, groups[0], _JOINT_FORMS)
                extra = values[n:]
                if any(v != 0 and abs(v) < 8.9e9 for v in extra):
                    raise MeasurementFormatError(path, f"{text.strip()!r:.80}: robot axes {n + 1}..6 hold "
                                                       f"values but the robot has {n} joints; expected 0 or "
                                                       f"9E9 there", row=row, column=column)
                out[k] = np.array(values[:n]) * scale_rapid
                continue
        raise MeasurementFormatError(path, f"{text.strip()!r:.80} is not a joint literal; expected a "
                                           f"{_JOINT_FORMS}", row=row, column=column)
    return out
