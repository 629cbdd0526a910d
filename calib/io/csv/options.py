"""How a measurement file is read: its options (:class:`ReadOptions`, checked once when made), the
columns of each file kind (:class:`Spec`) and a file as read (:class:`Table`), and the checks of
the options' values (Euler sequences, renames, the joining of a joint file and a tracker file:
:mod:`calib.io.csv.join` joins them). The one module the CSV layer's other modules share for
these types, so that none of them imports another in a circle."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.choices import JOINS
from calib.errors import ParameterError

__all__ = ["ReadOptions", "Spec", "Table", "LIMIT_TOLERANCE", "TIME_UNITS", "TARGET_FROM_EXAMPLE",
           "check_euler_sequence", "parse_rename", "check_join_options", "check_sides", "split_sides",
           "key_columns", "label_of", "name_unit", "check_target_from"]

#: Default joint limit tolerance, as a fraction of the joint range.
LIMIT_TOLERANCE = 0.01
#: Seconds per unit of a time column (``time_s``, ``--time-unit ms``, ...).
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
TARGET_FROM_EXAMPLE = r"(?P<key>P\d+)_(?P<target>SMR\d+)"
_UNIT_IN_BRACKETS = re.compile(r"^(.*?)\s*[\(\[]\s*([A-Za-z]+)\s*[\)\]]$")


class _Fields:
    """``options`` read with some fields replaced (the checks' view of stripped names)."""

    def __init__(self, options, replaced: dict):
        self._options, self._replaced = options, replaced

    def __getattr__(self, name):
        return self._replaced[name] if name in self._replaced else getattr(self._options, name)


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


#: ReadOptions' fields of the joining of a tracker file (:mod:`calib.io.csv.join`) besides ``join``.
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
    key : name of the column that joins a joint file and a tracker file, or ``"JOINT=TRACKER"``
        when the two files name it differently (``"Point=Target"``), or None.
    target_column, target_from, join, time, time_unit, max_gap : how a joint file and a tracker
        file are joined (one joint row to several measured rows, by nearest time; ``time`` may be
        ``"JOINT=TRACKER"`` too): see :mod:`calib.io.csv.join`, which checks them.
    convention : a vendor's column names and units (a key of
        :data:`calib.io.csv.conventions.CONVENTIONS`: ``"kuka"``, ``"abb"``, ``"ur"``, ``"fanuc"``,
        ``"staubli"``, ``"yaskawa"``, or ``"calib"`` to state calib's own ZYX reading of rx, ry,
        rz in any order), or None (calib's own names; ambiguous orientation names refused).
    header_line : line number (from 1) of the header, or None: the first line that names known
        columns (a preamble before it is skipped).
    instrument, columns, length_unit : the instrument's file: a preset of
        :data:`calib.io.csv.instruments.INSTRUMENTS` (``"leica"``, ``"spatialanalyzer"``), the names of
        the columns of a file without a header line (``"point,x_mm,y_mm,z_mm"``), the unit
        (``"mm"``, ``"m"``) of x, y, z named without one; see :mod:`calib.io.csv.instruments`.
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
    instrument: str | None = None
    columns: tuple[str, ...] | None = None
    length_unit: str | None = None

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
            from calib.io.csv.conventions import CONVENTIONS

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
        if any(v is not None for v in (self.instrument, self.columns, self.length_unit)):
            from calib.io.csv.instruments import check_file_options

            for name, value in check_file_options(self).items():
                object.__setattr__(self, name, value)
        if self.key is not None:
            if not isinstance(self.key, str) or not self.key.strip():
                raise ParameterError(f"key must be a column name, got {self.key!r:.60}")
            object.__setattr__(self, "key", str(self.key).strip())
            if "=" in self.key:                 # JOINT=TRACKER: each file's own name
                object.__setattr__(self, "key", check_sides(self.key, "key", "--key"))
        if not isinstance(self.join, str) or self.join != "key" or any(getattr(self, f) is not None
                                                                       for f in _JOIN_FIELDS):
            # (the defaults need no check; the names are stripped)
            for name, value in check_join_options(self).items():
                object.__setattr__(self, name, value)


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
    extras : optional per-row quantities of :data:`calib.io.csv.header.EXTRA_UNITS` (``time``
        with _s, _min or _h; ``temperature`` with _c or _degc), read in seconds and degrees
        Celsius, empty cells NaN: what a report plots the residuals against (drift).
    key : the name of the key column in this file when it differs from :attr:`ReadOptions.key`
        (``--key JOINT=TRACKER``: each side's own name), else None.
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
    key: str | None = None

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


def _column_name(value, option: str, flag: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ParameterError(f"{option} must be a column name ({flag} COLUMN), got {value!r:.60}")
    return value.strip()


def split_sides(value: str) -> tuple[str, str]:
    """(joint file's name, tracker file's name) of a column option: ``A=B`` names each side's
    column (``--key Point=Target``, ``--time 'timestamp=Time [s]'``), a single name both."""
    a, sep, b = value.partition("=")
    return (a.strip(), b.strip()) if sep else (value.strip(), value.strip())


def key_columns(options: ReadOptions) -> tuple[str, str]:
    """The key column's name in the joint file and in the tracker file (``options.key``)."""
    return split_sides(options.key)


def label_of(name: str) -> str:
    """The label a column name is read under: lower case, a unit in brackets as a suffix
    (``Time [s]`` -> ``time_s``), as the header check reads the file's names."""
    m = _UNIT_IN_BRACKETS.match(name.strip())
    return (f"{m.group(1)}_{m.group(2)}" if m and m.group(1) else name.strip()).lower()


def name_unit(name: str) -> str | None:
    """The time unit a column name states (``time_s``, ``t_ms``, ``Time (s)``), or None."""
    m = _UNIT_IN_BRACKETS.match(name)
    base, sep, suffix = (f"{m.group(1)}_{m.group(2)}" if m and m.group(1) else name).lower().rpartition("_")
    return suffix if sep and base and suffix in TIME_UNITS else None


def check_join_options(options: ReadOptions) -> dict:
    """Check the join fields of ``options`` (called by ReadOptions itself); their column names
    stripped (field -> value, which ReadOptions sets); :class:`calib.ParameterError` naming the
    option and its flag."""
    o, stripped = options, {}
    if not isinstance(o.join, str) or o.join not in JOINS:
        raise ParameterError(f"join must be one of {', '.join(JOINS)} (--join), got {o.join!r:.60}")
    for field, flag in (("target_column", "--target-column"), ("time", "--time")):
        if getattr(o, field) is not None:
            stripped[field] = _column_name(getattr(o, field), field, flag)
    if o.time is not None:
        stripped["time"] = check_sides(stripped["time"], "time", "--time")
    o = _Fields(o, stripped)
    if o.time_unit is not None and (not isinstance(o.time_unit, str) or o.time_unit not in TIME_UNITS):
        raise ParameterError(f"time_unit must be one of {', '.join(TIME_UNITS)} (--time-unit), got "
                             f"{o.time_unit!r:.60}")
    gap = o.max_gap
    if gap is not None and (isinstance(gap, bool) or not isinstance(gap, (int, float))
                            or not math.isfinite(gap) or gap < 0):
        raise ParameterError(f"max_gap must be a finite number of seconds >= 0 (--max-gap S), got "
                             f"{gap!r:.60}")
    if o.target_from is not None:
        check_target_from(o.target_from)
        if o.join == "key" and o.key is None:
            raise ParameterError("--target-from splits the point names of the key column: give it too "
                                 "(--key COLUMN)")
        if o.target_column is not None:
            raise ParameterError("the target id comes from one place: a target column (--target-column) "
                                 "or the compound point names of the key column (--target-from), not both")
    if o.target_column is not None and o.key is not None and \
            o.target_column.lower() == key_columns(o)[1].lower():
        raise ParameterError(f"--target-column {o.target_column!r} is the key column: to take the target "
                             f"id from a compound point name (P001_SMR2) give --target-from REGEX "
                             f"(e.g. {TARGET_FROM_EXAMPLE!r})")
    if o.join == "key":
        given = [flag for field, flag in (("time", "--time"), ("time_unit", "--time-unit"),
                                          ("max_gap", "--max-gap")) if getattr(o, field) is not None]
        if given:
            raise ParameterError(f"{', '.join(given)} join by time: give --join nearest-time too "
                                 f"(or leave {'them' if len(given) > 1 else 'it'} out to join by --key)")
        return stripped
    if o.key is not None:
        raise ParameterError("--key and --join nearest-time: join the files by a key column or by the "
                             "nearest time, not both")
    if o.target_from is not None:
        raise ParameterError("--target-from splits the key column (--key), and --join nearest-time has "
                             "none: give the target id in a column of the tracker file (--target-column)")
    if o.time is None:
        raise ParameterError("--join nearest-time needs the time column of both files: give --time "
                             "COLUMN (e.g. time_s, its unit in its name, or --time-unit)")
    if o.max_gap is None:
        raise ParameterError("--join nearest-time needs --max-gap S: the largest time, in seconds, "
                             "between a measured row and the joint row it is joined to")
    for side in dict.fromkeys(split_sides(o.time)):
        stated = name_unit(side)
        if stated is not None and o.time_unit is not None and stated != o.time_unit:
            raise ParameterError(f"--time {o.time!r}: {side!r} says its unit is {stated}, --time-unit "
                                 f"says {o.time_unit}: give one")
    return stripped


def check_sides(value: str, option: str, flag: str) -> str:
    """``value`` with blanks stripped around ``=``; ParameterError for an empty side."""
    if "=" not in value:
        return value
    a, b = split_sides(value)
    if not a or not b or "=" in b:
        raise ParameterError(f"{flag} {value!r}: expected COLUMN, or JOINT=TRACKER naming the column of "
                             f"the joint file and of the tracker file (e.g. {flag} "
                             f"{'Point=Target' if option == 'key' else 'timestamp=Time [s]'})")
    return f"{a}={b}"


def check_target_from(text) -> re.Pattern:
    if not isinstance(text, str) or not text:
        raise ParameterError(f"target_from must be a regular expression with the named groups key and "
                             f"target (--target-from REGEX, e.g. {TARGET_FROM_EXAMPLE!r}), got {text!r:.60}")
    try:
        rx = re.compile(text)
    except re.error as exc:
        raise ParameterError(f"--target-from {text!r:.80} is not a regular expression: {exc}") from None
    lack = [g for g in ("key", "target") if g not in rx.groupindex]
    if lack:
        raise ParameterError(f"--target-from {text!r:.80} has no named group{'s' if len(lack) > 1 else ''} "
                             f"{' and '.join(lack)}: name the part of the point name that is the key "
                             f"(?P<key>...) and the part that is the target (?P<target>...), e.g. "
                             f"{TARGET_FROM_EXAMPLE!r}")
    return rx
