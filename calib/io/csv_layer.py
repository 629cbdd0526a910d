"""The CSV layer of calib: one reader for every file kind, driven by a column :class:`Spec`.

A file kind (measurements, poses to measure, compensation targets, the two halves of a keyed
pair of files) is a :class:`Spec`: which quantities it needs (joints, position, orientation) and
which text labels it takes (``set``, ``target``, a key column). :func:`read_table` reads any of
them into a :class:`Table` in SI units; :mod:`calib.io.specs` turns tables into the objects
the algorithms take. Everything about the text of a file lives here (the matching of its header
in :mod:`calib.io.csv_header`), so every file kind has the same rules, errors and hints:

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

import math
from operator import methodcaller
from dataclasses import field
from pathlib import Path
from typing import Sequence

import numpy as np

from calib.dataclass_code import dataclass
from calib.errors import MeasurementFormatError, ParameterError
from calib.io.csv_cells import csv_text, read_cell
from calib.io.csv_lines import (READ_BYTES_PER_FILE_BYTE, WHITESPACE, _records, available_memory,  # noqa: F401
                                check_size, parse_number, read_lines, split_fields)
from calib.io.csv_header import ANGLE_UNITS, LENGTH_UNITS, ORIENTATIONS, POSITION_COLUMNS, Column, Header

__all__ = ["ANGLE_UNITS", "LENGTH_UNITS", "ORIENTATIONS", "ReadOptions", "Spec", "Table",
           "read_table", "parse_rename", "check_euler_sequence", "joint_columns", "csv_text"]

#: Largest accepted distance of a quaternion's norm from 1.
QUATERNION_NORM_TOLERANCE = 1e-3
#: Largest accepted entry of R R^T - I (and |det R - 1|) of a rotation matrix given in a file.
MATRIX_TOLERANCE = 1e-3
#: Default joint limit tolerance, as a fraction of the joint range.
LIMIT_TOLERANCE = 0.01
#: Past a limit by more than this fraction of the joint range is more than a reading just past it.
UNIT_HINT_EXCESS = 0.1
#: A unit mix-up is suggested only for values at least this many times the largest limit.
UNIT_HINT_RATIO = 3.0


# ====================================================================== options and specs
def check_euler_sequence(seq: str) -> str:
    """``seq`` if it is one of scipy's 12 Euler sequences (``ZYX`` intrinsic, ``xyz`` extrinsic),
    else :class:`calib.ParameterError`."""
    s = str(seq)
    if len(s) != 3 or not (set(s) <= set("XYZ") or set(s) <= set("xyz")) or s[0] == s[1] \
            or s[1] == s[2]:
        raise ParameterError(f"--euler {s!r} is not an Euler sequence: expected 3 axes, all upper "
                             f"case (intrinsic, e.g. ZYX) or all lower case (extrinsic, e.g. xyz), "
                             f"no axis twice in a row (one of scipy's 12 sequences)")
    return s


def parse_rename(text: str) -> tuple[tuple[str, str], ...]:
    """``"OLD=NEW,OLD=NEW"`` as pairs; ``OLD=`` (empty NEW) drops the column."""
    pairs = []
    for item in str(text).split(","):
        old, sep, new = item.partition("=")
        if not sep or not old.strip():
            raise ParameterError(f"--rename {text!r}: {item.strip()!r} is not OLD=NEW (column "
                                 f"names; an empty NEW drops the column)")
        pairs.append((old.strip(), new.strip()))
    olds = [o.lower() for o, _ in pairs]
    dup = next((o for o in olds if olds.count(o) > 1), None)
    if dup is not None:
        raise ParameterError(f"--rename {text!r}: column {dup!r} renamed twice")
    return tuple(pairs)


#: ReadOptions' fields of the joining of a tracker file (:mod:`calib.io.join`) besides ``join``.
_JOIN_FIELDS = ("target_column", "target_from", "time", "time_unit", "max_gap")


@dataclass(frozen=True)
class ReadOptions:
    """How to read tracker files as they come (all optional).

    rename : ((old, new), ...) header names mapped onto calib's names before parsing (matched
        case-insensitively, after stripping blanks); an empty ``new`` drops the column.
    euler : scipy Euler sequence of the ``e1, e2, e3`` columns (``"ZYX"`` intrinsic, ``"xyz"``
        extrinsic, ...), or None.
    limit_tolerance : joint values beyond a limit by at most this fraction of the joint range
        (upper - lower) are kept with a note (default 0.01, 1 %).
    key : name of the column that joins a joint file and a tracker file, or None.
    target_column, target_from, join, time, time_unit, max_gap : how a joint file and a tracker
        file are joined (one joint row to several measured rows, by nearest time): see
        :mod:`calib.io.join`, which checks them.
    convention : a vendor's column names and units (a key of
        :data:`calib.io.conventions.CONVENTIONS`: ``"kuka"``, ``"abb"``, ``"ur"``, ``"fanuc"``,
        ``"staubli"``, ``"yaskawa"``, or ``"calib"`` to state calib's own ZYX reading of rx, ry,
        rz in any order), or None (calib's own names; ambiguous orientation names refused).
    header_line : line number (from 1) of the header, or None: the first line that names known
        columns (a preamble before it is skipped).
    """

    rename: tuple[tuple[str, str], ...] = ()
    euler: str | None = None
    limit_tolerance: float = LIMIT_TOLERANCE
    key: str | None = None
    target_column: str | None = None
    target_from: str | None = None
    join: str = "key"
    time: str | None = None
    time_unit: str | None = None
    max_gap: float | None = None
    convention: str | None = None
    header_line: int | None = None

    def __post_init__(self):
        if isinstance(self.rename, str):
            object.__setattr__(self, "rename", parse_rename(self.rename))
        else:
            pairs = self.rename if isinstance(self.rename, (list, tuple)) else None
            if pairs is None or not all(isinstance(p, (list, tuple)) and len(p) == 2 and
                                        all(isinstance(x, str) for x in p) for p in pairs):
                raise ParameterError(f"rename must be pairs (old, new) of column names, or 'old=new,...', "
                                     f"got {self.rename!r:.60}")
            object.__setattr__(self, "rename", tuple((o.strip(), n.strip()) for o, n in pairs))
        if self.euler is not None:
            check_euler_sequence(self.euler)
        tol = self.limit_tolerance
        if isinstance(tol, bool) or not (isinstance(tol, (int, float)) and math.isfinite(tol) and 0 <= tol <= 1):
            raise ParameterError(f"limit_tolerance must be a fraction of the joint range in "
                                 f"[0, 1], got {tol!r}")
        if self.convention is not None:
            from calib.io.conventions import CONVENTIONS

            if not isinstance(self.convention, str) or self.convention not in CONVENTIONS:
                raise ParameterError(f"convention must be one of {', '.join(CONVENTIONS)}, got "
                                     f"{self.convention!r:.60}")
            seq = CONVENTIONS[self.convention].euler
            if seq is not None and self.euler is not None and self.euler != seq:
                raise ParameterError(f"euler {self.euler!r} contradicts the {self.convention} "
                                     f"convention, whose angles are the sequence {seq!r}")
        h = self.header_line
        if h is not None and (isinstance(h, bool) or not isinstance(h, int) or h < 1):
            raise ParameterError(f"header_line must be a line number >= 1, got {h!r:.60}")
        if self.key is not None:
            if not isinstance(self.key, str) or not self.key.strip():
                raise ParameterError(f"key must be a column name, got {self.key!r:.60}")
            object.__setattr__(self, "key", str(self.key).strip())
        if not isinstance(self.join, str) or self.join != "key" or any(getattr(self, f) is not None
                                                                       for f in _JOIN_FIELDS):
            from calib.io.join import check_join_options     # (the defaults need no check)

            check_join_options(self)


@dataclass(frozen=True, eq=False, repr=False)     # (the file kinds' constants: nothing compares or prints them)
class Spec:
    """The columns of one file kind.

    kind : what the file is, for messages ("measurement", "poses", "targets", ...).
    joints, position : "required", "optional" or "none".
    orientation : whether orientation columns are read (optional in every kind that has them).
    labels : text columns read as strings (``set``, ``target``).
    keyed : the key column of :attr:`ReadOptions.key` is required.
    lengths : optional length columns (``radius``), each with ``_m`` or ``_mm``, whose cells may
        be empty (NaN).
    sparse : the labels whose cells may be empty ("", touch files' ``point``, ``plane``,
        ``sphere``: one of them per row).
    sparse_pose : the position and orientation cells may be empty (NaN; touch files: a row
        measured by an instrument, or one naming the feature touched).
    extras : optional per-row quantities of :data:`calib.io.csv_header.EXTRA_UNITS` (``time``
        with _s, _min or _h; ``temperature`` with _c or _degc), read in seconds and degrees
        Celsius, empty cells NaN: what a report plots the residuals against (drift).
    """

    kind: str
    joints: str = "required"
    position: str = "none"
    orientation: bool = False
    labels: tuple[str, ...] = ()
    keyed: bool = False
    lengths: tuple[str, ...] = ()
    sparse: tuple[str, ...] = ()
    sparse_pose: bool = False
    extras: tuple[str, ...] = ()

    def may_be_empty(self, key) -> bool:
        """Whether the cells of the numeric quantity ``key`` may be empty (read as NaN)."""
        return key in self.lengths or key in self.extras or (self.sparse_pose and not isinstance(key, int))


@dataclass(frozen=True, eq=False, repr=False)     # (internal; array fields: nothing compares or prints them)
class Table:
    """A file read by :func:`read_table`, SI units, one entry per data row.

    rows : (N,) int, line numbers. q : (N, n) rad / m in chain order, or None.
    position : (N, 3) metres, or None. rotation : (N, 3, 3), or None (with
    ``Spec.sparse_pose``: NaN in the rows whose cells are empty).
    orientation : "none" or a key of :data:`ORIENTATIONS`.
    labels : label name (``set``, ``target``, the key) -> N stripped strings.
    lengths : length column name (``radius``) -> (N,) metres, NaN where the cell is empty.
    extras : extra quantity (``time``, ``temperature``) -> (N,) seconds / degrees Celsius, NaN
        where the cell is empty.
    names : quantity ("x", "qw", "set", joint index, ...) -> header name as written.
    ignored_columns : header names (as written) of columns calib does not know or that were
        dropped by a rename. notes : one-line remarks (ignored columns, readings kept just past a
        limit). renamed : the rename sources that matched a column of this file.
    """

    path: Path
    header_row: int
    rows: np.ndarray
    q: np.ndarray | None
    position: np.ndarray | None
    rotation: np.ndarray | None
    orientation: str
    labels: dict
    names: dict
    ignored_columns: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    renamed: tuple[str, ...] = ()
    lengths: dict = field(default_factory=dict)
    extras: dict = field(default_factory=dict)
    euler: str | None = None


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
    from calib.io.csv_header import Vocabulary
    from calib.model.robot import check_robot

    path = check_path(path, "path")
    check_robot(robot)
    options = check_instance(options, "options", ReadOptions, "calib.ReadOptions", allow_none=True) \
        or ReadOptions()
    vocabulary = Vocabulary(spec, robot, options)
    header_row, names, delimiter, lines, data = _records(path, vocabulary.known, options.header_line)
    header = Header(path, header_row, names, spec, robot, options, vocabulary)
    if not len(data):
        raise MeasurementFormatError(path, "header but no data rows", row=header_row)
    decimal_comma = delimiter != ","
    cols = header.columns
    N, ncols = len(data), len(names)
    label_names = set(spec.labels) | ({header.key} if header.key else set()) | \
        {"pose_literal", "joint_literal"}
    numeric = {k: c for k, c in cols.items() if k not in label_names}
    values = {k: np.empty(N) for k in numeric}
    labels = {k: [] for k in cols if k not in numeric}
    rows = (data + 1).astype(int)
    reader = _Rows(path, spec, header, delimiter, decimal_comma, ncols, numeric, labels)
    for start in range(0, N, CHUNK_ROWS):
        chunk = [lines[i] for i in data[start:start + CHUNK_ROWS].tolist()]
        got = reader.fast(chunk)
        if got is None:
            got = reader.slow(chunk, rows[start:start + CHUNK_ROWS])
        for key, v in got[0].items():
            values[key][start:start + len(chunk)] = v
        for key, v in got[1].items():
            # (an id as calib writes it for spreadsheets, a quote before a formula lead: csv_cells)
            labels[key].extend(map(read_cell, v) if any(t[:1] == "'" for t in v) else v)
        del chunk, got
    preamble = int(np.count_nonzero([bool(x.strip()) and not x.lstrip().startswith("#")
                                     for x in lines[:header_row - 1]]))
    del lines, data     # (the text of a million rows: 300 MB, before the rotations are built)
    orientation = header.orientation
    names_out = {k: c.name for k, c in cols.items()}
    if "joint_literal" in cols:
        from calib.io.csv_literals import joint_literals     # (URScript/RAPID cells only)

        c = cols["joint_literal"]
        qv = joint_literals(path, robot, c.name, labels.pop("joint_literal"), rows)
        for i in range(robot.n_joints):
            values[i] = qv[:, i]
            names_out[i] = c.name
    if "pose_literal" in cols:
        from calib.io.csv_literals import pose_literals

        c = cols["pose_literal"]
        orientation, pv = pose_literals(path, c.name, labels.pop("pose_literal"), rows)
        for k, v in zip(POSITION_COLUMNS + ORIENTATIONS[orientation][0], pv.T):
            values[k] = v
            names_out[k] = c.name
    q = None
    notes: list[str] = []
    euler = header.euler
    if header.ambiguous is not None:            # rx, ry, rz: the rows decide, or refused
        from calib.io.csv_orientation import READINGS, decide_rx_ry_rz

        qa = None if not any(isinstance(k, int) for k in values) else \
            np.column_stack([values[i] for i in range(robot.n_joints)])
        reading, note = decide_rx_ry_rz(
            path, *header.ambiguous[:1], header_row, header.ambiguous[1],
            ", ".join(cols[k].name for k in ("rx", "ry", "rz")), robot, qa,
            np.column_stack([values[k] for k in ("rx", "ry", "rz")]))
        orientation, keys, seq, _ = READINGS[reading]
        for old_key, key in zip(("rx", "ry", "rz"), keys):
            values[key] = values.pop(old_key)
            names_out[key] = names_out.pop(old_key)
        euler = seq or euler
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
        notes += _check_limits(path, robot, jcols, q, rows, options.limit_tolerance)
    position = None
    if "x" in values:
        position = np.column_stack([values[k] for k in POSITION_COLUMNS])
    rotation = None
    if orientation != "none":
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
            rotation = _rotation(path, orientation, names_out[group[0]], given, rows, euler)
        else:       # (sparse_pose: the rows without an orientation stay NaN)
            rotation = np.full((N, 3, 3), np.nan)
            if full.any():
                rotation[full] = _rotation(path, orientation, names_out[group[0]], given[full], rows[full], euler)
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
                raise MeasurementFormatError(path, f"wrong number of fields: {len(fields)}, expected "
                                                   f"{self.ncols} (one per header column){hint}", row=row)
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


def _check_limits(path: Path, robot, columns: dict, q: np.ndarray, rows: np.ndarray,
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
