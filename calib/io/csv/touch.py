"""Touch files (issue 24): the joint values at which the tool point touched a feature of the cell.

A touch file is a measurement file whose rows name, instead of a measured position, the feature
the tool point touched (:mod:`calib.model.touch`), one of these columns per row (the others of
the row left empty; several kinds and ids may be mixed in one file):

- ``point`` (an id): the tool point was at the same fixed, unknown point in every row of the id;
- ``plane`` (an id): the tool point lay on an unknown plane (a ball tip's radius is given to the
  reader, ``--probe-radius-mm``);
- ``sphere`` (an id) with ``radius_mm`` or ``radius_m`` (positive, the same in every row of the
  id): the tool point was at that distance from an unknown fixed centre.

Joint columns as in measurement files (:mod:`calib.io.csv.specs`). Example::

    # a nest touched from 4 orientations, and a face of a datum cube
    shoulder_pan_joint_deg,shoulder_lift_joint_deg,...,wrist_3_joint_deg,point,plane,sphere,radius_mm
    10.5,-80.2,95.0,-60.1,-90.0,12.0,P1,,,
    ...
    -20.0,-70.0,80.0,-90.0,-90.0,45.0,,A,,
    ...
    5.0,-60.0,70.0,-100.0,-80.0,0.0,,,S,100

Rows measured by an instrument may be mixed in: a row with ``x, y, z`` (units as in measurement
files; optionally an orientation, every measured row then giving it) and no feature is a
measured pose of the tool frame in the meas frame (:attr:`calib.model.touch.TouchData.measured`).
A row that names a feature and gives a measured pose is refused, naming the column. A ``point``
column in a file whose rows all give a measured pose is no feature but the rows' names (a tracker
export's point names): such a file is a measurement file (:func:`is_touch_file` says no).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.choices import FEATURE_KINDS
from calib.errors import CalibError, MeasurementFormatError
from calib.io.csv.layer import csv_text, joint_columns, read_table
from calib.io.csv.header import LENGTH_UNITS
from calib.io.csv.lines import records
from calib.io.csv.options import ReadOptions, Spec
from calib.io.fileio import atomic_write_text, check_not_input

# (calib.model.touch is imported by the reader and the writer: calib calibrate asks
# is_touch_file of every measurement file, which needs none of it)

__all__ = ["TOUCH", "is_touch_file", "read_touch", "write_touch"]

TOUCH = Spec("touch", joints="required", position="optional", orientation=True, labels=FEATURE_KINDS,
             lengths=("radius",), sparse=FEATURE_KINDS, sparse_pose=True)
#: Spheres of one id: radii equal to this (metres) are the same.
RADIUS_TOL = 1e-9


#: Bytes of a file's start in which :func:`is_touch_file` looks for the header row before it
#: reads the whole file as the readers do.
_HEADER_PEEK = 1 << 16


def is_touch_file(path: str | Path, header_line: int | None = None, rename=(), columns=None,
                  comments=()) -> bool:
    """Whether the header of the CSV file ``path`` has a ``point``, ``plane`` or ``sphere``
    column (the file is then read by :func:`read_touch`). The header is found as the reader finds
    it: past an instrument's preamble, or line ``header_line`` when given; ``rename`` (the pairs
    (old, new) of :attr:`ReadOptions.rename`) applies first, as in the reader. In a regular UTF-8
    file the header is looked for in its first 64 KB (``calib calibrate`` asks this of every
    measurement file: a million-row file was read whole, twice), else, or when those lines do not
    settle it, in the whole file. ``columns``: the names of a file without a header line
    (``--columns``, an instrument preset's), ``comments``: its comment line prefixes."""
    path = Path(path)
    renames = {str(old).strip().lower(): str(new).strip() for old, new in rename}

    def feature(name: str) -> bool:
        name = name.strip()
        return renames.get(name.lower(), name).lower() in FEATURE_KINDS

    names = list(columns) if columns is not None else _peek_header(path, feature, header_line,
                                                                    words=not renames)
    if names is None:
        names = records(path, feature, header_line)[1]
    kinds = {renames.get(n.strip().lower(), n.strip()).lower() for n in names if feature(n)}
    if kinds == {"point"} and _position_columns(names, renames):
        # a point column on rows that all carry a measured pose names them (a label); only a
        # file with touched rows (no position) reads it as the point touched
        return not _every_row_measured(path, header_line, renames, feature, columns, comments)
    return bool(kinds)


def _position_columns(names: list[str], renames: dict) -> list[int]:
    """The indices of the header names (after ``renames``) that give a measured position: x, y,
    z with or without a unit (``X [mm]``), a pose literal, UR's ``actual_TCP_pose_0..2``."""
    import re

    from calib.io.csv.header import POSE_LITERAL_NAMES
    from calib.io.csv.options import label_of

    out = []
    for i, name in enumerate(names):
        low = label_of(renames.get(name.strip().lower(), name.strip()))
        if re.fullmatch(r"[xyz](_[a-z]+)?|actual_tcp_pose_[012]", low) or low in POSE_LITERAL_NAMES:
            out.append(i)
    return out


def _every_row_measured(path: Path, header_line, renames: dict, feature, columns, comments) -> bool:
    """Whether every data row of the file has its position cells filled (a file read whole:
    only asked of a file whose header names a point and a position)."""
    from calib.io.csv.lines import WHITESPACE, split_fields

    header_row, names, delimiter, lines, data = records(path, feature, header_line, columns=columns,
                                                         comments=comments)
    cols = _position_columns(names, renames)
    rows = [lines[k] for k in data.tolist()]
    del lines
    last = max(cols)
    if delimiter == WHITESPACE:             # (no empty field: a row without a position is shorter)
        return all(len(f) > last for f in map(str.split, rows))
    d = delimiter
    text = "\n" + "\n".join(rows) + "\n"
    if '"' not in text and d + d not in text and "\n" + d not in text and d + "\n" not in text:
        # no empty field in any row (searches of the text: 0.2 s for 200,000 rows, splitting them
        # 0.6 s); a blank cell, or a short row, the measurement reader refuses naming the row
        return True
    del text
    split = (split_fields(path, int(k) + 1, r, d) for k, r in zip(data, rows))
    return all(len(f) > last and all(f[i].strip() for i in cols) for f in split)


def _peek_header(path: Path, known=None, header_line: int | None = None, words: bool = False
                 ) -> list[str] | None:
    """The header names of a regular file found in its first _HEADER_PEEK bytes as the reader
    finds them (:func:`calib.io.csv.lines.header_of`), or None when those bytes do not settle it
    (not a regular file, not UTF-8 there, no complete header line, any error). With ``words``
    (``known`` is a feature name, no renames) and bytes that name no feature where the header is
    looked for, the header is their first line (whichever line it is, it names no feature: the
    search would split each of up to 200 data lines that are not all numbers, e.g. with a
    ``set`` column, to find none); a file without a header line is still refused here, one with
    a preamble and no header by the reader."""
    from calib.io.csv.lines import MAX_PREAMBLE, header_of

    try:
        if not path.is_file():
            return None
        with open(path, "rb") as f:
            head = f.read(_HEADER_PEEK)
        text = head.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if len(head) == _HEADER_PEEK:
        lines = lines[:-1]                  # (the last may be cut)
    if words and not any(w in text.lower() for w in FEATURE_KINDS) and (
            len(head) < _HEADER_PEEK or header_line is None and sum(
                1 for line in lines if line.strip() and not line.lstrip().startswith("#")) > MAX_PREAMBLE):
        known = None                        # (the whole file, or every line the search looks at)
    try:
        return header_of(path, lines, known, header_line)[1]
    except CalibError:
        return None


def read_touch(csv_path: str | Path, robot, *, probe_radius: float = 0.0,
               options: ReadOptions | None = None) -> TouchData:
    """Read a touch file (format: module docstring) for ``robot``.

    probe_radius : metres, a ball tip's radius for plane rows. Returns :class:`TouchData` (SI):
    q (N, n) in chain order, each row's feature (in the order of first appearance), ``rows`` the
    line numbers, ``source`` the file. Raises :class:`calib.MeasurementFormatError` naming the
    file, row and column on any departure from the format.
    """
    from calib.checks import check_number, check_path
    from calib.model.touch import MAX_SPHERE_RADIUS_M, Feature, TouchData

    path = check_path(csv_path, "csv_path")
    check_number(probe_radius, "probe_radius (m)", minimum=0.0, maximum=1.0)
    t = read_table(path, TOUCH, robot, options)
    kinds = [k for k in FEATURE_KINDS if k in t.labels]
    if not kinds:
        raise MeasurementFormatError(path, "a touch file names the feature each row touched: give a "
                                           "column point, plane or sphere", row=t.header_row)
    radius = t.lengths.get("radius")
    if "sphere" in kinds and radius is None:
        raise MeasurementFormatError(path, "sphere rows need the sphere's radius: give a column radius_mm "
                                           "or radius_m", row=t.header_row, column=t.names["sphere"])
    features: dict[tuple[str, str], int] = {}
    radii: dict[tuple[str, str], tuple[float, int]] = {}
    feature = np.empty(len(t.rows), int)
    pose_cols = _pose_columns(t)
    present = (np.column_stack([np.isfinite(t.position)] + ([] if t.rotation is None else
                                                             [np.isfinite(t.rotation).all(axis=(1, 2))]))
               if t.position is not None else np.zeros((len(t.rows), 0), bool))
    measured = np.zeros(len(t.rows), bool)
    for k, row in enumerate(t.rows):
        given = [kind for kind in kinds if t.labels[kind][k]]
        if len(given) > 1:
            raise MeasurementFormatError(path, f"{' and '.join(given)}: more than one of point, plane, "
                                               f"sphere: a row names exactly one feature touched",
                                         row=int(row), column=t.names[given[1]])
        if present.shape[1] and present[k].any():
            if given:
                raise MeasurementFormatError(path, f"a row touching {given[0]} {t.labels[given[0]][k]!r} "
                                                   f"takes no measured pose: a row is either touched "
                                                   f"(point, plane, sphere) or measured (x, y, z)",
                                             row=int(row), column=pose_cols[int(np.argmax(present[k]))])
            if not present[k].all():
                lack = pose_cols[int(np.argmin(present[k]))]
                raise MeasurementFormatError(path, f"empty value: a measured row gives all of "
                                                   f"{', '.join(pose_cols)}", row=int(row), column=lack)
            if radius is not None and np.isfinite(radius[k]):
                raise MeasurementFormatError(path, "only sphere rows take a radius; this row is measured "
                                                   "(x, y, z)", row=int(row), column=t.names["radius"])
            measured[k] = True
            continue
        if not given:
            what = "point, plane, sphere" + (" or a measured x, y, z" if t.position is not None else "")
            raise MeasurementFormatError(path, f"none of {what}: a row names exactly one feature touched"
                                               + (" or is measured" if t.position is not None else ""),
                                         row=int(row))
        kind = given[0]
        key = (kind, t.labels[kind][k])
        r = np.nan if radius is None else float(radius[k])
        if kind == "sphere":
            if not np.isfinite(r) or r <= 0:
                raise MeasurementFormatError(path, f"sphere {key[1]!r} needs a positive radius, got "
                                                   f"{'none' if np.isnan(r) else repr(_shown(t, r))}",
                                             row=int(row), column=t.names["radius"])
            if r > MAX_SPHERE_RADIUS_M:
                raise MeasurementFormatError(path, f"sphere {key[1]!r}: radius {_shown(t, r)!r} is larger than "
                                                   f"any sphere a robot touches ({_shown(t, MAX_SPHERE_RADIUS_M):g} "
                                                   f"in the column's unit; larger ones are planes to a robot: "
                                                   f"give such a surface as a plane, or check the unit)",
                                             row=int(row), column=t.names["radius"])
            first = radii.setdefault(key, (r, int(row)))
            if abs(first[0] - r) > RADIUS_TOL:
                raise MeasurementFormatError(path, f"sphere {key[1]!r} has radius {_shown(t, r)!r} here but "
                                                   f"{_shown(t, first[0])!r} in row {first[1]}: one sphere, "
                                                   f"one radius", row=int(row), column=t.names["radius"])
        elif np.isfinite(r):
            raise MeasurementFormatError(path, f"only sphere rows take a radius; this row touches {kind} "
                                               f"{key[1]!r}", row=int(row), column=t.names["radius"])
        feature[k] = features.setdefault(key, len(features))
    if not features:
        raise MeasurementFormatError(path, "every row is measured (x, y, z): a touch file names the feature "
                                           "each touch row touched; without touch rows drop the columns "
                                           f"{', '.join(t.names[k] for k in kinds)}", row=t.header_row)
    meas = None
    if measured.any():
        from calib.model.measurements import Measurements

        meas = Measurements(q=t.q[measured], position=t.position[measured],
                            rotation=None if t.rotation is None else t.rotation[measured],
                            rows=t.rows[measured], joint_names=robot.joint_names, source=path,
                            prismatic=robot.prismatic, ignored_columns=t.ignored_columns, notes=t.notes,
                            orientation=(None if t.orientation == "none" else f"euler:{options.euler}"
                                         if t.orientation == "euler" else t.orientation))
    touch = ~measured
    feats = tuple(Feature(kind, fid, radii[(kind, fid)][0] if kind == "sphere" else None)
                  for (kind, fid) in features)
    return TouchData(t.q[touch], feature[touch], feats, probe_radius, rows=t.rows[touch],
                     joint_names=robot.joint_names, source=path, measured=meas)


def _pose_columns(t) -> list[str]:
    """The header names of the measured pose's cells: x, y, z, then the orientation's (one name
    for all of an orientation's columns, in the order of :func:`read_touch`'s check)."""
    from calib.io.csv.header import ORIENTATIONS, POSITION_COLUMNS

    if t.position is None:
        return []
    cols = [t.names[k] for k in POSITION_COLUMNS]
    if t.rotation is not None:
        cols.append(t.names[ORIENTATIONS[t.orientation][0][0]])
    return cols


def _shown(t, r: float) -> float:
    """A radius in metres in the unit of the file's radius column."""
    unit = t.names["radius"].rsplit("_", 1)[-1].lower()
    return r / LENGTH_UNITS.get(unit, 1.0)


def write_touch(path: str | Path, data: TouchData, robot, *, angle_unit: str = "deg",
                comment: str | None = None) -> None:
    """Write touch rows as a touch file (format: module docstring), atomically: joint columns
    named after ``robot``'s joints (``angle_unit`` "deg" or "rad"; prismatic joints in mm), the
    kind columns present in ``data``, and ``radius_mm`` when there are spheres; ``data``'s
    measured rows after the touch rows, with x_mm, y_mm, z_mm (and qw, qx, qy, qz, qw >= 0). Numbers are
    written with ``repr``: reading the file back gives the data to the unit conversion's rounding."""
    from calib.checks import check_instance, check_path
    from calib.model.robot import check_robot
    from calib.model.touch import TouchData

    check_path(path, "path")
    check_instance(data, "data", TouchData, "calib.read_touch or calib.simulate_touch")
    check_robot(robot)
    check_not_input(path, [data.source])
    header, qv = joint_columns(robot.joint_names, robot.prismatic, data.q, angle_unit, "mm")
    kinds = [k for k in FEATURE_KINDS if any(f.kind == k for f in data.features)]
    m = data.measured
    pose_header, pose = [], None
    if m is not None:       # measured rows: x, y, z in mm and a quaternion (qw >= 0), after the touch rows
        pose_header = ["x_mm", "y_mm", "z_mm"]
        mq = joint_columns(robot.joint_names, robot.prismatic, m.q, angle_unit, "mm")[1]
        pose = [m.position * 1e3]
        if m.rotation is not None:
            from scipy.spatial.transform import Rotation

            wxyz = Rotation.from_matrix(m.rotation).as_quat(scalar_first=True)
            pose.append(wxyz * np.where(wxyz[:, :1] < 0, -1.0, 1.0))
            pose_header += ["qw", "qx", "qy", "qz"]
        pose = np.hstack(pose)
    header += pose_header + kinds + (["radius_mm"] if "sphere" in kinds else [])
    rows = []
    for k in range(data.n_rows):
        f = data.features[data.feature[k]]
        row = [repr(float(v)) for v in qv[k]] + [""] * len(pose_header) \
            + [f.id if f.kind == kind else "" for kind in kinds]
        if "sphere" in kinds:
            row.append(repr(f.radius * 1e3) if f.kind == "sphere" else "")
        rows.append(row)
    for k in range(data.n_measured):
        rows.append([repr(float(v)) for v in mq[k]] + [repr(float(v)) for v in pose[k]]
                    + [""] * (len(kinds) + ("sphere" in kinds)))
    atomic_write_text(path, csv_text(header, rows, comment))
