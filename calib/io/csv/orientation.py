"""Ambiguous orientation columns decided by the rows, or refused.

Three columns named ``rx, ry, rz`` (in that order, with a unit suffix, no convention stated) may
be calib's ZYX angles ``R = Rz(rz) Ry(ry) Rx(rx)`` (the same as fixed-axis XYZ angles: Yaskawa,
Fanuc), a rotation vector (UR) or XYZ Euler angles ``R = Rx Ry Rz`` (Staubli). The rows of a
measurement file decide it when exactly one reading agrees with the robot:

the rotation angle between the tool orientations of two rows, ``angle(R_k^T R_l)``, does not
depend on the measurement frame nor on the tool's mounting (``R_k = R_meas_base R(q_k)
R_flange_tool``: the relative rotation is conjugated by ``R_flange_tool``, which keeps its
angle). So each reading's angles between consecutive rows are compared with the nominal model's
at the rows' joint values, without any frame to estimate: the median absolute difference is the
reading's score. A reading is taken when its score is at most :data:`DECIDE_MAX` (a nominal
model is better than 3 degrees) and every other reading's is at least :data:`MARGIN` times it and
at least twice :data:`DECIDE_MAX`; otherwise the file is refused with the candidates and the
scores. The note of the reading says which it took and the scores.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError
from calib.io.csv.conventions import DECIDE_MAX, MARGIN

__all__ = ["DECIDE_MAX", "MARGIN", "MIN_PAIRS", "decide_rx_ry_rz"]

#: Fewest pairs of rows (with a relative rotation of the model above 0.1 rad) that decide.
MIN_PAIRS = 5
#: Rows compared (the first ones): the decision costs one kinematics pass over them.
MAX_ROWS = 2000

#: reading -> (orientation kind of the reader, its column keys for rx, ry, rz, Euler sequence, text)
READINGS = {
    "zyx": ("zyx", ("rx", "ry", "rz"), None, "ZYX angles (= fixed-axis XYZ)"),
    "rotvec": ("rotvec", ("rvx", "rvy", "rvz"), None, "a rotation vector"),
    "XYZ": ("euler", ("e1", "e2", "e3"), "XYZ", "XYZ Euler angles"),
}


def _angles(R: np.ndarray) -> np.ndarray:
    """(N-1,) rotation angles (rad) between consecutive rotations of R (N, 3, 3)."""
    c = (np.einsum("kij,kij->k", R[:-1], R[1:]) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def _rotations(reading: str, v: np.ndarray) -> np.ndarray:
    from calib.model.spatial import rotation_from_rotvec, rotation_from_zyx

    if reading == "zyx":
        return rotation_from_zyx(v[:, ::-1])        # (rz, ry, rx)
    if reading == "rotvec":
        return rotation_from_rotvec(v)
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("XYZ", v).as_matrix()


def decide_rx_ry_rz(path: Path, message: str, row: int, column: str, names: str, robot,
                    q: np.ndarray | None, rx_ry_rz: np.ndarray) -> tuple[str, str]:
    """(reading, note) for rx, ry, rz values (N, 3) rad at joint values q (N, n) rad / m; raises
    :class:`calib.MeasurementFormatError` (``message`` and the scores, at the header ``row`` and
    ``column``) when the rows do not decide it (module docstring). names : the columns as written,
    for the note."""
    if q is None:
        raise MeasurementFormatError(path, f"{message}; the rows cannot decide it here (no joint "
                                           f"values in this file)", row=row, column=column)
    from calib.model.kinematics import ChainKinematics

    n = min(len(q), MAX_ROWS)
    R_model = ChainKinematics(robot).frame_poses(q[:n], frame="flange")[0]
    model = _angles(R_model)
    informative = model > 0.1
    scores = {}
    if informative.sum() >= MIN_PAIRS:
        for reading in READINGS:
            data = _angles(_rotations(reading, rx_ry_rz[:n]))
            scores[reading] = float(np.median(np.abs(data - model)[informative]))
    shown = ", ".join(f"{READINGS[r][3]} {s:.3g} rad" for r, s in sorted(scores.items(), key=lambda i: i[1]))
    if scores:
        best = min(scores, key=scores.get)
        others = [s for r, s in scores.items() if r != best]
        if scores[best] <= DECIDE_MAX and all(s >= max(MARGIN * scores[best], 2 * DECIDE_MAX) for s in others):
            return best, (f"{path}: {names} read as {READINGS[best][3]}: the rows decide it (median "
                          f"difference of the rotation angles between consecutive rows from the nominal "
                          f"model's: {shown}); state it with --convention to skip this check")
        why = (f"the rows do not decide it (median difference of the rotation angles between "
               f"consecutive rows from the nominal model's: {shown}; a reading is taken at most "
               f"{DECIDE_MAX:g} rad and {MARGIN:g} times below the others)")
    else:
        why = (f"the rows do not decide it (fewer than {MIN_PAIRS} pairs of consecutive rows "
               f"rotate the nominal model's flange by more than 0.1 rad)")
    raise MeasurementFormatError(path, f"{message}; {why}", row=row, column=column)
