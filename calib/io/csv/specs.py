"""The three file kinds of calib as specs of one CSV layer: measurements, poses, targets.

Every file is read by :func:`calib.io.csv.layer.read_table` (delimiters, comments, units in
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
- Or two files joined (:mod:`calib.io.csv.join`): the joints (with ``set`` and ``target`` if wanted)
  in one, the position and orientation in the other (``tracker=``), rows matched by a key column
  (:attr:`ReadOptions.key`) in any order, one joint row to one measured row or to several, each
  with its target id (``target_column``, ``target_from``); or each measured row to the joint row
  of the nearest timestamp (``join="nearest-time"``, ``time``, ``max_gap``).

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

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib.errors import MeasurementFormatError, ParameterError
from calib.io.fileio import atomic_write_text, check_not_input
from calib.model.measurements import TEXT_COLUMNS, Measurements
from calib.io.csv.layer import csv_text, joint_columns, read_table
from calib.io.csv.header import ANGLE_UNITS, LENGTH_UNITS, POSITION_COLUMNS, ORIENTATIONS
from calib.io.csv.options import ReadOptions, Spec, Table

if TYPE_CHECKING:      # (read_targets builds it: calib.io.csv.targets)
    from calib.io.csv.targets import CompensationTargets

__all__ = ["MEASUREMENT", "POSES", "TARGETS", "JOINT_SIDE", "TRACKER_SIDE", "read_measurements",
           "write_measurements", "read_poses", "write_poses", "read_targets",
           "write_compensation"]

MEASUREMENT = Spec("measurement", joints="required", position="required", orientation=True,
                   labels=("set", "target", "pose_id", "name"), sparse=("name",), extras=("time", "temperature"))
POSES = Spec("poses", joints="required")
#: The text columns of a targets file: the target's name, and a controller's configuration (KUKA
#: Status and Turn, ABB confdata, a FANUC configuration string; read with --convention).
TARGET_LABELS = ("name", "s", "t", "cf1", "cf4", "cf6", "cfx", "config")
TARGETS = Spec("targets", joints="optional", position="optional", orientation=True, labels=TARGET_LABELS)
#: The two halves of a measurement joined by a key: joints, and the tracker's poses.
JOINT_SIDE = Spec("joint", joints="required", labels=("set", "target", "pose_id", "name"), sparse=("name",),
                  keyed=True, extras=("time", "temperature"))
TRACKER_SIDE = Spec("tracker", joints="none", position="required", orientation=True,
                    labels=("set", "target", "pose_id", "name"), sparse=("name",), keyed=True,
                    extras=("time", "temperature"))


#: The unit of each extra column in :attr:`Measurements.columns` names (SI, or Celsius).
_EXTRA_SI = {"time": "s", "temperature": "c"}


def _rename_notes(options: ReadOptions, tables: list[Table]) -> tuple[str, ...]:
    """A note for each rename whose source names no column of the files read."""
    used = {old for t in tables for old in t.renamed}
    where = " or ".join(str(t.path) for t in tables)
    return tuple(f"--rename {old}={new}: no column {old!r} in {where}"
                 for old, new in options.rename if old.lower() not in used)


# ====================================================================== measurements
def read_measurements(csv_path: str | Path, robot, *, tracker: str | Path | None = None,
                      options: ReadOptions | None = None) -> Measurements:
    """Read a measurement CSV file (format: module docstring and docs/formats.md) for ``robot``.

    Parameters
    ----------
    csv_path : the measurement file; with ``tracker``, the file of joint values.
    robot : the robot whose joints the file names; its joint limits are checked.
    tracker : a second file with the measured poses (x, y, z and an orientation), joined to
        ``csv_path`` through the key column ``options.key`` (one joint row to one or several
        measured rows, each with its target id: ``options.target_column``,
        ``options.target_from``) or by the nearest time (``options.join == "nearest-time"``,
        ``options.time``, ``options.max_gap``): see :mod:`calib.io.csv.join`; None for one file.
    options : :class:`ReadOptions` (rename, Euler sequence, limit tolerance, the join).

    Returns
    -------
    Measurements in SI units: ``q`` (N, n) rad / m in chain order, ``position`` (N, 3) m and
    ``rotation`` (N, 3, 3) (or None) of the tool frame in the meas frame, ``rows`` the line
    numbers of ``source``: ``csv_path`` (one file, or a join of one measured row per joint row),
    else ``tracker`` (one result row per measured row); ``sets``, ``target``, and the
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
        given = [flag for flag, on in (("--key", options.key is not None),
                                       ("--join nearest-time", options.join != "key"),
                                       ("--target-column", options.target_column is not None),
                                       ("--target-from", options.target_from is not None)) if on]
        if given:
            if given == ["--key"]:
                raise ParameterError("a key column joins two files: give the tracker file too "
                                     "(--tracker POSES.csv)")
            raise ParameterError(f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} for a "
                                 f"tracker file joined to the joint file: give it too (--tracker "
                                 f"POSES.csv)")
        t = read_table(csv_path, MEASUREMENT, robot, options)
        q, pose, rows, labels, tables = t.q, t, t.rows, t.labels, [t]
        source, joined_notes = Path(csv_path), ()
        order = np.arange(len(rows))
        extras = dict(t.extras)
    else:
        if options.join == "key" and options.key is None:
            raise ParameterError("a tracker file is joined to the joint file by a key column: "
                                 "give it (--key COLUMN), or join by the nearest time (--join "
                                 "nearest-time)")
        from calib.io.csv.join import join_tables, sides       # (a tracker file only)

        joint_spec, tracker_spec = sides(JOINT_SIDE, TRACKER_SIDE, options)
        # (the instrument's preset, --columns and --length-unit describe the tracker file)
        j = read_table(csv_path, joint_spec, robot, replace(options, instrument=None, columns=None,
                                                            length_unit=None))
        pose = read_table(tracker, tracker_spec, robot, options)
        tables = [j, pose]
        joined = join_tables(j, pose, options)
        order, labels, joined_notes = joined.tracker, joined.labels, joined.notes
        q = j.q[joined.joint]
        # one result row per measured row: the joint file's row numbers while they stay unique
        # (outliers are told by row), else the tracker file's
        rows, source = (j.rows[joined.joint], Path(csv_path)) if joined.one_to_one \
            else (pose.rows[joined.tracker], Path(tracker))
        extras = {**{k: v[order] for k, v in pose.extras.items()},
                  **{k: v[joined.joint] for k, v in j.extras.items()}}
    position = pose.position[order]
    rotation = None if pose.rotation is None else pose.rotation[order]
    columns = {f"{k}_{_EXTRA_SI[k]}": v for k, v in extras.items()}
    if tracker is not None and joined.unix_time_s is not None:     # when the robot was measured
        columns["unix_time_s"] = joined.unix_time_s
    for label in TEXT_COLUMNS:
        if labels.get(label) is not None:
            columns[label] = np.asarray(labels[label], dtype=object)
    return Measurements(q=q, position=position, rotation=rotation, rows=rows,
                        sets=labels.get("set"), target=labels.get("target"), columns=columns or None,
                        joint_names=robot.joint_names, source=source,
                        prismatic=robot.prismatic,
                        ignored_columns=tuple(c for t in tables for c in t.ignored_columns),
                        notes=tuple(n for t in tables for n in t.notes) + joined_notes
                        + _rename_notes(options, tables),
                        orientation=f"euler:{pose.euler}" if pose.orientation == "euler" else pose.orientation)


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
    x, y, z, the orientation columns, ``time_s`` and ``temperature_c`` (empty cells for NaN),
    ``set``, ``target`` and ``pose_id`` when the data has them. Numbers are
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
    extra = dict(m.columns or {})
    for name in ("time_s", "temperature_c"):
        if name in extra:
            header.append(name)
            columns.append(np.asarray(extra[name], float).reshape(-1, 1))
    values = np.hstack(columns) if m.n_poses else np.zeros((0, len(header)))
    texts = [m.sets, m.target, extra.get("pose_id"), extra.get("name")]
    header += [name for name, t in zip(("set", "target", "pose_id", "name"), texts) if t is not None]
    rows = [[("" if v != v else repr(float(v))) for v in values[k]] + [str(t[k]) for t in texts if t is not None]
            for k in range(m.n_poses)]
    n_text = sum(t is not None for t in texts)
    atomic_write_text(path, csv_text(header, rows, comment, range(len(header) - n_text, len(header))))


# ====================================================================== poses
def write_poses(path: str | Path, robot, q: np.ndarray, *, angle_unit: str = "deg",
                length_unit: str = "mm", comment: str | None = None, names=None,
                name_column: str = "point", extra=None) -> None:
    """Write configurations as a "poses to measure" CSV (format: module docstring), atomically.

    Parameters
    ----------
    path : output file.
    robot : the robot whose joints the columns name (``<joint name>_<unit>``, chain order).
    q : (N, n_joints) float, radians (metres for prismatic joints).
    angle_unit : "deg" or "rad" (revolute and continuous joints).
    length_unit : "mm" or "m" (prismatic joints).
    comment : text written first as ``#`` comment lines.
    names : None, or one name per row (distinct, non-empty text without commas or quotes),
        written first in the column ``name_column``: the key the instrument's file gives the
        same points, for a join (``calibrate ... --tracker FILE --key point``).
    extra : None, or {column: one text per row} written after the names (no commas, quotes or
        '#'; readers ignore such columns), e.g. the targets a plan's pose sees.
    """
    from calib.checks import check_configurations, check_path
    from calib.model.robot import check_robot

    check_path(path, "path")
    check_robot(robot)
    q = check_configurations(q, robot.n_joints, "q")
    if names is not None:
        if not isinstance(names, (list, tuple, np.ndarray)) or not all(isinstance(n, str) for n in names):
            raise ParameterError(f"names must be a list of {len(q)} names (text), got {names!r:.60}")
        names = [str(n) for n in names]
        if len(names) != len(q) or len(set(names)) != len(names) or \
                any(not n.strip() or any(c in n for c in ',"\n#') for n in names):
            raise ParameterError(f"names must be {len(q)} distinct names without commas, quotes or '#'")
        if not isinstance(name_column, str) or not name_column.isidentifier():
            raise ParameterError(f"name_column must be a column name, got {name_column!r}")
    extra = {} if extra is None else extra
    if not isinstance(extra, dict) or not all(
            isinstance(k, str) and k.isidentifier() and isinstance(v, (list, tuple)) and len(v) == len(q)
            and all(isinstance(x, str) and not any(c in x for c in ',"\n#') for x in v) for k, v in extra.items()):
        raise ParameterError(f"extra must map column names to {len(q)} texts each (no commas, quotes or '#')")
    if not isinstance(angle_unit, str) or angle_unit not in ANGLE_UNITS:
        raise ParameterError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if not isinstance(length_unit, str) or length_unit not in LENGTH_UNITS:
        raise ParameterError(f"length_unit must be 'mm' or 'm', got {length_unit!r}")
    header, values = joint_columns(robot.joint_names, robot.prismatic, q, angle_unit, length_unit)
    rows = [[repr(float(v)) for v in row] for row in values]
    if extra:
        header = list(extra) + header
        rows = [[extra[k][i] for k in extra] + row for i, row in enumerate(rows)]
    if names is not None:
        header = [name_column] + header
        rows = [[name] + row for name, row in zip(names, rows)]
    # (the text columns, names and extra texts, escaped for spreadsheets as every cell calib writes)
    n_text = len(extra) + (names is not None)
    atomic_write_text(path, csv_text(header, rows, comment, range(n_text)))


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
    from calib.io.csv.targets import CompensationTargets

    names = t.labels.get("name")
    return CompensationTargets(q=t.q, position=t.position, rotation=t.rotation, rows=t.rows,
                               source=t.path, ignored_columns=t.ignored_columns,
                               notes=t.notes + _rename_notes(options, [t]),
                               names=None if names is None else tuple(names),
                               configuration={k: (t.names[k], tuple(v)) for k, v in t.labels.items()
                                              if k != "name"})


def check_names(names, n: int) -> tuple[str, ...] | None:
    """``names`` as a tuple of n strings (one per target), or None; a ParameterError otherwise."""
    if names is None:
        return None
    if isinstance(names, (str, bytes)) or not hasattr(names, "__len__") or len(names) != n \
            or not all(isinstance(x, str) for x in names):
        raise ParameterError(f"names must be {n} target names (str) or None, got {names!r:.60}")
    return tuple(names)


def write_compensation(path: str | Path, result, *, angle_unit: str = "deg",
                       length_unit: str = "mm", comment: str | None = None, names=None) -> None:
    """Write the corrected joint values of a :class:`calib.CompensationResult` with a status per
    target as CSV, atomically.

    Columns: the joint columns ``<joint>_deg`` (``_mm`` for prismatic joints; units as chosen),
    the corrected joint values to send to the controller, in the order of the targets; then
    ``status`` (ok, limit, singular, not_converged), ``residual_mm`` (distance of the calibrated
    tool position from the target), ``residual_rad`` (angle of the orientation residual; pose
    targets only), ``frame_std_mm`` and ``frame_std_deg`` (when the result carries the base
    frame's uncertainty: the 1-sigma error of the reached pose it causes) and ``detail`` (why a target is not ok: the joint beyond its limit and by how
    much, the singular value, the residual). Joint values are written as computed, never clipped:
    a row whose status is not ``ok`` must not be sent to the robot as it is.

    ``names`` : (N,) the targets' names (a targets file's name column), written first as a
    ``name`` column; None: no such column.

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
    names = check_names(names, result.n_targets)
    if names is not None:
        header = ["name"] + header
    header += ["status", "residual_mm"] + (["residual_rad"] if result.rotation_error is not None else [])
    framed = getattr(result, "frame_position_std", None) is not None
    if framed:        # the base frame's uncertainty (targets in the robot's base frame)
        header += ["frame_std_mm", "frame_std_deg"]
    header.append("detail")
    rows = []
    for k in range(result.n_targets):
        row = ([str(names[k])] if names is not None else []) + [repr(float(v)) for v in values[k]]
        row += [str(result.status[k]), f"{result.position_error[k] * 1e3:.6g}"]
        if result.rotation_error is not None:
            row.append(f"{result.rotation_error[k]:.6g}")
        if framed:
            row += [f"{result.frame_position_std[k] * 1e3:.4g}",
                    f"{math.degrees(result.frame_rotation_std[k]):.4g}"]
        row.append("" if result.status[k] == "ok" and not framed else result.describe(k))
        rows.append(row)
    text = [header.index("status"), len(header) - 1]     # (status and detail: the rest are numbers)
    atomic_write_text(path, csv_text(header, rows, comment, text))
