"""The CSV layer of calib: one reader for every file kind, driven by a column :class:`Spec`.

A file kind (measurements, poses to measure, compensation targets, the two halves of a keyed
pair of files) is a :class:`Spec`: which quantities it needs (joints, position, orientation) and
which text labels it takes (``set``, ``target``, a key column). :func:`read_table` reads any of
them into a :class:`Table` in SI units; :mod:`calib.io.csv.specs` turns tables into the objects
the algorithms take. Everything about the text of a file lives here (the matching of its header
in :mod:`calib.io.csv.header`), so every file kind has the same rules, errors and hints:

- UTF-8 (a byte-order mark is accepted); ``#`` comment lines and blank lines anywhere; row numbers
  are line numbers in the file.
- The delimiter (comma, semicolon or tab) is the one that splits the header into the most
  fields; with a semicolon or a tab, a decimal comma (``441,5``) is accepted.
- Header names are matched case-insensitively; ``X (mm)`` and ``X [mm]`` read as ``x_mm``;
  :attr:`ReadOptions.rename` maps a file's names onto calib's first. Columns calib does not know
  are ignored and listed (:attr:`Table.ignored_columns`), except near-misses of a known name
  (``x_mn``), which are errors with a "did you mean" hint.
- Orientations: a quaternion, ZYX angles, Euler angles of any sequence, a rotation vector or a
  rotation matrix, converted by Pinocchio (quaternions, ZYX angles, rotation vectors) and
  :class:`scipy.spatial.transform.Rotation` (the other Euler sequences).
- Joint values beyond a limit by at most :attr:`ReadOptions.limit_tolerance` of the joint range
  are kept with a note; further beyond is an error whose hint fits the size of the excess.

Errors are :class:`calib.MeasurementFormatError`: one line naming the file, row and column.
"""
from __future__ import annotations

from operator import methodcaller
from pathlib import Path
from typing import Sequence

import numpy as np

from calib.errors import MeasurementFormatError, ParameterError
from calib.io.csv.cells import csv_text, read_cell  # noqa: F401  (csv_text: importable from here too)
from calib.io.csv.lines import WHITESPACE, parse_number, records, split_fields
from calib.io.csv.header import ANGLE_UNITS, LENGTH_UNITS, ORIENTATIONS, POSITION_COLUMNS, Column, Header
from calib.io.csv.options import ReadOptions, Spec, Table

__all__ = ["read_table", "joint_columns", "csv_text"]

#: Largest accepted distance of a quaternion's norm from 1.
QUATERNION_NORM_TOLERANCE = 1e-3
#: Largest accepted entry of R R^T - I (and |det R - 1|) of a rotation matrix given in a file.
MATRIX_TOLERANCE = 1e-3


# ====================================================================== reading
#: Data lines parsed at once by the vectorised path (bounds its scratch memory).
CHUNK_ROWS = 1 << 15


def read_table(path: str | Path, spec: Spec, robot, options: ReadOptions | None = None) -> Table:
    """Read a CSV file of kind ``spec`` for ``robot`` (its joint names, units and limits).

    Returns a :class:`Table` in SI units (rad, m; rotations as (N, 3, 3) matrices of the tool
    frame in the meas frame). Raises :class:`calib.MeasurementFormatError` naming the file, row
    and column on any departure from the format.

    The rows are parsed column by column, a chunk of :data:`CHUNK_ROWS` lines at a time
    (vectorised); a chunk with anything unusual (quotes, a wrong field count, a cell that is not
    a finite number) is parsed again line by line, which raises the one-line error naming the
    row and column, or reads what the fast path declined (quoted fields).
    """
    from calib.checks import check_instance, check_path
    from calib.io.csv.header import Vocabulary
    from calib.model.robot import check_robot

    path = check_path(path, "path")
    check_robot(robot)
    options = check_instance(options, "options", ReadOptions, "calib.ReadOptions", allow_none=True) \
        or ReadOptions()
    vocabulary = Vocabulary(spec, robot, options)
    columns, comments, named_by = (None, (), "")
    if options.instrument is not None or options.columns is not None:
        from calib.io.csv.instruments import file_columns

        columns, comments, named_by = file_columns(options)
    header_row, names, delimiter, lines, data = records(path, vocabulary.known, options.header_line,
                                                         columns=columns, comments=comments, named_by=named_by)
    header = Header(path, header_row, names, spec, robot, options, vocabulary, named_by=named_by)
    if not len(data):
        raise MeasurementFormatError(path, "header but no data rows", row=header_row)
    cols = header.columns
    values, labels, rows = _parse_rows(path, spec, header, delimiter, len(names), lines, data)
    preamble = 0 if header_row is None else int(np.count_nonzero(
        [bool(x.strip()) and not x.lstrip().startswith(("#",) + comments) for x in lines[:header_row - 1]]))
    del lines, data     # (the text of a million rows: 300 MB, before the rotations are built)
    names_out = {k: c.name for k, c in cols.items()}
    orientation = _literal_cells(path, robot, cols, values, labels, rows, names_out) or header.orientation
    q = None
    notes: list[str] = []
    euler = header.euler
    if header.ambiguous is not None:            # rx, ry, rz: the rows decide, or refused
        orientation, euler, note = _decided_rx_ry_rz(path, robot, header, values, names_out, euler)
        notes.append(note)
    if preamble:
        notes.append(f"{path}: {preamble} line{'s' if preamble > 1 else ''} before the header "
                     f"(line {header_row}) skipped as a preamble")
    if any(isinstance(k, int) for k in values):
        q = np.column_stack([values[i] for i in range(robot.n_joints)])
        jcols = {i: cols[i] if i in cols else
                 Column(cols["joint_literal"].index, cols["joint_literal"].name, i, 1.0,
                        "m" if robot.joints[i].is_prismatic else "rad")
                 for i in range(robot.n_joints)}
        from calib.io.csv.limits import check_limits

        notes += check_limits(path, robot, jcols, q, rows, options.limit_tolerance)
    position = None
    if "x" in values:
        position = np.column_stack([values[k] for k in POSITION_COLUMNS])
    rotation = None if orientation == "none" else _rotations(path, orientation, values, names_out, rows, euler)
    if header.ignored:
        notes.insert(0, f"{path}: ignored columns (not calib's): {', '.join(header.ignored)}")
    for arr in (q, position, rotation, rows):
        if arr is not None:
            arr.setflags(write=False)
    return Table(path=path, header_row=header_row, rows=rows, q=q, position=position,
                 rotation=rotation, orientation=orientation,
                 labels={k: tuple(v) for k, v in labels.items()},
                 names=names_out,
                 ignored_columns=tuple(header.ignored), notes=tuple(notes),
                 renamed=tuple(header.renamed),
                 lengths={k: values[k] for k in spec.lengths if k in cols},
                 extras={k: values[k] for k in spec.extras if k in cols},
                 euler=euler if orientation == "euler" else None)


def _parse_rows(path: Path, spec: Spec, header: Header, delimiter: str, ncols: int, lines, data):
    """The data lines ``data`` (indices into ``lines``) parsed a chunk of :data:`CHUNK_ROWS` at a
    time: (the numeric columns' values by quantity, the text columns' cells by label, the rows'
    line numbers)."""
    cols = header.columns
    N = len(data)
    label_names = set(spec.labels) | ({header.key} if header.key else set()) | \
        {"pose_literal", "joint_literal"}
    numeric = {k: c for k, c in cols.items() if k not in label_names}
    values = {k: np.empty(N) for k in numeric}
    labels = {k: [] for k in cols if k not in numeric}
    rows = (data + 1).astype(int)
    reader = _Rows(path, spec, header, delimiter, delimiter != ",", ncols, numeric, labels)
    for start in range(0, N, CHUNK_ROWS):
        chunk = [lines[i] for i in data[start:start + CHUNK_ROWS].tolist()]
        got = reader.fast(chunk)
        if got is None:
            got = reader.slow(chunk, rows[start:start + CHUNK_ROWS])
        for key, v in got[0].items():
            values[key][start:start + len(chunk)] = v
        for key, v in got[1].items():
            # (an id as calib writes it for spreadsheets, a quote before a formula lead: csv/cells.py)
            labels[key].extend(map(read_cell, v) if any(t[:1] == "'" for t in v) else v)
        del chunk, got
    return values, labels, rows


def _literal_cells(path: Path, robot, cols: dict, values: dict, labels: dict, rows, names_out: dict) -> str | None:
    """The URScript/RAPID cells of a joint literal or pose literal column read into ``values``
    (and ``names_out``) as the joints' and the pose's quantities; the literal pose's orientation
    kind, or None without a pose literal."""
    orientation = None
    if "joint_literal" in cols:
        from calib.io.csv.literals import joint_literals     # (URScript/RAPID cells only)

        c = cols["joint_literal"]
        qv = joint_literals(path, robot, c.name, labels.pop("joint_literal"), rows)
        for i in range(robot.n_joints):
            values[i] = qv[:, i]
            names_out[i] = c.name
    if "pose_literal" in cols:
        from calib.io.csv.literals import pose_literals

        c = cols["pose_literal"]
        orientation, pv = pose_literals(path, c.name, labels.pop("pose_literal"), rows)
        for k, v in zip(POSITION_COLUMNS + ORIENTATIONS[orientation][0], pv.T):
            values[k] = v
            names_out[k] = c.name
    return orientation


def _decided_rx_ry_rz(path: Path, robot, header: Header, values: dict, names_out: dict, euler):
    """Columns named rx, ry, rz without a convention: their reading decided by the rows (or
    refused: :func:`calib.io.csv.orientation.decide_rx_ry_rz`), their values renamed to its
    quantities. Returns (the orientation kind, the Euler sequence, the note)."""
    from calib.io.csv.orientation import READINGS, decide_rx_ry_rz

    cols = header.columns
    qa = None if not any(isinstance(k, int) for k in values) else \
        np.column_stack([values[i] for i in range(robot.n_joints)])
    reading, note = decide_rx_ry_rz(
        path, *header.ambiguous[:1], header.row, header.ambiguous[1],
        ", ".join(cols[k].name for k in ("rx", "ry", "rz")), robot, qa,
        np.column_stack([values[k] for k in ("rx", "ry", "rz")]))
    orientation, keys, seq, _ = READINGS[reading]
    for old_key, key in zip(("rx", "ry", "rz"), keys):
        values[key] = values.pop(old_key)
        names_out[key] = names_out.pop(old_key)
    return orientation, seq or euler, note


def _rotations(path: Path, orientation: str, values: dict, names_out: dict, rows, euler) -> np.ndarray:
    """(N, 3, 3) the rotations of the orientation columns (NaN in the rows of a sparse file that
    give none; a row that gives some of its columns only is refused)."""
    group = ORIENTATIONS[orientation][0]
    given = np.column_stack([values[k] for k in group])
    full = np.isfinite(given).all(axis=1)
    part = np.flatnonzero(~full & np.isfinite(given).any(axis=1))
    if len(part):       # (sparse_pose: an orientation is given whole or not at all)
        k = int(part[0])
        empty = names_out[group[int(np.argmin(np.isfinite(given[k])))]]
        raise MeasurementFormatError(path, f"empty value: an orientation gives all of "
                                           f"{', '.join(names_out[c] for c in group)} or none",
                                     row=int(rows[k]), column=empty)
    if full.all():
        return _rotation(path, orientation, names_out[group[0]], given, rows, euler)
    rotation = np.full((len(given), 3, 3), np.nan)      # (sparse_pose: the rows without an orientation stay NaN)
    if full.any():
        rotation[full] = _rotation(path, orientation, names_out[group[0]], given[full], rows[full], euler)
    return rotation


class _Rows:
    """The data lines of one file, parsed a chunk at a time: :meth:`fast` (vectorised, None
    when anything is unusual) and :meth:`slow` (line by line, the exact errors)."""

    def __init__(self, path, spec, header, delimiter, decimal_comma, ncols, numeric, labels):
        self.path, self.spec, self.header = path, spec, header
        self.delimiter, self.decimal_comma, self.ncols = delimiter, decimal_comma, ncols
        self.numeric, self.labels = numeric, list(labels)

    def fast(self, chunk: list[str]):
        """({key: (n,) SI values}, {label: [n stripped strings]}) of the lines, or None."""
        d, ncols, n = self.delimiter, self.ncols, len(chunk)
        whole = "".join(chunk)
        if d != WHITESPACE and '"' in whole:
            return None                 # quoted fields: the csv module's reading
        underscore = "_" in whole
        del whole
        split = list(map(str.split, chunk)) if d == WHITESPACE else \
            list(map(methodcaller("split", d), chunk))
        if set(map(len, split)) != {ncols}:
            return None
        columns = list(zip(*split))
        del split
        out, texts = {}, {}
        for key, c in self.numeric.items():
            col = columns[c.index]
            if underscore and "_" in "".join(col):
                return None             # float() reads 1_000, the format does not
            if self.decimal_comma:
                joined = "\x00".join(col)
                if "," in joined:
                    col = joined.replace(",", ".").split("\x00")
            empty = None
            if self.spec.may_be_empty(key):
                empty = np.array([not t.strip() for t in col])
                col = ["nan" if e else t for t, e in zip(col, empty)]
            try:
                v = np.fromiter(map(float, col), dtype=float, count=n)
            except ValueError:
                return None
            ok = np.isfinite(v) if empty is None else (np.isfinite(v) | empty)
            if not ok.all():
                return None
            out[key] = v * c.scale
        cols = self.header.columns
        for key in self.labels:
            text = list(map(str.strip, columns[cols[key].index]))
            if key == "set":
                text = list(map(str.lower, text))
                if not set(text) <= {"cal", "val"}:
                    return None
            elif key not in self.spec.sparse and "" in set(text):
                return None
            texts[key] = text
        return out, texts

    def slow(self, chunk: list[str], rows: np.ndarray):
        """As :meth:`fast`, line by line; raises the first error of the lines."""
        path, header, cols = self.path, self.header, self.header.columns
        n = len(chunk)
        out = {k: np.empty(n) for k in self.numeric}
        texts = {k: [] for k in self.labels}
        for k, (line, row) in enumerate(zip(chunk, rows.tolist())):
            fields = split_fields(path, row, line, self.delimiter)
            if len(fields) != self.ncols:
                hint = ""
                if "[" in line and self.delimiter in line[line.index("["):] and \
                        any(k in cols for k in ("pose_literal", "joint_literal")):
                    hint = f"; quote a literal [...] that holds the delimiter {self.delimiter!r}"
                per = f"column named by {header.named_by}" if header.named_by else "header column"
                lack = header.names[len(fields)] if len(fields) < self.ncols else None   # (the first without one)
                raise MeasurementFormatError(path, f"wrong number of fields: {len(fields)}, expected "
                                                   f"{self.ncols} (one per {per}){hint}", row=row, column=lack)
            for key, c in self.numeric.items():
                if self.spec.may_be_empty(key) and not fields[c.index].strip():
                    out[key][k] = np.nan
                    continue
                out[key][k] = parse_number(path, row, c.name, fields[c.index],
                                           self.decimal_comma) * c.scale
            for key in self.labels:
                c = cols[key]
                text = fields[c.index].strip()
                if key == "set":
                    if text.lower() not in ("cal", "val"):
                        raise MeasurementFormatError(path, f"{text!r} is not a set; expected cal or val",
                                                     row=row, column=c.name)
                    text = text.lower()
                elif not text and key not in self.spec.sparse:
                    what = ("key" if key == header.key else
                            "literal" if key in ("pose_literal", "joint_literal") else key)
                    raise MeasurementFormatError(path, f"empty {what}, expected "
                                                       f"{'a value' if what == 'literal' else 'an id'}",
                                                 row=row, column=c.name)
                texts[key].append(text)
        return out, texts


def _rotation(path: Path, kind: str, first: str, values: np.ndarray, rows: np.ndarray,
              euler: str | None) -> np.ndarray:
    """(N, 3, 3) rotation matrices from the orientation values (SI) of kind ``kind`` (``first``:
    the name of its first column, for messages): quaternions, ZYX angles and rotation vectors by
    calib's vectorised maps (:mod:`calib.model.spatial`), other Euler sequences by scipy's
    Rotation (imported only then: it takes longer to import than a whole calibration)."""
    if kind == "quaternion":
        norm = np.linalg.norm(values, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
        if len(bad):
            raise MeasurementFormatError(
                path, f"quaternion (qw, qx, qy, qz) has norm {norm[bad[0]]:.6g}, expected 1 "
                      f"(within {QUATERNION_NORM_TOLERANCE:g})", row=int(rows[bad[0]]), column=first)
        from calib.model.spatial import rotation_from_quaternion

        return rotation_from_quaternion(values / norm[:, None])
    if kind == "zyx":   # R = Rz(rz) Ry(ry) Rx(rx) = Pinocchio's rpy (roll rx, pitch ry, yaw rz)
        from calib.model.spatial import rotation_from_zyx

        return rotation_from_zyx(values)
    if kind == "euler":
        from scipy.spatial.transform import Rotation

        return Rotation.from_euler(euler, values).as_matrix()
    if kind == "rotvec":
        from calib.model.spatial import rotation_from_rotvec

        return rotation_from_rotvec(values)
    R = values.reshape(-1, 3, 3)
    err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > MATRIX_TOLERANCE) | (np.abs(det - 1.0) > MATRIX_TOLERANCE))
    if len(bad):
        k = bad[0]
        raise MeasurementFormatError(
            path, f"r11 ... r33 is not a rotation matrix: |R R^T - I| = {err[k]:.3g}, det R = "
                  f"{det[k]:.6g}, expected orthonormal with det +1 (within {MATRIX_TOLERANCE:g}; "
                  f"rows of the matrix are r1j, r2j, r3j)", row=int(rows[k]), column=first)
    U, _, Vt = np.linalg.svd(R)          # the nearest rotation (within the tolerance above)
    return U @ Vt


# ====================================================================== writing
def joint_columns(joint_names: Sequence[str], prismatic, q, angle_unit: str, length_unit: str):
    """(header names, values in the column units) of the joint columns of q (N, n) rad / m."""
    from calib.errors import DataError

    if not isinstance(angle_unit, str) or angle_unit not in ANGLE_UNITS:
        raise ParameterError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if not isinstance(length_unit, str) or length_unit not in LENGTH_UNITS:
        raise ParameterError(f"length_unit must be 'mm' or 'm', got {length_unit!r}")
    q = np.atleast_2d(np.asarray(q, float))
    n = len(joint_names)
    if q.ndim != 2 or q.shape[1] != n:
        raise DataError(f"q must be (N, {n}) joint values, got shape {q.shape}")
    if not np.isfinite(q).all():
        raise DataError("q holds NaN or infinite values")
    prismatic = np.asarray(prismatic, bool)
    scale = np.where(prismatic, LENGTH_UNITS[length_unit], ANGLE_UNITS[angle_unit])
    header = [f"{name}_{length_unit if p else angle_unit}" for name, p in zip(joint_names, prismatic)]
    return header, q / scale
