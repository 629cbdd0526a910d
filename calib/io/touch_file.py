"""Touch files (issue 24): the joint values at which the tool point touched a feature of the cell.

A touch file is a measurement file whose rows name, instead of a measured position, the feature
the tool point touched (:mod:`calib.model.touch`), one of these columns per row (the others of
the row left empty; several kinds and ids may be mixed in one file):

- ``point`` (an id): the tool point was at the same fixed, unknown point in every row of the id;
- ``plane`` (an id): the tool point lay on an unknown plane (a ball tip's radius is given to the
  reader, ``--probe-radius-mm``);
- ``sphere`` (an id) with ``radius_mm`` or ``radius_m`` (positive, the same in every row of the
  id): the tool point was at that distance from an unknown fixed centre.

Joint columns as in measurement files (:mod:`calib.io.specs`). Example::

    # a nest touched from 4 orientations, and a face of a datum cube
    shoulder_pan_joint_deg,shoulder_lift_joint_deg,...,wrist_3_joint_deg,point,plane,sphere,radius_mm
    10.5,-80.2,95.0,-60.1,-90.0,12.0,P1,,,
    ...
    -20.0,-70.0,80.0,-90.0,-90.0,45.0,,A,,
    ...
    5.0,-60.0,70.0,-100.0,-80.0,0.0,,,S,100

Rows measured by an instrument (``x, y, z``) are not mixed with touch rows in one file (yet):
such a file is refused, naming the column.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.errors import CalibError, MeasurementFormatError
from calib.io.csv_layer import LENGTH_UNITS, ReadOptions, Spec, _records, csv_text, joint_columns, read_table
from calib.io.fileio import atomic_write_text, check_not_input
from calib.model.touch import FEATURE_KINDS, Feature, TouchData

__all__ = ["TOUCH", "is_touch_file", "read_touch", "write_touch"]

TOUCH = Spec("touch", joints="required", position="optional", labels=FEATURE_KINDS,
             lengths=("radius",), sparse=FEATURE_KINDS)
#: Spheres of one id: radii equal to this (metres) are the same.
RADIUS_TOL = 1e-9


#: Bytes of a file's start in which :func:`is_touch_file` looks for the header row before it
#: reads the whole file as the readers do.
_HEADER_PEEK = 1 << 16


def is_touch_file(path: str | Path) -> bool:
    """Whether the header of the CSV file ``path`` has a ``point``, ``plane`` or ``sphere``
    column (the file is then read by :func:`read_touch`). The header row of a regular UTF-8 file
    is found in its first 64 KB (``calib calibrate`` asks this of every measurement file: a
    million-row file was read whole, twice); other files are read as the readers read them."""
    path = Path(path)
    names = _peek_header(path)
    if names is None:
        names = _records(path)[1]
    return any(n.strip().lower() in FEATURE_KINDS for n in names)


def _peek_header(path: Path) -> list[str] | None:
    """The header names of a regular file from its first _HEADER_PEEK bytes, split as
    :func:`calib.io.csv_layer._records` splits them, or None when they do not settle it (not a
    regular file, not UTF-8 there, no complete header line, a header that looks like data)."""
    from calib.io.csv_layer import _DELIMITERS, _field_count, _looks_numeric, split_fields

    try:
        if not path.is_file():
            return None
        with open(path, "rb") as f:
            head = f.read(_HEADER_PEEK)
        text = head.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    complete = lines[:-1] if len(head) == _HEADER_PEEK else lines     # (the last may be cut)
    for k, line in enumerate(complete):
        if line.strip() and not line.lstrip().startswith("#"):
            try:
                best = max(_DELIMITERS, key=lambda d: _field_count(path, k + 1, line, d))
                names = split_fields(path, k + 1, line, best)
            except CalibError:
                return None
            return None if _looks_numeric(names) else names
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

    path = check_path(csv_path, "csv_path")
    check_number(probe_radius, "probe_radius (m)", minimum=0.0, maximum=1.0)
    t = read_table(path, TOUCH, robot, options)
    if t.position is not None:
        raise MeasurementFormatError(path, "measured positions (x, y, z) and touch rows (point, plane, "
                                           "sphere) in one file are not supported: give them in two files",
                                     row=t.header_row, column=t.names["x"])
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
    for k, row in enumerate(t.rows):
        given = [kind for kind in kinds if t.labels[kind][k]]
        if len(given) != 1:
            what = "none of" if not given else f"{' and '.join(given)}: more than one of"
            raise MeasurementFormatError(path, f"{what} point, plane, sphere: a row names exactly one "
                                               f"feature touched", row=int(row),
                                         column=t.names[given[1]] if len(given) > 1 else None)
        kind = given[0]
        key = (kind, t.labels[kind][k])
        r = np.nan if radius is None else float(radius[k])
        if kind == "sphere":
            if not np.isfinite(r) or r <= 0:
                raise MeasurementFormatError(path, f"sphere {key[1]!r} needs a positive radius, got "
                                                   f"{'none' if np.isnan(r) else repr(_shown(t, r))}",
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
    feats = tuple(Feature(kind, fid, radii[(kind, fid)][0] if kind == "sphere" else None)
                  for (kind, fid) in features)
    return TouchData(t.q, feature, feats, probe_radius, rows=t.rows, joint_names=robot.joint_names,
                     source=path)


def _shown(t, r: float) -> float:
    """A radius in metres in the unit of the file's radius column."""
    unit = t.names["radius"].rsplit("_", 1)[-1].lower()
    return r / LENGTH_UNITS.get(unit, 1.0)


def write_touch(path: str | Path, data: TouchData, robot, *, angle_unit: str = "deg",
                comment: str | None = None) -> None:
    """Write touch rows as a touch file (format: module docstring), atomically: joint columns
    named after ``robot``'s joints (``angle_unit`` "deg" or "rad"; prismatic joints in mm), the
    kind columns present in ``data``, and ``radius_mm`` when there are spheres. Numbers are
    written with ``repr``: reading the file back gives the data to the unit conversion's rounding."""
    from calib.checks import check_instance, check_path
    from calib.model.robot import check_robot

    check_path(path, "path")
    check_instance(data, "data", TouchData, "calib.read_touch or calib.simulate_touch")
    check_robot(robot)
    check_not_input(path, [data.source])
    header, qv = joint_columns(robot.joint_names, robot.prismatic, data.q, angle_unit, "mm")
    kinds = [k for k in FEATURE_KINDS if any(f.kind == k for f in data.features)]
    header += kinds + (["radius_mm"] if "sphere" in kinds else [])
    rows = []
    for k in range(data.n_rows):
        f = data.features[data.feature[k]]
        row = [repr(float(v)) for v in qv[k]] + [f.id if f.kind == kind else "" for kind in kinds]
        if "sphere" in kinds:
            row.append(repr(f.radius * 1e3) if f.kind == "sphere" else "")
        rows.append(row)
    atomic_write_text(path, csv_text(header, rows, comment))
