"""The three file kinds of calib as specs of one CSV layer: measurements, poses, targets.

Every file is read by :func:`calib.io.csv_layer.read_table` (delimiters, comments, units in
column names, ignored and near-miss columns, orientations, joint limits: see that module); this
module says which columns each kind takes and builds the objects the algorithms take.

Measurement file (:func:`read_measurements`): one row per robot pose.

- **Joints** (required): one column per joint, each exactly once, named after the URDF joint
  (``joint1_deg``), or ``q1`` ... ``qn``, ``J1`` ... ``Jn``, ``A1`` ... ``An`` in chain order
  (case-insensitive; one naming style per file), with the unit suffix ``_rad`` or ``_deg``
  (revolute and continuous joints), ``_m`` or ``_mm`` (prismatic joints).
- **Position** (required): ``x``, ``y``, ``z`` with ``_m`` or ``_mm``: the origin of the tool frame
  in the meas frame.
- **Orientation** (optional) of the tool frame in the meas frame, one of: a unit quaternion
  ``qw, qx, qy, qz`` (no suffix, any column order); ZYX angles ``rz, ry, rx`` (R = Rz Ry Rx, Eq.
  (3) of the paper); Euler angles ``e1, e2, e3`` of the sequence given by ``euler`` (scipy
  notation); a rotation vector ``rvx, rvy, rvz`` (axis times angle); a rotation matrix
  ``r11`` ... ``r33`` (``rij`` is row i, column j). Angles with ``_rad`` or ``_deg``.
- ``set`` (optional): ``cal`` or ``val``. ``target`` (optional): any id of the reflector or
  target measured on the tool.
- Or two files joined by a key column (:attr:`ReadOptions.key`): the joints (with ``set`` and
  ``target`` if wanted) in one, the position and orientation in the other (``tracker=``), rows
  matched by key in any order.

Example (the bundled BRTIRUS0707A; ``set`` may be left out, and so may ``qw`` ... ``qz``)::

    # BRTIRUS0707A, laser tracker T-Mac on the tool flange
    joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz,set
    0,0,0,0,0,0,441.0,0.0,-36.5,0.0,1.0,0.0,0.0,cal
    10,-20,30,0,45,90,256.267,45.187,131.509,0.35372,0.67949,-0.57016,-0.29681,val

The same poses with ``q1`` ... ``q6`` in radians and ZYX angles::

    q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m,rz_deg,ry_deg,rx_deg
    0,0,0,0,0,0,0.441,0.0,-0.0365,0,0,180
    0.174533,-0.349066,0.523599,0,0.785398,1.570796,0.256267,0.045187,0.131509,-80,0,125

Poses file (:func:`read_poses`, :func:`write_poses`): the joint columns of a measurement file; the
"poses to measure" that ``select-poses`` writes. Once measured, the columns ``x_mm, y_mm, z_mm``
(and ``qw, qx, qy, qz``) added to each row make it a measurement file.

Targets file (:func:`read_targets`): joint columns alone (*joint targets*: the nominal tool pose
there), or a position ``x, y, z`` with an optional orientation as in measurement files (*pose* or
*position targets*), with joint columns, if also given, as the solver's start.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.errors import MeasurementFormatError, ParameterError
from calib.io.fileio import atomic_write_text, check_not_input
from calib.model.measurements import Measurements
from calib.io.csv_layer import (ANGLE_UNITS, LENGTH_UNITS, POSITION_COLUMNS, ORIENTATIONS, ReadOptions, Spec,
                                Table, csv_text, joint_columns, read_table)

__all__ = ["MEASUREMENT", "POSES", "TARGETS", "JOINT_SIDE", "TRACKER_SIDE", "read_measurements",
           "write_measurements", "read_poses", "write_poses", "CompensationTargets", "read_targets",
           "write_compensation"]

MEASUREMENT = Spec("measurement", joints="required", position="required", orientation=True,
                   labels=("set", "target"))
POSES = Spec("poses", joints="required")
TARGETS = Spec("targets", joints="optional", position="optional", orientation=True)
#: The two halves of a measurement joined by a key: joints, and the tracker's poses.
JOINT_SIDE = Spec("joint", joints="required", labels=("set", "target"), keyed=True)
TRACKER_SIDE = Spec("tracker", joints="none", position="required", orientation=True,
                    labels=("set", "target"), keyed=True)


def _rename_notes(options: ReadOptions, tables: list[Table]) -> tuple[str, ...]:
    """A note for each rename whose source names no column of the files read."""
    used = {old for t in tables for old in t.renamed}
    where = " or ".join(str(t.path) for t in tables)
    return tuple(f"--rename {old}={new}: no column {old!r} in {where}"
                 for old, new in options.rename if old.lower() not in used)


# ====================================================================== measurements
def read_measurements(csv_path: str | Path, robot, *, tracker: str | Path | None = None,
                      options: ReadOptions | None = None) -> Measurements:
    """Read a measurement CSV file (format: module docstring and README) for ``robot``.

    Parameters
    ----------
    csv_path : the measurement file; with ``tracker``, the file of joint values.
    robot : the robot whose joints the file names; its joint limits are checked.
    tracker : a second file with the measured poses (x, y, z and an orientation), joined to
        ``csv_path`` row by row through the key column ``options.key``; None for one file.
    options : :class:`ReadOptions` (rename, Euler sequence, limit tolerance, key).

    Returns
    -------
    Measurements in SI units: ``q`` (N, n) rad / m in chain order, ``position`` (N, 3) m and
    ``rotation`` (N, 3, 3) (or None) of the tool frame in the meas frame, ``rows`` the line
    numbers (of ``csv_path``), ``sets``, ``target``, ``source`` = ``csv_path``, and the
    ``ignored_columns`` and ``notes`` of the reading (the caller decides whether to print them).

    Raises
    ------
    MeasurementFormatError : on any departure from the format, naming file, row and column.
    """
    from calib.checks import check_instance, check_path
    from calib.model.robot import check_robot

    check_path(csv_path, "csv_path")
    check_robot(robot)
    if tracker is not None:
        check_path(tracker, "tracker")
    options = check_instance(options, "options", ReadOptions, "calib.ReadOptions", allow_none=True) \
        or ReadOptions()
    if tracker is None:
        if options.key is not None:
            raise ParameterError("a key column joins two files: give the tracker file too "
                                 "(--tracker POSES.csv)")
        t = read_table(csv_path, MEASUREMENT, robot, options)
        q, pose, rows, labels, tables = t.q, t, t.rows, t.labels, [t]
        order = np.arange(len(rows))
    else:
        if options.key is None:
            raise ParameterError("a tracker file is joined to the joint file by a key column: "
                                 "give it (--key COLUMN)")
        j = read_table(csv_path, JOINT_SIDE, robot, options)
        pose = read_table(tracker, TRACKER_SIDE, robot, options)
        tables = [j, pose]
        order = _join(j, pose, options.key)
        q, rows = j.q, j.rows
        labels = _joined_labels(j, pose, order)
    position = pose.position[order]
    rotation = None if pose.rotation is None else pose.rotation[order]
    return Measurements(q=q, position=position, rotation=rotation, rows=rows,
                        sets=labels.get("set"), target=labels.get("target"),
                        joint_names=robot.joint_names, source=Path(csv_path),
                        prismatic=robot.prismatic,
                        ignored_columns=tuple(c for t in tables for c in t.ignored_columns),
                        notes=tuple(n for t in tables for n in t.notes) + _rename_notes(options, tables),
                        orientation=f"euler:{pose.euler}" if pose.orientation == "euler" else pose.orientation)


def _join(j: Table, t: Table, key: str) -> np.ndarray:
    """Index into ``t`` of each row of ``j`` with the same key (errors name file, row, key)."""
    first = {}
    for table in (j, t):
        seen: dict[str, int] = {}
        for k, value in enumerate(table.labels[key]):
            if value in seen:
                raise MeasurementFormatError(table.path, f"duplicated key {value!r} (also in row "
                                                         f"{table.rows[seen[value]]})",
                                             row=int(table.rows[k]), column=table.names[key])
            seen[value] = k
        first[table.path] = seen
    in_t, in_j = first[t.path], first[j.path]
    for a, b, index in ((j, t, in_t), (t, j, in_j)):
        for k, value in enumerate(a.labels[key]):
            if value not in index:
                raise MeasurementFormatError(a.path, f"key {value!r} is not in {b.path}",
                                             row=int(a.rows[k]), column=a.names[key])
    return np.array([in_t[v] for v in j.labels[key]], dtype=int)


def _joined_labels(j: Table, t: Table, order: np.ndarray) -> dict:
    """set and target from either file; a label in both must agree row by row."""
    out = {}
    for label in ("set", "target"):
        a = j.labels.get(label)
        b = None if label not in t.labels else tuple(t.labels[label][i] for i in order)
        if a is not None and b is not None:
            for k, (x, y) in enumerate(zip(a, b)):
                if x != y:
                    raise MeasurementFormatError(
                        t.path, f"{label} {y!r} differs from {x!r} in row {j.rows[k]} of {j.path} "
                                f"(same key); give {label} in one file or the same in both",
                        row=int(t.rows[order[k]]), column=t.names[label])
        out[label] = a if a is not None else b
    return out


def write_measurements(path: str | Path, measurements: Measurements, *, angle_unit: str = "deg",
                       length_unit: str = "mm", orientation: str = "quaternion",
                       comment: str | None = None) -> None:
    """Write measurements as CSV (format: module docstring), atomically.

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
    x, y, z, the orientation columns, ``set`` and ``target`` when the data has them. Numbers are
    written with ``repr`` (shortest exact round-trip form), so reading the file back gives the data
    to rounding of the unit conversion (~1e-16 relative).
    """
    import warnings

    from scipy.spatial.transform import Rotation

    from calib.checks import check_path
    from calib.model.measurements import check_measurements

    check_path(path, "path")
    check_measurements(measurements)
    if not isinstance(angle_unit, str) or angle_unit not in ANGLE_UNITS:
        raise ParameterError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if not isinstance(length_unit, str) or length_unit not in LENGTH_UNITS:
        raise ParameterError(f"length_unit must be 'mm' or 'm', got {length_unit!r}")
    if not isinstance(orientation, str) or orientation not in ("quaternion", "zyx", "none"):
        raise ParameterError(f"orientation must be 'quaternion', 'zyx' or 'none', got {orientation!r}")
    check_not_input(path, [measurements.source])
    m = measurements
    if m.rotation is None:
        orientation = "none"
    header, qv = joint_columns(m.joint_names, m.prismatic, m.q, angle_unit, length_unit)
    lscale = LENGTH_UNITS[length_unit]
    header += [f"{k}_{length_unit}" for k in POSITION_COLUMNS]
    columns = [qv.reshape(m.n_poses, -1), m.position / lscale]
    if orientation == "quaternion":
        header += list(ORIENTATIONS["quaternion"][0])
        wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
        wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)  # same rotation, qw >= 0 for readability
        columns.append(wxyz)
    elif orientation == "zyx":
        header += [f"{k}_{angle_unit}" for k in ORIENTATIONS["zyx"][0]]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # gimbal lock: any valid split is fine
            columns.append(Rotation.from_matrix(m.rotation).as_euler("ZYX") / ANGLE_UNITS[angle_unit])
    values = np.hstack(columns) if m.n_poses else np.zeros((0, len(header)))
    texts = [m.sets, m.target]
    header += [name for name, t in zip(("set", "target"), texts) if t is not None]
    rows = [[repr(float(v)) for v in values[k]] + [str(t[k]) for t in texts if t is not None]
            for k in range(m.n_poses)]
    atomic_write_text(path, csv_text(header, rows, comment))


# ====================================================================== poses
def write_poses(path: str | Path, robot, q: np.ndarray, *, angle_unit: str = "deg",
                length_unit: str = "mm", comment: str | None = None) -> None:
    """Write configurations as a "poses to measure" CSV (format: module docstring), atomically.

    Parameters
    ----------
    path : output file.
    robot : the robot whose joints the columns name (``<joint name>_<unit>``, chain order).
    q : (N, n_joints) float, radians (metres for prismatic joints).
    angle_unit : "deg" or "rad" (revolute and continuous joints).
    length_unit : "mm" or "m" (prismatic joints).
    comment : text written first as ``#`` comment lines.
    """
    from calib.checks import check_configurations, check_path
    from calib.model.robot import check_robot

    check_path(path, "path")
    check_robot(robot)
    q = check_configurations(q, robot.n_joints, "q")
    if not isinstance(angle_unit, str) or angle_unit not in ANGLE_UNITS:
        raise ParameterError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if not isinstance(length_unit, str) or length_unit not in LENGTH_UNITS:
        raise ParameterError(f"length_unit must be 'mm' or 'm', got {length_unit!r}")
    header, values = joint_columns(robot.joint_names, robot.prismatic, q, angle_unit, length_unit)
    atomic_write_text(path, csv_text(header, [[repr(float(v)) for v in row] for row in values],
                                     comment))


def read_poses(path: str | Path, robot, *, options: ReadOptions | None = None) -> np.ndarray:
    """Read a "poses to measure" CSV (format: module docstring) for ``robot``.

    Returns (N, n_joints) float, radians (metres for prismatic joints), in chain order. Columns
    other than the joints are ignored. Raises :class:`calib.MeasurementFormatError` naming file,
    row and column on any departure from the format, including values beyond the joint limits.
    """
    from calib.checks import check_instance

    options = check_instance(options, "options", ReadOptions, "calib.ReadOptions", allow_none=True) \
        or ReadOptions()
    return read_table(path, POSES, robot, options).q


# ====================================================================== compensation targets
@dataclass(frozen=True, eq=False)
class CompensationTargets:
    """Targets read by :func:`read_targets` (SI units, meas frame).

    q : (N, n) rad / m, the nominal joints (or the start for pose targets), or None.
    position : (N, 3) metres, target tool positions, or None for joint targets.
    rotation : (N, 3, 3) target tool orientations, or None (joint or position targets).
    rows : (N,) line numbers in the file; source : the file.
    ignored_columns, notes : as in :class:`calib.Measurements`.
    """

    q: np.ndarray | None
    position: np.ndarray | None
    rotation: np.ndarray | None
    rows: np.ndarray
    source: Path | None = None
    ignored_columns: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        """"joints", "pose" or "position"."""
        if self.position is None:
            return "joints"
        return "pose" if self.rotation is not None else "position"

    @property
    def n_targets(self) -> int:
        return len(self.rows)


def read_targets(path: str | Path, nominal, *, options: ReadOptions | None = None) -> CompensationTargets:
    """Read a compensation targets CSV for the nominal model.

    Columns (units in the names, as in measurement files):

    - joint columns ``<joint>_deg`` / ``_rad`` (``_mm`` / ``_m`` for prismatic joints), or
      ``q1_deg``, ``J1_deg``, ``A1_deg`` ...: the joint values the controller would use with the
      nominal model. Alone, they make *joint targets*: the target is the nominal tool pose there.
    - ``x, y, z`` with ``_mm`` or ``_m``: a target tool position in the meas frame (the nominal
      model's base frame), optionally with an orientation as in measurement files. They make
      *pose targets* (*position targets* without orientation); joint columns, if also given, are
      the solver's start (they choose the solution branch).

    Example (joint targets of the bundled robot)::

        joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg
        10,-20,30,0,45,90

    Example (pose targets with the nominal joints as start)::

        x_mm,y_mm,z_mm,qw,qx,qy,qz,joint1_deg,joint2_deg,joint3_deg,joint4_deg,joint5_deg,joint6_deg
        256.267,45.187,131.509,0.35372,0.67949,-0.57016,-0.29681,10,-20,30,0,45,90

    Raises :class:`calib.MeasurementFormatError` naming the file, row and column.
    """
    from calib.checks import check_instance

    options = check_instance(options, "options", ReadOptions, "calib.ReadOptions", allow_none=True) \
        or ReadOptions()
    t = read_table(path, TARGETS, nominal, options)
    return CompensationTargets(q=t.q, position=t.position, rotation=t.rotation, rows=t.rows,
                               source=t.path, ignored_columns=t.ignored_columns,
                               notes=t.notes + _rename_notes(options, [t]))


def write_compensation(path: str | Path, result, *, angle_unit: str = "deg",
                       length_unit: str = "mm", comment: str | None = None) -> None:
    """Write the corrected joint values of a :class:`calib.CompensationResult` with a status per
    target as CSV, atomically.

    Columns: the joint columns ``<joint>_deg`` (``_mm`` for prismatic joints; units as chosen),
    the corrected joint values to send to the controller, in the order of the targets; then
    ``status`` (ok, limit, singular, not_converged), ``residual_mm`` (distance of the calibrated
    tool position from the target), ``residual_rad`` (angle of the orientation residual; pose
    targets only) and ``detail`` (why a target is not ok: the joint beyond its limit and by how
    much, the singular value, the residual). Joint values are written as computed, never clipped:
    a row whose status is not ``ok`` must not be sent to the robot as it is.

    The file reads back as a poses file (:func:`read_poses`): the status columns are ignored.
    """
    from calib.checks import check_path

    check_path(path, "path")
    if not all(hasattr(result, a) for a in ("joint_names", "prismatic", "q", "status", "position_error",
                                             "rotation_error", "n_targets", "describe")):
        raise ParameterError(f"result must be a CompensationResult (calib.compensate, calib.compensate_poses), "
                             f"got {type(result).__name__}")
    header, values = joint_columns(result.joint_names, result.prismatic, result.q, angle_unit,
                                   length_unit)
    header += ["status", "residual_mm"] + (["residual_rad"] if result.rotation_error is not None else [])
    header.append("detail")
    rows = []
    for k in range(result.n_targets):
        row = [repr(float(v)) for v in values[k]]
        row += [str(result.status[k]), f"{result.position_error[k] * 1e3:.6g}"]
        if result.rotation_error is not None:
            row.append(f"{result.rotation_error[k]:.6g}")
        row.append("" if result.status[k] == "ok" else result.describe(k))
        rows.append(row)
    atomic_write_text(path, csv_text(header, rows, comment))
