"""Measurements: joint values with the measured tool pose, one robot pose per row (SI units).

:class:`Measurements` is the data the calibration takes. Files are read and written by
:mod:`calib.io.csv.specs` (:func:`calib.read_measurements`, :func:`calib.write_measurements`; the
format is described there and in docs/formats.md), which this module re-exports.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping, Sequence

import numpy as np

from calib.checks import check_instance, check_names, check_path
from calib.errors import DataError

__all__ = ["Measurements", "TEXT_COLUMNS"]  # read_measurements, write_measurements: see __getattr__ below

#: The per-row columns of :attr:`Measurements.columns` that hold text (the others are numbers):
#: ``pose_id`` and ``name`` (the row's name: a point name, a waypoint).
TEXT_COLUMNS = ("pose_id", "name")

SET_VALUES = ("cal", "val")
#: Tolerance of the orthonormality check of rotation matrices given to :class:`Measurements`.
ROTATION_TOLERANCE = 1e-6


# ====================================================================== data
@dataclass(frozen=True, eq=False, repr=False)     # (its own __repr__ below: the generated one was built and discarded)
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
    target : (N,) tuple of str, the id of the target (reflector) measured in each row, or None
        when the data has no target column.
    ignored_columns : header names of the source file's columns that calib ignored.
    notes : one-line remarks of the reading (ignored columns, readings kept just past a joint
        limit), for the caller to show; the library does not print them.
    columns : per-row columns the report uses, or None: ``time_s`` (seconds), ``temperature_c``
        (degrees Celsius), ``unix_time_s`` (seconds since 1970-01-01 UTC: the row's date and time,
        from timestamps that are dates), each (N,) float with NaN for an empty cell, and
        ``pose_id`` (N,) str (rows of one id are visits of one commanded pose) and ``name`` (N,) str
        (the row's name, "" where a file gives none), the text columns of :data:`TEXT_COLUMNS`.
    orientation : how the file gave the orientation (``"quaternion"``, ``"zyx"``, ``"rotvec"``,
        ``"matrix"``, or ``"euler:<sequence>"`` with the sequence it was read with), or None
        (data not read from a file, position only): what a check of a misreading tries.

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
    target: tuple[str, ...] | None = None
    ignored_columns: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    orientation: str | None = None
    columns: Mapping[str, np.ndarray] | None = None

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
            else check_names(self.joint_names, "joint_names")
        if len(names) != n:
            raise DataError(f"joint_names has {len(names)} names for {n} joint columns of q")
        if len(set(names)) != n:
            raise DataError(f"joint_names are not unique: {', '.join(names)}")
        prismatic = np.zeros(n, bool) if self.prismatic is None else np.array(self.prismatic, bool)
        if prismatic.shape != (n,):
            raise DataError(f"prismatic must be ({n},) booleans, got shape {prismatic.shape}")
        target = None
        if self.target is not None:
            target = tuple(str(t) for t in np.asarray(self.target, dtype=object).ravel())
            if np.shape(self.target) != (N,):
                raise DataError(f"target must be ({N},) ids or None, got shape "
                                f"{np.shape(self.target)}")
        source = None if self.source is None else check_path(self.source, "source")
        columns = None
        if self.columns is not None:
            if not isinstance(self.columns, Mapping) or not all(isinstance(k, str) for k in self.columns):
                raise DataError(f"columns must map names to ({N},) arrays, got {self.columns!r:.60}")
            columns = {}
            for name, values in self.columns.items():
                v = np.array(values, dtype=object if name in TEXT_COLUMNS else float)
                if v.shape != (N,):
                    raise DataError(f"columns[{name!r}] must be ({N},), got shape {v.shape}")
                v.setflags(write=False)
                columns[name] = v
            columns = MappingProxyType(columns)
        for arr in (q, position, rotation, rows, sets, prismatic):
            if arr is not None:
                arr.setflags(write=False)
        for name, value in (("q", q), ("position", position), ("rotation", rotation),
                            ("rows", rows), ("sets", sets), ("joint_names", names),
                            ("source", source),
                            ("prismatic", prismatic), ("target", target), ("columns", columns),
                            ("ignored_columns", check_names(self.ignored_columns, "ignored_columns")),
                            ("notes", check_names(self.notes, "notes")),
                            ("orientation", None if self.orientation is None or rotation is None
                             else str(self.orientation))):
            object.__setattr__(self, name, value)

    @classmethod
    def from_arrays(cls, q, position, rotation=None, sets=None, joint_names: Sequence[str] | None = None,
                    prismatic=None, target=None) -> "Measurements":
        """Measurements from arrays in SI units (see the class attributes for shapes and frames).

        ``q`` (N, n) rad / m; ``position`` (N, 3) m in the meas frame; ``rotation`` (N, 3, 3) or
        None; ``sets`` (N,) of ``"cal"`` / ``"val"`` or None; ``joint_names`` default
        ``q1`` ... ``qn``; ``prismatic`` (n,) bool, default all False; ``target`` (N,) ids or
        None. Rows are numbered 1 ... N.
        """
        return cls(q=q, position=position, rotation=rotation, sets=sets, joint_names=joint_names,
                   prismatic=prismatic, target=target)

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

    @property
    def target_ids(self) -> tuple[str, ...]:
        """The distinct target ids in order of first appearance; () without a target column."""
        return tuple(dict.fromkeys(self.target)) if self.target is not None else ()

    def subset(self, index_or_mask) -> "Measurements":
        """The poses selected by a boolean mask (N,), integer indices (0-based) or a slice.

        Rows, sets, targets and source are kept, so reports still name the original line numbers.
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
        # rows of checked measurements need no check again (the constructor's took 0.2 ms of each
        # calibration's cal / val split): the arrays are indexed copies, read-only as it makes them
        out = object.__new__(type(self))
        out.__dict__.update(self.__dict__)
        arrays = {"q": self.q[idx], "position": self.position[idx],
                  "rotation": None if self.rotation is None else self.rotation[idx], "rows": self.rows[idx],
                  "sets": None if self.sets is None else self.sets[idx]}
        columns = None if self.columns is None else {k: v[idx] for k, v in self.columns.items()}
        for arr in list(arrays.values()) + list((columns or {}).values()):
            if arr is not None:
                arr.setflags(write=False)
        out.__dict__.update(arrays, target=None if self.target is None else tuple(self.target[i] for i in idx),
                            columns=None if columns is None else MappingProxyType(columns))
        return out

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
        if self.target is not None:
            split += f", {len(self.target_ids)} target{'s' if len(self.target_ids) != 1 else ''}"
        src = f", source={str(self.source)!r}" if self.source is not None else ""
        return f"Measurements({self.n_poses} poses, {self.n_joints} joints, {kind}{split}{src})"


def is_touch_data(value) -> bool:
    """Whether ``value`` is touch data (:class:`calib.model.touch.TouchData`), without loading
    that module when nothing has (a calibration of measurements does not pay for its classes)."""
    import sys

    touch = sys.modules.get("calib.model.touch")
    return touch is not None and isinstance(value, touch.TouchData)


def finite_array(value, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} must be a numeric array: {exc}") from None
    if not np.isfinite(arr).all():
        raise DataError(f"{name} holds NaN or infinite values")
    return arr


def check_measurements(value, name: str = "measurements", *, allow_none: bool = False) -> Measurements | None:
    """``value`` if it is a :class:`Measurements` (or None when ``allow_none``), else
    :class:`calib.ParameterError` naming ``name``."""
    return check_instance(value, name, Measurements, "from calib.read_measurements",
                          allow_none=allow_none)
