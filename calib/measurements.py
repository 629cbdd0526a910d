"""Measurement files: joint values with the measured tool pose, one robot pose per row.

A measurement file is a CSV table with one row per robot pose: the joint values (as commanded or
read from the controller) and the pose of the tool frame measured in the ``meas`` frame (laser
tracker, CMM, ...). :func:`read_measurements` reads it against a :class:`calib.RobotModel` into a
:class:`Measurements`; :func:`write_measurements` writes one.

CSV format
----------
- Comma separated, one record per line, read with Python's :mod:`csv` module (fields may be
  quoted). The file is UTF-8 (a byte-order mark is accepted).
- Lines whose first non-blank character is ``#`` are comments, anywhere in the file (also before
  the header). Blank lines are ignored. Row numbers in error messages are line numbers in the file,
  counting every line (comments and blank lines included), starting at 1.
- The first line that is neither a comment nor blank is the header. Column names are
  case-sensitive; whitespace around them is ignored. Columns may come in any order, and each
  column carries its own unit (``x_mm`` next to ``y_m`` is allowed).
- **Joints** (required): one column per joint of the robot, each exactly once, named either after
  the URDF joint (``joint1_deg``) or ``q1`` ... ``qn`` in chain order (``q1_deg``); one naming style
  per file. Unit suffix ``_rad`` or ``_deg`` (revolute and continuous joints), ``_m`` or ``_mm``
  (prismatic joints). Values must lie within the URDF joint limits (tolerance 1e-6 rad or m);
  continuous joints are not checked.
- **Position** (required): ``x``, ``y``, ``z`` with suffix ``_m`` or ``_mm``: the origin of the tool
  frame in the meas frame.
- **Orientation** (optional) of the tool frame in the meas frame, one of

  - a unit quaternion ``qw``, ``qx``, ``qy``, ``qz`` (no suffix, scalar first). A norm further than
    1e-3 from 1 is an error; otherwise it is normalised;
  - ZYX angles ``rz``, ``ry``, ``rx`` with suffix ``_rad`` or ``_deg`` (yaw, pitch, roll):
    R = Rz(rz) Ry(ry) Rx(rx), the rotation of Eq. (3) of the paper;
  - nothing: position-only measurements.

  An incomplete set (``qw``, ``qx`` only) or both sets in one file is an error.
- **set** (optional): ``cal`` (used for identification) or ``val`` (held out for validation),
  case-insensitive.

Example (the bundled BRTIRUS0707A; ``set`` may be left out, and so may ``qw`` ... ``qz``)::

    # BRTIRUS0707A, laser tracker T-Mac on the tool flange
    joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz,set
    0,0,0,0,0,0,441.0,0.0,-36.5,0.0,1.0,0.0,0.0,cal
    10,-20,30,0,45,90,256.267,45.187,131.509,0.35372,0.67949,-0.57016,-0.29681,val

The same poses with ``q1`` ... ``q6`` in radians and ZYX angles::

    q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m,rz_deg,ry_deg,rx_deg
    0,0,0,0,0,0,0.441,0.0,-0.0365,0,0,180
    0.174533,-0.349066,0.523599,0,0.785398,1.570796,0.256267,0.045187,0.131509,-80,0,125

Every departure from this format raises :class:`calib.MeasurementFormatError`, whose message is
one line naming the file, the row (line number) and the column, and what was expected.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, replace
from io import StringIO
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import CalibError, DataError, MeasurementFormatError
from .fileio import atomic_write_text, check_not_input
from .robot import RobotModel
from .spatial import (quaternion_from_rotation, rotation_from_quaternion, rotation_from_zyx,
                      zyx_from_rotation)

__all__ = ["Measurements", "read_measurements", "write_measurements"]

#: Multiply a value in the unit of the suffix by this to get SI (radians, metres).
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
POSITION_COLUMNS = ("x", "y", "z")
QUATERNION_COLUMNS = ("qw", "qx", "qy", "qz")
ZYX_COLUMNS = ("rz", "ry", "rx")
SET_COLUMN = "set"
SET_VALUES = ("cal", "val")

#: Tolerance of the joint limit check, rad or m.
LIMIT_TOLERANCE = 1e-6
#: Largest accepted distance of a quaternion's norm from 1.
QUATERNION_NORM_TOLERANCE = 1e-3
#: Tolerance of the orthonormality check of rotation matrices given to :class:`Measurements`.
ROTATION_TOLERANCE = 1e-6


# ====================================================================== data
@dataclass(frozen=True, eq=False)
class Measurements:
    """Measured tool poses with the joint values they were taken at (immutable, SI units).

    Attributes
    ----------
    q : (N, n) float, radians (revolute and continuous joints) or metres (prismatic), chain order.
    position : (N, 3) float, metres: origin of the tool frame in the meas frame.
    rotation : (N, 3, 3) float rotation matrices of the tool frame in the meas frame (the rotation
        part of ``T_meas_tool``), or None for position-only measurements.
    rows : (N,) int: 1-based line numbers in the source file (for error messages and outlier
        reports); 1 ... N for data not read from a file.
    sets : (N,) str, each ``"cal"`` or ``"val"``; None when the data has no set column.
    joint_names : (n,) the joint names in chain order; default ``q1`` ... ``qn``.
    source : the file the data was read from, or None.
    prismatic : (n,) bool: which joints are prismatic (their ``q`` is in metres); default none.
        Needed to write the right unit suffixes.

    All arrays are read-only copies. The constructor checks shapes, finiteness, the set labels
    and that each rotation is orthonormal with determinant +1 (to 1e-6), and raises
    :class:`calib.DataError` otherwise.
    """

    q: np.ndarray
    position: np.ndarray
    rotation: np.ndarray | None = None
    rows: np.ndarray | None = None
    sets: np.ndarray | None = None
    joint_names: tuple[str, ...] | None = None
    source: Path | None = None
    prismatic: np.ndarray | None = None

    def __post_init__(self):
        q = finite_array(self.q, "q")
        if q.ndim != 2:
            raise DataError(f"q must be an (N, n) array of joint values, got shape {q.shape}")
        N, n = q.shape
        position = finite_array(self.position, "position")
        if position.shape != (N, 3):
            raise DataError(f"position must be ({N}, 3) (one row per pose of q), got shape "
                            f"{position.shape}")
        rotation = None
        if self.rotation is not None:
            rotation = finite_array(self.rotation, "rotation")
            if rotation.shape != (N, 3, 3):
                raise DataError(f"rotation must be ({N}, 3, 3) or None, got shape {rotation.shape}")
            err = np.abs(rotation @ np.swapaxes(rotation, 1, 2) - np.eye(3)).max(axis=(1, 2))
            bad = np.flatnonzero((err > ROTATION_TOLERANCE) | (np.linalg.det(rotation) <= 0))
            if len(bad):
                raise DataError(f"rotation[{bad[0]}] is not a rotation matrix (orthonormal with "
                                f"determinant +1 to {ROTATION_TOLERANCE:g})")
        if self.rows is None:
            rows = np.arange(1, N + 1)
        else:
            rows = np.array(self.rows)
            if rows.shape != (N,) or (N and not np.issubdtype(rows.dtype, np.integer)):
                raise DataError(f"rows must be ({N},) integers, got shape {rows.shape} of "
                                f"{rows.dtype}")
            rows = rows.astype(int)
        sets = None
        if self.sets is not None:
            sets = np.array(self.sets, dtype=object)
            if sets.shape != (N,):
                raise DataError(f"sets must be ({N},) or None, got shape {sets.shape}")
            bad = [s for s in sets if s not in SET_VALUES]
            if bad:
                raise DataError(f"sets holds {bad[0]!r}; each entry must be 'cal' or 'val'")
            sets = sets.astype("<U3")
        names = tuple(f"q{i}" for i in range(1, n + 1)) if self.joint_names is None \
            else tuple(str(s) for s in self.joint_names)
        if len(names) != n:
            raise DataError(f"joint_names has {len(names)} names for {n} joint columns of q")
        if len(set(names)) != n:
            raise DataError(f"joint_names are not unique: {', '.join(names)}")
        prismatic = np.zeros(n, bool) if self.prismatic is None else np.array(self.prismatic, bool)
        if prismatic.shape != (n,):
            raise DataError(f"prismatic must be ({n},) booleans, got shape {prismatic.shape}")
        for arr in (q, position, rotation, rows, sets, prismatic):
            if arr is not None:
                arr.setflags(write=False)
        for name, value in (("q", q), ("position", position), ("rotation", rotation),
                            ("rows", rows), ("sets", sets), ("joint_names", names),
                            ("source", None if self.source is None else Path(self.source)),
                            ("prismatic", prismatic)):
            object.__setattr__(self, name, value)

    @classmethod
    def from_arrays(cls, q, position, rotation=None, sets=None, joint_names: Sequence[str] | None = None,
                    prismatic=None) -> "Measurements":
        """Measurements from arrays in SI units (see the class attributes for shapes and frames).

        ``q`` (N, n) rad / m; ``position`` (N, 3) m in the meas frame; ``rotation`` (N, 3, 3) or
        None; ``sets`` (N,) of ``"cal"`` / ``"val"`` or None; ``joint_names`` default
        ``q1`` ... ``qn``; ``prismatic`` (n,) bool, default all False. Rows are numbered 1 ... N.
        """
        return cls(q=q, position=position, rotation=rotation, sets=sets, joint_names=joint_names,
                   prismatic=prismatic)

    # ------------------------------------------------------------------ queries
    @property
    def n_poses(self) -> int:
        return self.q.shape[0]

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    @property
    def has_orientation(self) -> bool:
        """True when each pose has a measured rotation, False for position-only data."""
        return self.rotation is not None

    def subset(self, index_or_mask) -> "Measurements":
        """The poses selected by a boolean mask (N,), integer indices (0-based) or a slice.

        Rows, sets and source are kept, so reports still name the original line numbers.
        """
        N = self.n_poses
        if isinstance(index_or_mask, slice):
            idx = np.arange(N)[index_or_mask]
        else:
            sel = np.asarray(index_or_mask)
            if sel.dtype == bool:
                if sel.shape != (N,):
                    raise DataError(f"boolean mask of shape {sel.shape} for {N} poses, expected ({N},)")
                idx = np.flatnonzero(sel)
            elif sel.size == 0:
                idx = np.zeros(0, int)
            elif np.issubdtype(sel.dtype, np.integer) and sel.ndim <= 1:
                idx = np.atleast_1d(sel)
                if ((idx < -N) | (idx >= N)).any():
                    raise DataError(f"pose index {idx[(idx < -N) | (idx >= N)][0]} out of range for "
                                    f"{N} poses")
            else:
                raise DataError(f"subset expects a boolean mask, integer indices or a slice, got "
                                f"an array of {sel.dtype} with shape {sel.shape}")
        return replace(self, q=self.q[idx], position=self.position[idx],
                       rotation=None if self.rotation is None else self.rotation[idx],
                       rows=self.rows[idx], sets=None if self.sets is None else self.sets[idx])

    def calibration(self) -> "Measurements":
        """The poses used for identification: the ``cal`` rows, or all poses when there is no set
        column."""
        if self.sets is None:
            return self
        return self.subset(self.sets == "cal")

    def validation(self) -> "Measurements | None":
        """The held-out ``val`` rows (possibly zero poses); None when there is no set column."""
        if self.sets is None:
            return None
        return self.subset(self.sets == "val")

    def __repr__(self) -> str:
        kind = "position and orientation" if self.has_orientation else "position only"
        split = ""
        if self.sets is not None:
            split = f", {int((self.sets == 'cal').sum())} cal / {int((self.sets == 'val').sum())} val"
        src = f", source={str(self.source)!r}" if self.source is not None else ""
        return f"Measurements({self.n_poses} poses, {self.n_joints} joints, {kind}{split}{src})"


def finite_array(value, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} must be a numeric array: {exc}") from None
    if not np.isfinite(arr).all():
        raise DataError(f"{name} holds NaN or infinite values")
    return arr


# ====================================================================== reading
@dataclass(frozen=True)
class _Column:
    """One recognised header column: its field index, name, quantity and scale to SI."""

    index: int
    name: str
    key: object          # joint index (int, 0-based), "x", "qw", "rz", ... or "set"
    scale: float = 1.0   # value * scale is in rad or m
    unit: str = ""       # the suffix, "" for qw ... qz and set
    style: str = ""      # "urdf" or "index" for joints


def _unit_text(units: Sequence[str]) -> str:
    return " or ".join(f"_{u}" for u in units)


class _Header:
    """The header of a measurement file, checked against a robot."""

    def __init__(self, path: Path, row: int, names: list[str], robot: RobotModel):
        self.path, self.row, self.robot = path, row, robot
        joints = robot.joints
        n = len(joints)
        self.joint_units = [tuple(LENGTH_UNITS) if j.is_prismatic else tuple(ANGLE_UNITS)
                            for j in joints]
        # base name -> (key, accepted units, style); reserved names take precedence
        bases: dict[str, tuple[object, tuple[str, ...], str]] = {}
        for k in POSITION_COLUMNS:
            bases[k] = (k, tuple(LENGTH_UNITS), "")
        for k in ZYX_COLUMNS:
            bases[k] = (k, tuple(ANGLE_UNITS), "")
        for i, j in enumerate(joints):
            bases.setdefault(j.name, (i, self.joint_units[i], "urdf"))
        for i in range(n):
            bases.setdefault(f"q{i + 1}", (i, self.joint_units[i], "index"))
        self.bases = bases
        valid = [f"{b}_{u}" for b, (_, units, _) in bases.items() for u in units]
        valid += list(QUATERNION_COLUMNS) + [SET_COLUMN]
        self.lower_valid = {v.lower(): v for v in valid}

        self.columns: dict[object, _Column] = {}
        styles: dict[str, str] = {}
        for index, raw in enumerate(names):
            name = raw.strip()
            col = self._classify(index, name)
            if col.key in self.columns:
                prev = self.columns[col.key]
                what = f"joint {joints[col.key].name}" if isinstance(col.key, int) else col.key
                if prev.name == name:
                    reason = f"duplicated column: {name!r} appears in columns {prev.index + 1} and {index + 1}"
                else:
                    reason = (f"duplicated column: {what} is given twice, by {prev.name!r} (column "
                              f"{prev.index + 1}) and {name!r} (column {index + 1}); give each once")
                self.fail(reason, name)
            if col.style:
                other = next((s for s in styles if s != col.style), None)
                if other is not None:
                    self.fail(f"mixes joint naming styles: {styles[other]!r} uses "
                              f"{self._style_text(other)} but {name!r} uses "
                              f"{self._style_text(col.style)}; use one style for all joints", name)
                styles.setdefault(col.style, name)
            self.columns[col.key] = col
        self._check_complete(names)

    # -------------------------------------------------------------- helpers
    def fail(self, reason: str, column: str | None = None):
        raise MeasurementFormatError(self.path, reason, row=self.row, column=column)

    def _style_text(self, style: str) -> str:
        n = self.robot.n_joints
        if style == "urdf":
            return "URDF joint names"
        return f"q1..q{n}"

    def _accepted(self) -> str:
        robot = self.robot
        names = ", ".join(robot.joint_names)
        prism = [j.name for j in robot.joints if j.is_prismatic]
        junits = "_rad or _deg"
        if prism:
            junits += f" (_m or _mm for the prismatic joint{'s' if len(prism) > 1 else ''} " \
                      f"{', '.join(prism)})"
        return (f"accepted columns: one per joint, named {names} or q1..q{robot.n_joints}, with "
                f"suffix {junits}; x, y, z with _m or _mm; optionally qw, qx, qy, qz or rz, ry, "
                f"rx with _rad or _deg; optionally set")

    def _case_hint(self, name: str) -> str:
        match = self.lower_valid.get(name.lower())
        return f" (column names are case-sensitive: did you mean {match!r}?)" if match else ""

    def _classify(self, index: int, name: str) -> _Column:
        if not name:
            self.fail(f"column {index + 1} of the header has an empty name (a stray comma?); "
                      f"{self._accepted()}")
        if name in QUATERNION_COLUMNS or name == SET_COLUMN:
            return _Column(index, name, name)
        if name in self.bases:
            _, units, _ = self.bases[name]
            self.fail(f"missing unit suffix: expected a unit suffix {_unit_text(units)} "
                      f"(e.g. {name}_{units[-1]})", name)
        base, sep, suffix = name.rpartition("_")
        if sep and base in self.bases:
            key, units, style = self.bases[base]
            if suffix not in units:
                self.fail(f"wrong unit suffix _{suffix}: {base} takes {_unit_text(units)}", name)
            scale = (LENGTH_UNITS if suffix in LENGTH_UNITS else ANGLE_UNITS)[suffix]
            return _Column(index, name, key, scale, suffix, style)
        if sep and base in QUATERNION_COLUMNS:
            self.fail(f"quaternion components take no unit suffix: expected {base!r}", name)
        if sep and base[:1] == "q" and base[1:].isdigit() and suffix in ANGLE_UNITS.keys() | LENGTH_UNITS.keys():
            self.fail(f"too many joint columns: the robot has {self.robot.n_joints} joints "
                      f"({', '.join(self.robot.joint_names)}), so joint columns run q1..q"
                      f"{self.robot.n_joints}", name)
        hint = self._case_hint(name)
        if not hint and (";" in name or "\t" in name):
            hint = " (fields must be separated by commas)"
        self.fail(f"unknown column{hint}; {self._accepted()}", name)

    def _check_complete(self, names: list[str]) -> None:
        robot = self.robot
        present = [c for c in self.columns.values() if isinstance(c.key, int)]
        style = present[0].style if present else "urdf"
        missing = [i for i in range(robot.n_joints) if i not in self.columns]
        if missing:
            def expected(i):
                base = robot.joints[i].name if style == "urdf" else f"q{i + 1}"
                return " or ".join(f"{base}_{u}" for u in self.joint_units[i])
            self.fail(f"missing joint column{'s' if len(missing) > 1 else ''}: the header has "
                      f"{len(present)} joint columns but the robot has {robot.n_joints} joints "
                      f"({', '.join(robot.joint_names)}); expected "
                      f"{'; '.join(expected(i) for i in missing)}")
        for k in POSITION_COLUMNS:
            if k not in self.columns:
                self.fail(f"missing column {k}: expected {k}_m or {k}_mm (the position x, y, z "
                          f"is required)")
        for group, label in ((QUATERNION_COLUMNS, "quaternion"), (ZYX_COLUMNS, "ZYX angle")):
            have = [k for k in group if k in self.columns]
            if have and len(have) < len(group):
                lack = [k for k in group if k not in self.columns]
                self.fail(f"incomplete {label} columns: found {', '.join(have)} but not "
                          f"{', '.join(lack)}; give all of {', '.join(group)} or none")
        if any(k in self.columns for k in QUATERNION_COLUMNS) and \
                any(k in self.columns for k in ZYX_COLUMNS):
            self.fail("both a quaternion (qw, qx, qy, qz) and ZYX angles (rz, ry, rx) are given; "
                      "give one orientation or none")

    @property
    def orientation(self) -> str:
        if "qw" in self.columns:
            return "quaternion"
        if "rz" in self.columns:
            return "zyx"
        return "none"


def _read_lines(path: Path) -> list[str]:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise MeasurementFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise MeasurementFormatError(path, "is a directory, expected a CSV file") from None
    except OSError as exc:
        raise MeasurementFormatError(path, f"cannot be read: {exc.strerror or exc}") from None
    if not data:
        raise MeasurementFormatError(path, "file is empty, expected a header row and data rows")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        row = data[:exc.start].count(b"\n") + 1
        raise MeasurementFormatError(path, f"not UTF-8 text (byte 0x{data[exc.start]:02x})",
                                     row=row) from None
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def split_fields(path: Path, row: int, line: str) -> list[str]:
    try:
        return next(csv.reader([line], strict=True))
    except csv.Error as exc:
        raise MeasurementFormatError(path, f"malformed CSV: {exc}", row=row) from None


def parse_number(path: Path, row: int, column: str, text: str) -> float:
    s = text.strip()
    if not s:
        raise MeasurementFormatError(path, "empty value, expected a number", row, column)
    try:
        if "_" in s:
            raise ValueError(s)
        value = float(s)
    except ValueError:
        raise MeasurementFormatError(path, f"{s!r} is not a number", row, column) from None
    if math.isnan(value):
        raise MeasurementFormatError(path, f"{s!r}: NaN value, expected a finite number", row, column)
    if math.isinf(value):
        raise MeasurementFormatError(path, f"{s!r}: infinite value, expected a finite number",
                                     row, column)
    return value


def _looks_numeric(fields: list[str]) -> bool:
    try:
        [float(f) for f in fields]
    except ValueError:
        return False
    return True


def read_records(path: Path) -> tuple[int, list[str], list[tuple[int, str]]]:
    """The header and data lines of a calib CSV file (comments and blank lines skipped).

    Returns (header line number, column names as written, [(line number, line), ...] of the data
    rows). Raises :class:`MeasurementFormatError` for an unreadable file, a file without a header
    row, or a first line that looks like data.
    """
    lines = _read_lines(path)
    records = [(k + 1, line) for k, line in enumerate(lines)
               if line.strip() and not line.lstrip().startswith("#")]
    if not records:
        raise MeasurementFormatError(path, "no header row: the file holds only comments and blank "
                                           "lines")
    header_row, header_line = records[0]
    names = split_fields(path, header_row, header_line)
    if _looks_numeric(names):
        raise MeasurementFormatError(path, "this line looks like data, expected the header row "
                                           "(column names such as joint1_deg, x_mm; a line starting "
                                           "with # is a comment)", row=header_row)
    return header_row, names, records[1:]


def read_measurements(csv_path: str | Path, robot: RobotModel) -> Measurements:
    """Read a measurement CSV file (format: see the module docstring) for ``robot``.

    Parameters
    ----------
    csv_path : the CSV file.
    robot : the robot whose joints the file's joint columns name; its joint limits are checked.

    Returns
    -------
    Measurements in SI units: ``q`` (N, n) rad / m in the robot's chain order, ``position``
    (N, 3) m and ``rotation`` (N, 3, 3) (or None) of the tool frame in the meas frame, ``rows``
    the line numbers, ``sets`` the ``set`` column in lower case (or None), ``joint_names`` the
    robot's joint names, ``source`` the path.

    Raises
    ------
    MeasurementFormatError : on any departure from the format, naming file, row and column.
    """
    path = Path(csv_path)
    header_row, names, data = read_records(path)
    header = _Header(path, header_row, names, robot)
    if not data:
        raise MeasurementFormatError(path, "header but no data rows", row=header_row)

    n, N, ncols = robot.n_joints, len(data), len(names)
    cols = header.columns
    q = np.empty((N, n))
    position = np.empty((N, 3))
    orient_keys = {"quaternion": QUATERNION_COLUMNS, "zyx": ZYX_COLUMNS, "none": ()}[header.orientation]
    orient = np.empty((N, len(orient_keys)))
    sets = [] if SET_COLUMN in cols else None
    rows = np.array([r for r, _ in data], dtype=int)
    for k, (row, line) in enumerate(data):
        fields = split_fields(path, row, line)
        if len(fields) != ncols:
            raise MeasurementFormatError(path, f"wrong number of fields: {len(fields)}, expected "
                                               f"{ncols} (one per header column)", row=row)
        for i in range(n):
            c = cols[i]
            q[k, i] = parse_number(path, row, c.name, fields[c.index]) * c.scale
        for j, key in enumerate(POSITION_COLUMNS):
            c = cols[key]
            position[k, j] = parse_number(path, row, c.name, fields[c.index]) * c.scale
        for j, key in enumerate(orient_keys):
            c = cols[key]
            orient[k, j] = parse_number(path, row, c.name, fields[c.index]) * c.scale
        if header.orientation == "quaternion":
            norm = float(np.linalg.norm(orient[k]))
            if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
                raise MeasurementFormatError(
                    path, f"quaternion (qw, qx, qy, qz) has norm {norm:.6g}, expected 1 (within "
                          f"{QUATERNION_NORM_TOLERANCE:g})", row=row, column="qw")
            orient[k] /= norm
        if sets is not None:
            c = cols[SET_COLUMN]
            value = fields[c.index].strip().lower()
            if value not in SET_VALUES:
                raise MeasurementFormatError(path, f"{fields[c.index].strip()!r} is not a set; "
                                                   f"expected cal or val", row=row, column=c.name)
            sets.append(value)

    _check_limits(path, robot, header, q, rows, data)

    if header.orientation == "quaternion":
        rotation = rotation_from_quaternion(orient)
    elif header.orientation == "zyx":
        rotation = rotation_from_zyx(orient)
    else:
        rotation = None
    return Measurements(q=q, position=position, rotation=rotation, rows=rows,
                        sets=None if sets is None else np.array(sets),
                        joint_names=robot.joint_names, source=path, prismatic=robot.prismatic)


def _check_limits(path: Path, robot: RobotModel, header: _Header, q: np.ndarray,
                  rows: np.ndarray, data) -> None:
    """Raise on the first row (then first column in header order) outside the joint limits."""
    lo, hi = robot.lower, robot.upper
    checked = np.array([j.kind != "continuous" for j in robot.joints])
    outside = ((q < lo - LIMIT_TOLERANCE) | (q > hi + LIMIT_TOLERANCE)) & checked
    if not outside.any():
        return
    k = int(np.flatnonzero(outside.any(axis=1))[0])
    order = sorted(np.flatnonzero(outside[k]), key=lambda i: header.columns[i].index)
    i = int(order[0])
    c, joint = header.columns[i], robot.joints[i]
    raw = split_fields(path, int(rows[k]), data[k][1])[c.index].strip()
    value = float(raw)
    count = int(outside[:, i].sum())
    others = f" ({count} rows of this column are outside)" if count > 1 else ""
    reason = (f"{joint.name} = {raw} {c.unit} is outside the joint limits "
              f"[{lo[i] / c.scale:.6g}, {hi[i] / c.scale:.6g}] {c.unit}{others}")
    if c.unit == "rad" and joint.kind == "revolute":
        as_deg = value * ANGLE_UNITS["deg"]
        fits = lo[i] - LIMIT_TOLERANCE <= as_deg <= hi[i] + LIMIT_TOLERANCE
        # limits of at most +-2 pi (to the 4 decimals URDFs usually give them with)
        small = max(abs(lo[i]), abs(hi[i])) <= 2 * math.pi + 1e-3
        if fits or (abs(value) > 2 * math.pi and small):
            reason += "; degrees given as radians? use the _deg suffix"
    elif c.unit == "m" and joint.is_prismatic:
        if lo[i] - LIMIT_TOLERANCE <= value * LENGTH_UNITS["mm"] <= hi[i] + LIMIT_TOLERANCE:
            reason += "; millimetres given as metres? use the _mm suffix"
    raise MeasurementFormatError(path, reason, row=int(rows[k]), column=c.name)


# ====================================================================== writing
def write_measurements(path: str | Path, measurements: Measurements, *, angle_unit: str = "deg",
                       length_unit: str = "mm", orientation: str = "quaternion",
                       comment: str | None = None) -> None:
    """Write measurements as CSV (format: see the module docstring), atomically.

    Parameters
    ----------
    path : the output file; refused if it is ``measurements.source`` (inputs are never
        overwritten).
    measurements : the data (SI units inside).
    angle_unit : ``"deg"`` or ``"rad"``: unit of revolute joint columns and ZYX angles.
    length_unit : ``"mm"`` or ``"m"``: unit of x, y, z and of prismatic joint columns.
    orientation : ``"quaternion"`` (qw, qx, qy, qz, scalar first, with qw >= 0), ``"zyx"``
        (rz, ry, rx) or ``"none"``; forced to ``"none"`` for position-only data.
    comment : text written first as ``#`` comment lines (one per line of the text).

    The header names the joints ``<joint name>_<unit>`` from ``measurements.joint_names``, then
    x, y, z, the orientation columns and ``set`` when the data has sets. Numbers are written with
    ``repr`` (shortest exact round-trip form), so reading the file back gives the data to
    rounding of the unit conversion (~1e-16 relative).
    """
    if angle_unit not in ANGLE_UNITS:
        raise CalibError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if length_unit not in LENGTH_UNITS:
        raise CalibError(f"length_unit must be 'mm' or 'm', got {length_unit!r}")
    if orientation not in ("quaternion", "zyx", "none"):
        raise CalibError(f"orientation must be 'quaternion', 'zyx' or 'none', got {orientation!r}")
    check_not_input(path, [measurements.source])
    m = measurements
    if m.rotation is None:
        orientation = "none"

    ascale, lscale = ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit]
    joint_scale = np.where(m.prismatic, lscale, ascale)
    header = [f"{name}_{length_unit if p else angle_unit}"
              for name, p in zip(m.joint_names, m.prismatic)]
    header += [f"{k}_{length_unit}" for k in POSITION_COLUMNS]
    columns = [m.q / joint_scale, m.position / lscale]
    if orientation == "quaternion":
        header += list(QUATERNION_COLUMNS)
        columns.append(quaternion_from_rotation(m.rotation))  # qw >= 0 for readability
    elif orientation == "zyx":
        header += [f"{k}_{angle_unit}" for k in ZYX_COLUMNS]
        columns.append(zyx_from_rotation(m.rotation) / ascale)
    values = np.hstack(columns) if m.n_poses else np.zeros((0, len(header)))

    buf = StringIO()
    if comment is not None:
        for line in str(comment).splitlines() or [""]:
            buf.write(f"# {line}".rstrip() + "\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header + ([SET_COLUMN] if m.sets is not None else []))
    for k in range(m.n_poses):
        row = [repr(float(v)) for v in values[k]]
        if m.sets is not None:
            row.append(str(m.sets[k]))
        writer.writerow(row)
    atomic_write_text(path, buf.getvalue())
