"""Joint values against the URDF limits, for the CSV layer (:func:`calib.io.csv.layer.read_table`).

A value past a limit by at most the limit tolerance (a fraction of the joint range) is kept with a
note naming the rows; further beyond is a :class:`calib.MeasurementFormatError` naming the row and
column, whose hint fits the size of the excess (a unit mix-up only when the value is several
times the largest limit and fits the limits in the other unit). Continuous joints are not checked.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.csv.header import ANGLE_UNITS, LENGTH_UNITS

__all__ = ["check_limits", "UNIT_HINT_EXCESS", "UNIT_HINT_RATIO"]

#: Past a limit by more than this fraction of the joint range is more than a reading just past it.
UNIT_HINT_EXCESS = 0.1
#: A unit mix-up is suggested only for values at least this many times the largest limit.
UNIT_HINT_RATIO = 3.0


def check_limits(path: Path, robot, columns: dict, q: np.ndarray, rows: np.ndarray,
                  tolerance: float) -> list[str]:
    """Notes for readings just past a limit; raise on the first row (then first column in header
    order) further beyond."""
    lo, hi = robot.lower, robot.upper
    checked = np.array([j.kind != "continuous" for j in robot.joints]) & np.isfinite(lo) & \
        np.isfinite(hi)
    span = np.where(checked, hi - lo, 0.0)
    tol = tolerance * span
    below, above = lo - q, q - hi                       # > 0 outside
    excess = np.where(checked, np.maximum(below, above), -np.inf)
    beyond = excess > tol + 1e-12
    notes = []
    for i in np.flatnonzero(((excess > 0) & ~beyond).any(axis=0)):
        c = columns[int(i)]
        near = np.flatnonzero((excess[:, i] > 0) & ~beyond[:, i])
        shown = ", ".join(str(r) for r in rows[near[:10]]) + (", ..." if len(near) > 10 else "")
        notes.append(f"{path}: {robot.joints[i].name} is past its joint limit by up to "
                     f"{excess[near, i].max() / c.scale:.4g} {c.unit} (within the limit tolerance, "
                     f"{100 * tolerance:.3g} % of the range = {tol[i] / c.scale:.3g} {c.unit}) in row"
                     f"{'s' if len(near) > 1 else ''} {shown}; kept as read")
    if not beyond.any():
        return notes
    k = int(np.flatnonzero(beyond.any(axis=1))[0])
    i = int(min(np.flatnonzero(beyond[k]), key=lambda j: columns[int(j)].index))
    c, joint = columns[i], robot.joints[i]
    value = q[k, i] / c.scale
    count = int(beyond[:, i].sum())
    others = f" ({count} rows of this column are outside)" if count > 1 else ""
    side = "upper" if above[k, i] > 0 else "lower"
    reason = (f"{joint.name} = {value:.6g} {c.unit} is outside the joint limits "
              f"[{lo[i] / c.scale:.6g}, {hi[i] / c.scale:.6g}] {c.unit}{others}: "
              f"{excess[k, i] / c.scale:.4g} {c.unit} past the {side} limit, "
              f"{100 * excess[k, i] / span[i]:.3g} % of the joint range")
    hint = (f"; beyond the limit tolerance ({100 * tolerance:.3g} % of the range); if the reading "
            f"is right, raise it (--limit-tolerance) or the URDF limit")
    if excess[k, i] > UNIT_HINT_EXCESS * span[i]:
        hint = "; check the joint order, the zero offsets and the URDF limits"
        # a unit mix-up multiplies the value by 180/pi or 1000: only suggest one when the value
        # is several times the largest limit and fits the limits in the other unit
        scale_off = abs(value) >= UNIT_HINT_RATIO * max(abs(lo[i]), abs(hi[i]))
        if c.unit == "rad" and not joint.is_prismatic and scale_off:
            fits = lo[i] - tol[i] <= value * ANGLE_UNITS["deg"] <= hi[i] + tol[i]
            small = max(abs(lo[i]), abs(hi[i])) <= 2 * math.pi + 1e-3
            if fits or (abs(value) > 2 * math.pi and small):
                hint = "; degrees given as radians? use the _deg suffix"
        elif c.unit == "m" and joint.is_prismatic and scale_off:
            if lo[i] - tol[i] <= value * LENGTH_UNITS["mm"] <= hi[i] + tol[i]:
                hint = "; millimetres given as metres? use the _mm suffix"
    raise MeasurementFormatError(path, reason + hint, row=int(rows[k]), column=c.name)
